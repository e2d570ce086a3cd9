"""Rational transfer functions in the Laplace variable s (s in 1/s).

A :class:`TransferFunction` holds numerator and denominator coefficients in
descending powers of s, the way the paper and the model file write them. It is
checked once, on construction: a transfer function that cannot describe a
physical thermal path (improper, unstable, zero denominator) is refused.

Examples
--------
>>> link = TransferFunction([1.0], [26.48, 1.0])
>>> round(link.dc_gain, 3)
1.0
>>> [round(float(tc), 2) for tc in link.time_constants_s]
[26.48]
>>> round(abs(link.frequency_response(10.83)), 6)
0.003487
"""

from __future__ import annotations

import cmath
import functools
import math
from dataclasses import dataclass

import numpy as np

#: Two poles closer than this (relative) are separated before the modal
#: decomposition; the effect on any response is below this relative size.
REPEATED_POLE_TOLERANCE = 1e-9
REPEATED_POLE_SEPARATION = 1e-7


class TransferFunctionError(ValueError):
    """A transfer function that cannot describe a stable physical path."""


def _trim_leading_zeros(coefficients: tuple[float, ...]) -> tuple[float, ...]:
    index = 0
    while index < len(coefficients) - 1 and coefficients[index] == 0.0:
        index += 1
    return coefficients[index:]


@dataclass(frozen=True)
class ModalForm:
    """Partial-fraction form ``H(s) = direct + sum_i residues[i] / (s - poles[i])``.

    Attributes
    ----------
    poles : numpy.ndarray
        Complex poles in 1/s, all with negative real part.
    residues : numpy.ndarray
        Complex residues matching ``poles`` (output units per input unit per s).
    direct : float
        Direct feedthrough (output units per input unit).
    """

    poles: np.ndarray
    residues: np.ndarray
    direct: float


@dataclass(frozen=True)
class TransferFunction:
    """A proper, stable rational transfer function.

    Parameters
    ----------
    numerator, denominator : sequence of float
        Polynomial coefficients in descending powers of s.

    Raises
    ------
    TransferFunctionError
        If the denominator is zero, the numerator degree exceeds the
        denominator degree (improper), a coefficient is not finite, or a pole
        is not in the left half plane (zero or negative time constant).
    """

    numerator: tuple[float, ...]
    denominator: tuple[float, ...]

    def __post_init__(self) -> None:
        numerator = tuple(float(c) for c in self.numerator)
        denominator = tuple(float(c) for c in self.denominator)
        if not numerator or not denominator:
            raise TransferFunctionError("numerator and denominator need at least one coefficient")
        if not all(np.isfinite(numerator)) or not all(np.isfinite(denominator)):
            raise TransferFunctionError("coefficients must be finite numbers")
        numerator = _trim_leading_zeros(numerator)
        denominator = _trim_leading_zeros(denominator)
        if denominator == (0.0,):
            raise TransferFunctionError("denominator is zero")
        if len(numerator) > len(denominator):
            raise TransferFunctionError(
                f"improper: numerator degree {len(numerator) - 1} exceeds "
                f"denominator degree {len(denominator) - 1}"
            )
        object.__setattr__(self, "numerator", numerator)
        object.__setattr__(self, "denominator", denominator)
        poles = self.poles
        if poles.size and np.any(poles.real >= 0.0):
            bad = ", ".join(f"{p:.4g}" for p in poles if p.real >= 0.0)
            raise TransferFunctionError(
                f"not stable: pole(s) {bad} 1/s; every time constant must be positive"
            )

    # -- basic properties -------------------------------------------------
    @property
    def order(self) -> int:
        """Degree of the denominator (number of states)."""
        return len(self.denominator) - 1

    @functools.cached_property
    def poles(self) -> np.ndarray:
        """Poles in 1/s (complex array, read-only: found once per transfer function)."""
        poles = np.zeros(0, dtype=complex) if self.order == 0 else np.roots(self.denominator).astype(complex)
        poles.setflags(write=False)
        return poles

    @property
    def time_constants_s(self) -> list[float]:
        """Time constants -1/p of the real poles, in s, largest first."""
        real = [-1.0 / p.real for p in self.poles if abs(p.imag) <= 1e-12 * abs(p)]
        return sorted(real, reverse=True)

    @property
    def dc_gain(self) -> float:
        """Gain at s = 0 (output units per input unit)."""
        return float(self.numerator[-1] / self.denominator[-1])

    def frequency_response(self, angular_frequency_rad_s):
        """Complex gain H(j omega).

        Parameters
        ----------
        angular_frequency_rad_s : float or array_like
            Angular frequency in rad/s.

        Returns
        -------
        complex or numpy.ndarray
            H evaluated at s = j omega: a complex for a number, an array of the
            input's shape for an array.
        """
        if isinstance(angular_frequency_rad_s, (int, float)):
            s = 1j * float(angular_frequency_rad_s)     # plain Python complex: fast for one frequency
            return _polynomial_value(self.numerator, s) / _polynomial_value(self.denominator, s)
        s = 1j * np.asarray(angular_frequency_rad_s, dtype=float)
        value = _polynomial_value(self.numerator, s) / _polynomial_value(self.denominator, s)
        return complex(value) if np.ndim(value) == 0 else value

    # -- algebra ------------------------------------------------------------
    def __mul__(self, other: "TransferFunction | float") -> "TransferFunction":
        """Series connection ``self * other``; a number scales the gain."""
        if isinstance(other, (int, float)):
            return TransferFunction(tuple(float(other) * c for c in self.numerator), self.denominator)
        return TransferFunction(
            tuple(np.polymul(self.numerator, other.numerator)),
            tuple(np.polymul(self.denominator, other.denominator)),
        )

    __rmul__ = __mul__

    def __add__(self, other: "TransferFunction") -> "TransferFunction":
        """Parallel connection ``self + other`` (outputs added)."""
        return TransferFunction(
            tuple(np.polyadd(np.polymul(self.numerator, other.denominator),
                             np.polymul(other.numerator, self.denominator))),
            tuple(np.polymul(self.denominator, other.denominator)),
        )

    def __sub__(self, other: "TransferFunction") -> "TransferFunction":
        """``self - other``: the parallel connection with ``other`` negated."""
        return self + (-1.0) * other

    def time_scaled(self, factor: float) -> "TransferFunction":
        """The same path with every time constant multiplied by ``factor``.

        Returns ``H(factor * s)``: same static gain, dynamics ``factor`` times slower.
        """
        if factor <= 0.0:
            raise TransferFunctionError(f"time scale factor must be positive, got {factor}")

        def scale(coefficients: tuple[float, ...]) -> tuple[float, ...]:
            degree = len(coefficients) - 1
            return tuple(c * factor ** (degree - i) for i, c in enumerate(coefficients))

        return TransferFunction(scale(self.numerator), scale(self.denominator))

    @classmethod
    def first_order_lag(cls, time_constant_s: float, gain: float = 1.0) -> "TransferFunction":
        """``gain / (time_constant_s * s + 1)``; a zero time constant gives a pure gain."""
        if time_constant_s < 0.0:
            raise TransferFunctionError(f"time constant must not be negative, got {time_constant_s}")
        if time_constant_s == 0.0:
            return cls((gain,), (1.0,))
        return cls((gain,), (time_constant_s, 1.0))

    # -- modal decomposition -----------------------------------------------
    def modal_form(self) -> ModalForm:
        """Partial-fraction expansion over (made) distinct poles.

        Poles that coincide within ``REPEATED_POLE_TOLERANCE`` are separated by
        ``REPEATED_POLE_SEPARATION`` (relative) first, which changes any
        response by less than that relative amount.

        Returns
        -------
        ModalForm
            Found once per transfer function (its arrays read-only).
        """
        return self._modal_form

    @functools.cached_property
    def _modal_form(self) -> ModalForm:
        lead = self.denominator[0]
        denominator: np.ndarray = np.asarray(self.denominator) / lead
        numerator: np.ndarray = np.asarray(self.numerator) / lead
        direct = 0.0
        if len(numerator) == len(denominator):
            direct = float(numerator[0])
            numerator = np.polysub(numerator, direct * denominator)
        poles = self.poles
        poles = _separate_repeated(poles)
        if poles.size:
            denominator = np.real_if_close(np.poly(poles)).astype(complex)
        residues = np.array(
            [np.polyval(numerator, p) / np.polyval(np.polyder(denominator), p) for p in poles],
            dtype=complex,
        )
        poles = np.array(poles)
        for array in (poles, residues):
            array.setflags(write=False)
        return ModalForm(poles=poles, residues=residues, direct=direct)

    def sampled_response(self, angular_frequency_rad_s, period_s: float, setting_delay_s: float = 0.0):
        """Response of the samples to a held input, per harmonic component: the loop's view.

        The output is sampled every ``period_s``; ``setting_delay_s`` after each
        sample a new input value is set and held until the next setting (a
        zero-order hold). For an input sequence ``u_k = Re(c exp(j w t_k))`` with
        ``t_k`` the sample instants, the samples contain
        ``Re(H_sampled(w) c exp(j w t_k))`` at ``w``: this is ``H_sampled``. It
        differs from ``H(j w)`` by the hold's attenuation and delay and by the
        hold's images (at ``w + m 2 pi / period``), which the samples fold back
        onto ``w``; above half the sampling rate that matters.

        Parameters
        ----------
        angular_frequency_rad_s : float or array_like
            Angular frequency of the input sequence (rad/s).
        period_s : float
            Sample and hold period (s).
        setting_delay_s : float
            From a sample to the setting of the new input (s), at least 0; whole periods of it
            delay the response by as many samples.

        Returns
        -------
        complex or numpy.ndarray
        """
        if not (setting_delay_s >= 0.0 and period_s > 0.0):
            raise ValueError(f"need setting_delay_s >= 0 and period_s > 0, got {setting_delay_s}, {period_s}")
        whole_periods = math.floor(setting_delay_s / period_s)
        setting_delay_s -= whole_periods * period_s
        modal = self.modal_form()
        omega = np.asarray(angular_frequency_rad_s, dtype=float)
        z = np.exp(1j * omega * period_s)[..., None]
        poles, residues = modal.poles, modal.residues
        # exact solution of x' = p x + u over one period: u_{k-1} until the setting, then u_k
        a = np.exp(poles * period_s)
        before = np.exp(poles * (period_s - setting_delay_s)) * np.expm1(poles * setting_delay_s) / poles
        after = np.expm1(poles * (period_s - setting_delay_s)) / poles
        states = (after + before / z) / (z - a)
        response = (np.sum(residues * states, axis=-1) + modal.direct / z[..., 0]) * z[..., 0] ** -whole_periods
        return complex(response) if np.ndim(response) == 0 else response

    def to_dict(self) -> dict:
        """Plain mapping for the model file."""
        return {"numerator": [float(c) for c in self.numerator],
                "denominator": [float(c) for c in self.denominator]}


def _polynomial_value(coefficients: tuple[float, ...], s):
    """Polynomial in descending powers at s (Horner), for a complex number or a complex array alike."""
    value = 0.0
    for coefficient in coefficients:
        value = value * s + coefficient
    return value


def _separate_repeated(poles: np.ndarray) -> np.ndarray:
    poles = np.array(poles, dtype=complex)
    for i in range(len(poles)):
        for j in range(i):
            if abs(poles[i] - poles[j]) <= REPEATED_POLE_TOLERANCE * max(abs(poles[i]), 1e-300):
                poles[i] = poles[i] * (1.0 + REPEATED_POLE_SEPARATION * (1 + i))
    return poles


def first_order_link(value: complex, angular_frequency_rad_s: float) -> TransferFunction:
    """A link g / (tau s + 1) with the given complex gain at one frequency, or the nearest proper form.

    A phase in (-pi/2, 0] is a first-order lag. A lead (positive phase) needs a
    zero: (n1 s + n0) / (tau s + 1) with tau = 0.1 / omega, the numerator fixed
    by the value.
    """
    phase = cmath.phase(value)
    if -math.pi / 2 < phase <= 0.0:
        tau = math.tan(-phase) / angular_frequency_rad_s
        return TransferFunction((abs(value) * math.hypot(1.0, angular_frequency_rad_s * tau),),
                                (tau, 1.0) if tau > 0 else (1.0,))
    tau = 0.1 / angular_frequency_rad_s
    numerator = value * complex(1.0, angular_frequency_rad_s * tau)
    return TransferFunction((numerator.imag / angular_frequency_rad_s, numerator.real), (tau, 1.0))
