"""A linear path driven by a piecewise-constant input: modal state, exact zero-order hold.

The simulated cryostat's heater paths (G2*G1 to the flange thermometer, G3 to
the PTC stage) are driven by a heater power held constant between writes. A
path is kept in modal form, ``z_i' = lambda_i z_i + u``, output
``y = d u + Re(sum_i r_i z_i)``, and advanced with the exact solution for the
input held over a step of any length h::

    z_i(t + h) = a z_i(t) + (a - 1)/lambda_i u,      a = exp(lambda_i h)

so writes may come at any instant. Identification uses the same path for the
response of a trial time constant to a record's heater.

Examples
--------
>>> from cryod.model.transfer_function import TransferFunction
>>> path = HeaterPath(TransferFunction.first_order_lag(10.0))    # 1 / (10 s + 1)
>>> path.input = 1.0
>>> path.hold(10.0)
>>> round(path.output(), 4)                                      # 1 - exp(-1)
0.6321
"""

from __future__ import annotations

import cmath
import math
from typing import Callable

import numpy as np

from cryod.model.kept_results import KeptResults, digest
from cryod.model.transfer_function import TransferFunction

#: Step lengths whose hold coefficients a path keeps (all forgotten when one more comes).
HOLD_STEPS_KEPT = 64


def _exponential(all_real: bool) -> Callable[[complex], complex]:
    """The exponential for a path's poles: math's when they are all real (held as floats), else cmath's."""
    # math.exp takes no complex: the poles are floats whenever all_real, which their declared type (complex) cannot say
    return math.exp if all_real else cmath.exp  # type: ignore[return-value]


class HeaterPath:
    """A linear path driven by a piecewise-constant input, in modal form.

    Parameters
    ----------
    transfer_function : TransferFunction
        Input (W) to output (K) transfer function.
    """

    def __init__(self, transfer_function: TransferFunction):
        form = transfer_function.modal_form()
        self.transfer_function = transfer_function
        self.all_real = bool(np.all(form.poles.imag == 0.0))
        # real poles as floats: the hold and the mean then run on math's real functions, not cmath's
        self.poles: list[complex]
        self.residues: list[complex]
        if self.all_real:
            self.poles = [float(p.real) for p in form.poles]
            self.residues = [float(r.real) for r in form.residues]
        else:
            self.poles = [complex(p) for p in form.poles]
            self.residues = [complex(r) for r in form.residues]
        self.direct = float(form.direct)
        self.state = [0.0 * p for p in self.poles]
        self.input = 0.0
        # the coefficients of the steps held lately, by (duration, time scale): a simulated loop's steps take a few
        # dozen durations over and over
        self._hold_coefficients: dict[tuple[float, float], list] = {}
        self._window_key: tuple[float, float] | None = None
        self._window: tuple[list, list] = ([], [])

    def settle(self, value: float) -> None:
        """Put the path in steady state for a constant input ``value``."""
        self.input = value
        self.state = [-value / p for p in self.poles]

    def hold(self, duration_s: float, time_scale: float = 1.0) -> None:
        """Advance by ``duration_s`` with the input held (exact).

        ``time_scale`` multiplies every time constant for this step.
        """
        if duration_s <= 0.0:
            return
        key = (duration_s, time_scale)
        coefficients = self._hold_coefficients.get(key)
        if coefficients is None:
            exp = _exponential(self.all_real)
            decay = [exp(pole * duration_s / time_scale) for pole in self.poles]
            coefficients = [(a, (a - 1.0) / pole) for a, pole in zip(decay, self.poles)]
            if len(self._hold_coefficients) >= HOLD_STEPS_KEPT:
                self._hold_coefficients.clear()
            self._hold_coefficients[key] = coefficients
        u = self.input
        state = self.state
        for i, (a, gain) in enumerate(coefficients):
            state[i] = a * state[i] + gain * u

    def output(self) -> float:
        """Output now (the input's direct part uses the input in effect)."""
        total: complex = self.direct * self.input
        for residue, z in zip(self.residues, self.state):
            total += residue * z
        return total.real if isinstance(total, complex) else total

    def mean_output(self, duration_s: float, time_scale: float = 1.0) -> float:
        """Mean output over the next ``duration_s`` with the input held; state unchanged."""
        if duration_s <= 0.0:
            return self.output()
        u = self.input
        total = self.direct * u * duration_s
        for residue, z, state_gain, input_gain in zip(self.residues, self.state, *self._window_gains(duration_s,
                                                                                                      time_scale)):
            total += residue * (state_gain * z + input_gain * u)
        total = total.real if isinstance(total, complex) else total
        return total / duration_s

    def _window_gains(self, duration_s: float, time_scale: float) -> tuple[list, list]:
        """Per pole, what the state and the input add to the integral over ``duration_s``: (a - 1) / rate and
        ((a - 1) / rate - duration) / pole, a = exp(rate duration); kept while the window stays the same."""
        key = (duration_s, time_scale)
        if key != self._window_key:
            exp = _exponential(self.all_real)
            state_gains, input_gains = [], []
            for pole in self.poles:
                rate = pole / time_scale
                a = exp(rate * duration_s)
                state_gains.append((a - 1.0) / rate)
                input_gains.append(((a - 1.0) / rate - duration_s) / pole)
            self._window_key, self._window = key, (state_gains, input_gains)
        return self._window

    def run(self, durations_s: np.ndarray, inputs: np.ndarray, kept_by: bytes | None = None) -> np.ndarray:
        """Outputs at the start of each interval and after the last one (vectorised).

        Parameters
        ----------
        durations_s : numpy.ndarray
            Interval lengths h_k in s (length n).
        inputs : numpy.ndarray
            Input held over each interval (length n).
        kept_by : bytes, optional
            A digest of ``durations_s`` and ``inputs``: each mode's states are then kept
            (:data:`_MODE_STATES`) for the next run with the same pole, starting state and inputs (a path whose
            gains alone changed has the same modes).

        Returns
        -------
        numpy.ndarray
            Output at the n + 1 interval boundaries. The path's state is left
            at the end of the last interval.
        """
        durations_s = np.asarray(durations_s, dtype=float)
        inputs = np.asarray(inputs, dtype=float)
        count = durations_s.size
        outputs = np.zeros(count + 1)
        previous_input = np.concatenate(([self.input], inputs))
        outputs += self.direct * previous_input
        for i, pole in enumerate(self.poles):
            def made(pole=pole, initial=self.state[i]):
                a = np.exp(pole * durations_s)
                b = (a - 1.0) / pole * inputs
                return linear_recurrence(a, b, initial)

            if kept_by is None:
                states = made()
            else:
                states = _MODE_STATES.get_or_make(digest(kept_by, pole, self.state[i]), made)
            self.state[i] = states[-1].item()
            outputs += np.real(self.residues[i] * states)
        if count:
            self.input = float(inputs[-1])
        return outputs


#: The last modes' states over a record, by inputs, pole and starting state (see :meth:`HeaterPath.run`).
_MODE_STATES = KeptResults(24)

#: Samples per block of :func:`linear_recurrence`'s two-level scan.
SCAN_BLOCK = 32


def linear_recurrence(a: np.ndarray, b: np.ndarray, initial) -> np.ndarray:
    """z[0] = initial, z[k+1] = a[k] z[k] + b[k]; returns z[0..n].

    A parallel prefix scan over the affine maps ``z -> a z + b``, without a
    Python loop over the samples, in two levels: a Hillis-Steele scan inside
    blocks of :data:`SCAN_BLOCK` samples (all blocks at once, log2 of the block
    length whole-array passes), then one over the blocks' composite maps, then
    each sample from its block's starting value. That is about a third of the
    work of a single scan over the whole record (log2 n passes). Only products
    and sums of the factors are formed, never quotients, so nothing overflows
    (|a| <= 1) and the result agrees with the sequential loop to rounding.

    Parameters
    ----------
    a, b : numpy.ndarray
        Factors and offsets (length n, real or complex).
    initial : float or complex
        z[0].

    Returns
    -------
    numpy.ndarray
        z[0..n] (length n + 1).

    Examples
    --------
    >>> linear_recurrence(np.array([0.5, 0.5, 1.0]), np.array([1.0, 0.0, 1.0]), 2.0)
    array([2., 2., 1., 2.])
    """
    a, b = np.asarray(a), np.asarray(b)
    dtype = np.result_type(a, b, np.asarray(initial), float)
    count = a.size
    if count <= 2 * SCAN_BLOCK:
        return _scan(a, b, initial, dtype)
    blocks = -(-count // SCAN_BLOCK)
    factor = np.ones(blocks * SCAN_BLOCK, dtype=dtype)
    offset = np.zeros(blocks * SCAN_BLOCK, dtype=dtype)
    factor[:count], offset[:count] = a, b                  # the padding (a = 1, b = 0) changes nothing before it
    # one column per block: each pass of the scan works on whole contiguous rows, into a scratch array
    factor = np.ascontiguousarray(factor.reshape(blocks, SCAN_BLOCK).T)
    offset = np.ascontiguousarray(offset.reshape(blocks, SCAN_BLOCK).T)
    scratch = np.empty_like(factor)
    span = 1
    while span < SCAN_BLOCK:                                 # each block's maps composed from its start
        np.multiply(factor[span:], offset[:-span], out=scratch[span:])
        np.add(scratch[span:], offset[span:], out=offset[span:])
        np.multiply(factor[span:], factor[:-span], out=scratch[span:])
        factor, scratch = scratch, factor
        factor[:span] = scratch[:span]
        span *= 2
    starts = _scan(factor[-1], offset[-1], initial, dtype)    # z at each block's start
    values = np.empty(count + 1, dtype=dtype)
    values[0] = initial
    np.multiply(factor, starts[:-1], out=factor)
    factor += offset
    values[1:] = factor.T.ravel()[:count]
    return values


def _scan(a: np.ndarray, b: np.ndarray, initial, dtype) -> np.ndarray:
    """:func:`linear_recurrence` as one Hillis-Steele scan over all the samples."""
    factor = np.empty(a.size + 1, dtype=dtype)
    offset = np.empty(a.size + 1, dtype=dtype)
    factor[0], offset[0] = 0.0, initial
    factor[1:], offset[1:] = a, b
    span = 1
    while span < factor.size:
        offset[span:] = factor[span:] * offset[:-span] + offset[span:]
        factor[span:] = factor[span:] * factor[:-span]
        span *= 2
    return offset
