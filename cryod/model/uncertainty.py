"""What an identified model is not sure of: its fitted parameters, their standard uncertainties and correlations.

``cryod identify`` fits a model in a parametric form: the heater-to-thermometer
path as a sum of first-order terms ``sum_i g_i / (tau_i s + 1)`` (G2 G1), the
heater-to-PTC-stage path likewise (G3), the complex gain of the cooler's line
from T5 to T2 (which gives the link G_link), the operating point and the
cooler's fundamental. :class:`ModelUncertainty` holds those parameters' values,
standard uncertainties (1 sigma) and correlation matrix; the model file keeps
them in its optional ``uncertainty`` section (:mod:`cryod.model.model_file`).

:func:`apply_parameters` rebuilds the model's transfer functions from a set of
parameter values, so anything computed from a model (a prediction, the
feedforward's limit) can be given an uncertainty by evaluating it on models
drawn from the parameters' distribution (:meth:`ModelUncertainty.sampled_models`).
A model whose transfer functions no longer follow from its stated parameters
(edited by hand after identification) is refused by :func:`check_consistent`.

Parameter names
---------------
``heater_to_thermometer.time_constant_s.K``, ``heater_to_thermometer.gain_K_per_W.K``
    Term K (1 = shortest time constant) of G2 G1; G2 is the shortest term's lag.
``heater_to_ptc_stage.time_constant_s.K``, ``heater_to_ptc_stage.gain_K_per_W.K``
    Term K of G3.
``ptc_line.T2_over_T5_real``, ``ptc_line.T2_over_T5_imaginary``
    T2's line over T5's line at the fundamental (complex amplitudes).
``operating_point.flange_temperature_K``, ``operating_point.ptc_stage_temperature_K``
``ptc.angular_frequency_rad_s``, ``ptc.ptc_stage_amplitude_K``, ``ptc.phase_rad``

Examples
--------
>>> from cryod.model import load_model
>>> model = load_model()
>>> values = {"heater_to_thermometer.time_constant_s.1": 26.48, "heater_to_thermometer.gain_K_per_W.1": 1.2,
...           "heater_to_thermometer.time_constant_s.2": 165.41, "heater_to_thermometer.gain_K_per_W.2": 5.6}
>>> rebuilt = apply_parameters(model, values)
>>> [round(float(t), 2) for t in rebuilt.heater_to_thermometer.time_constants_s], round(rebuilt.heater_to_thermometer.dc_gain, 2)
([165.41, 26.48], 6.8)
"""

from __future__ import annotations

import cmath
import dataclasses
import math
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Iterator

import numpy as np

from cryod.model.transfer_function import TransferFunction, first_order_link

if TYPE_CHECKING:
    from cryod.model.parameters import CryostatModel

_TERM = re.compile(r"^(heater_to_thermometer|heater_to_ptc_stage)\.(time_constant_s|gain_K_per_W)\.([1-9][0-9]*)$")
#: Parameters that are not terms of a heater path.
SCALAR_PARAMETERS = (
    "ptc_line.T2_over_T5_real", "ptc_line.T2_over_T5_imaginary",
    "operating_point.flange_temperature_K", "operating_point.ptc_stage_temperature_K",
    "ptc.angular_frequency_rad_s", "ptc.ptc_stage_amplitude_K", "ptc.phase_rad",
)
#: Largest relative difference between a model's transfer-function coefficients and those
#: rebuilt from its stated parameters that still counts as the same model.
CONSISTENCY_TOLERANCE = 1e-7


class UncertaintyError(ValueError):
    """Parameters that do not describe a model (an unknown name, a missing term, a bad correlation)."""


def parameter_known(name: str) -> bool:
    """Whether ``name`` is a parameter this module can rebuild a model from."""
    return name in SCALAR_PARAMETERS or _TERM.match(name) is not None


@dataclass(frozen=True)
class ModelUncertainty:
    """Fitted parameters with standard uncertainties and their correlation.

    Attributes
    ----------
    names : tuple of str
    values : tuple of float
        The fitted values, in the units the names end with.
    standard_uncertainties : tuple of float
        1 sigma, same units.
    correlation : tuple of tuple of float
        Correlation coefficients, symmetric, ones on the diagonal.
    method : str
        How the uncertainties were found (for the reader of the file).
    """

    names: tuple[str, ...]
    values: tuple[float, ...]
    standard_uncertainties: tuple[float, ...]
    correlation: tuple[tuple[float, ...], ...]
    method: str = ""

    def __post_init__(self):
        count = len(self.names)
        if len(set(self.names)) != count:
            raise UncertaintyError("each parameter may appear once")
        for name in self.names:
            if not parameter_known(name):
                raise UncertaintyError(f"unknown parameter {name!r}")
        if len(self.values) != count or len(self.standard_uncertainties) != count:
            raise UncertaintyError("every parameter needs a value and a standard uncertainty")
        if any(not math.isfinite(v) for v in self.values):
            raise UncertaintyError("values must be finite")
        if any(not (math.isfinite(s) and s >= 0.0) for s in self.standard_uncertainties):
            raise UncertaintyError("standard uncertainties must be finite and not negative")
        matrix = np.asarray(self.correlation, dtype=float)
        if matrix.shape != (count, count):
            raise UncertaintyError(f"the correlation matrix must be {count} x {count}, one row per parameter")
        if not np.all(np.isfinite(matrix)) or np.any(np.abs(matrix) > 1.0 + 1e-9):
            raise UncertaintyError("correlation coefficients must lie within -1..1")
        if not np.allclose(matrix, matrix.T, atol=1e-6) or not np.allclose(np.diag(matrix), 1.0, atol=1e-6):
            raise UncertaintyError("the correlation matrix must be symmetric with ones on its diagonal")
        object.__setattr__(self, "values", tuple(float(v) for v in self.values))
        object.__setattr__(self, "standard_uncertainties", tuple(float(s) for s in self.standard_uncertainties))
        object.__setattr__(self, "correlation", tuple(tuple(float(c) for c in row) for row in matrix))

    @classmethod
    def from_covariance(cls, names, values, covariance, method: str = "") -> "ModelUncertainty":
        """From a covariance matrix (units squared)."""
        covariance = np.asarray(covariance, dtype=float)
        sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
        scale = np.where(sigma > 0.0, sigma, 1.0)
        correlation = covariance / np.outer(scale, scale)
        correlation[np.diag_indices_from(correlation)] = 1.0
        return cls(tuple(names), tuple(float(v) for v in values), tuple(float(s) for s in sigma),
                   tuple(map(tuple, np.clip(correlation, -1.0, 1.0))), method)

    @property
    def covariance(self) -> np.ndarray:
        """Covariance matrix (units squared)."""
        sigma = np.asarray(self.standard_uncertainties)
        return np.asarray(self.correlation) * np.outer(sigma, sigma)

    def value(self, name: str) -> float:
        return self.values[self.names.index(name)]

    def standard_uncertainty(self, name: str) -> float:
        return self.standard_uncertainties[self.names.index(name)]

    def as_dict(self) -> dict[str, float]:
        """Parameter values by name."""
        return dict(zip(self.names, self.values))

    def draws(self, count: int, seed: int | None = 0) -> Iterator[dict[str, float]]:
        """``count`` parameter sets drawn from the multivariate normal distribution the uncertainties state."""
        generator = np.random.default_rng(seed)
        samples = generator.multivariate_normal(np.asarray(self.values), self.covariance, size=count,
                                                method="eigh", check_valid="ignore")
        for sample in samples:
            yield dict(zip(self.names, (float(v) for v in sample)))

    def sampled_models(self, model: "CryostatModel", count: int, seed: int | None = 0) -> Iterator["CryostatModel"]:
        """Models rebuilt from ``count`` drawn parameter sets (draws that give an unstable path are skipped)."""
        for values in self.draws(count, seed):
            try:
                yield apply_parameters(model, values)
            except (ValueError, ArithmeticError):
                continue

    def propagate(self, function, model: "CryostatModel", step: float = 1e-4) -> tuple[float, float]:
        """Value and standard uncertainty of ``function(model)`` (a float) by linear propagation.

        The derivative by each parameter is a central difference of
        ``step`` times its standard uncertainty.
        """
        centre = float(function(apply_parameters(model, self.as_dict())))
        gradient = np.zeros(len(self.names))
        for index, (name, sigma) in enumerate(zip(self.names, self.standard_uncertainties)):
            if sigma <= 0.0:
                continue
            delta = step * sigma
            values = self.as_dict()
            values[name] = self.values[index] + delta
            upper = float(function(apply_parameters(model, values)))
            values[name] = self.values[index] - delta
            lower = float(function(apply_parameters(model, values)))
            gradient[index] = (upper - lower) / (2.0 * delta)
        variance = float(gradient @ self.covariance @ gradient)
        return centre, math.sqrt(max(variance, 0.0))


# ---------------------------------------------------------------------------
# from parameters to a model
# ---------------------------------------------------------------------------
def terms_of(values: dict[str, float], path: str) -> list[tuple[float, float]]:
    """(time constant, gain) of each term of ``path`` in ``values``, in the terms' order; [] when absent."""
    found: dict[int, dict[str, float]] = {}
    for name, value in values.items():
        match = _TERM.match(name)
        if match and match.group(1) == path:
            found.setdefault(int(match.group(3)), {})[match.group(2)] = value
    if not found:
        return []
    if sorted(found) != list(range(1, len(found) + 1)):
        raise UncertaintyError(f"{path}: terms must be numbered 1..{len(found)} without gaps, got {sorted(found)}")
    terms = []
    for index in range(1, len(found) + 1):
        term = found[index]
        if set(term) != {"time_constant_s", "gain_K_per_W"}:
            raise UncertaintyError(f"{path}: term {index} needs both time_constant_s and gain_K_per_W")
        terms.append((term["time_constant_s"], term["gain_K_per_W"]))
    return terms


def sum_of_lags(terms: list[tuple[float, float]]) -> TransferFunction:
    """``sum_i g_i / (tau_i s + 1)`` as one rational transfer function."""
    numerator: np.ndarray = np.zeros(1)
    denominator: np.ndarray = np.ones(1)
    for tau, gain in terms:
        lag = np.array([tau, 1.0])
        numerator = np.polyadd(np.polymul(numerator, lag), gain * denominator)
        denominator = np.polymul(denominator, lag)
    return TransferFunction(tuple(numerator), tuple(denominator))


def thermometer_paths(terms: list[tuple[float, float]]) -> tuple[TransferFunction, TransferFunction]:
    """(G2, G1) from the terms of G2 G1: G2 is the shortest term's lag, G1 the rest times its inverse.

    ``G1 = (tau_1 s + 1) sum_i g_i / (tau_i s + 1) = g_1 + sum_{i>1} g_i (tau_1 s + 1) / (tau_i s + 1)``.
    """
    ordered = sorted(terms)
    shortest, gain = ordered[0]
    flange_to_thermometer = TransferFunction((1.0,), (shortest, 1.0))
    numerator = np.array([gain])
    denominator = np.ones(1)
    for tau, term_gain in ordered[1:]:
        lag = np.array([tau, 1.0])
        numerator = np.polyadd(np.polymul(numerator, lag), term_gain * np.polymul(np.array([shortest, 1.0]),
                                                                                  denominator))
        denominator = np.polymul(denominator, lag)
    return flange_to_thermometer, TransferFunction(tuple(numerator), tuple(denominator))


def link_from_line_gain(model: "CryostatModel", flange_to_thermometer: TransferFunction,
                        line_gain: complex) -> TransferFunction:
    """G_link from T2's line over T5's line at the fundamental.

    The T5 line is ``B sin(theta)``; the heat it drives is ``q = C dT5/dt``,
    so T2's line is ``G2 G_link (j w C)`` times it: ``G_link(j w) = line_gain / (j w C G2(j w))``.
    The link is the first-order form with that value at the line.
    """
    omega = model.ptc.angular_frequency_rad_s
    capacity = model.ptc.heat_capacity_J_per_K
    value = line_gain / (1j * omega * capacity * complex(flange_to_thermometer.frequency_response(omega)))
    return first_order_link(value, omega)


def apply_parameters(model: "CryostatModel", values: dict[str, float]) -> "CryostatModel":
    """``model`` with whatever ``values`` give replaced.

    Parameters
    ----------
    model : CryostatModel
        Gives everything the parameters do not: the PTC heat capacity, the
        harmonics, the effects, the sensor noise.
    values : dict of str to float
        Parameter values by name (see the module's list). The heater-to-T2
        terms replace G2 and G1; the heater-to-T5 terms replace G3; the line
        gain replaces G_link (computed with the new G2 and the new frequency).

    Returns
    -------
    CryostatModel
    """
    unknown = [name for name in values if not parameter_known(name)]
    if unknown:
        raise UncertaintyError(f"unknown parameter(s): {', '.join(unknown)}")
    changes: dict = {}
    point = model.operating_point
    if "operating_point.flange_temperature_K" in values or "operating_point.ptc_stage_temperature_K" in values:
        changes["operating_point"] = dataclasses.replace(
            point,
            flange_temperature_K=values.get("operating_point.flange_temperature_K", point.flange_temperature_K),
            ptc_stage_temperature_K=values.get("operating_point.ptc_stage_temperature_K",
                                               point.ptc_stage_temperature_K))
    ptc_changes: dict[str, Any] = {key: values[f"ptc.{key}"]
                                   for key in ("angular_frequency_rad_s", "ptc_stage_amplitude_K", "phase_rad")
                                   if f"ptc.{key}" in values}
    if ptc_changes:
        changes["ptc"] = dataclasses.replace(model.ptc, **ptc_changes)
    flange_terms = terms_of(values, "heater_to_thermometer")
    if flange_terms:
        changes["flange_to_thermometer"], changes["heater_to_flange"] = thermometer_paths(flange_terms)
    stage_terms = terms_of(values, "heater_to_ptc_stage")
    if stage_terms:
        changes["heater_to_ptc_stage"] = sum_of_lags(stage_terms)
    updated = dataclasses.replace(model, **changes)
    if "ptc_line.T2_over_T5_real" in values or "ptc_line.T2_over_T5_imaginary" in values:
        if not {"ptc_line.T2_over_T5_real", "ptc_line.T2_over_T5_imaginary"} <= set(values):
            raise UncertaintyError("the line gain needs both ptc_line.T2_over_T5_real and _imaginary")
        gain = complex(values["ptc_line.T2_over_T5_real"], values["ptc_line.T2_over_T5_imaginary"])
        updated = dataclasses.replace(updated, ptc_to_flange=link_from_line_gain(
            updated, updated.flange_to_thermometer, gain))
    return updated


def line_gain_of(model: "CryostatModel") -> complex:
    """T2's line over T5's line at the model's fundamental (complex), without effects."""
    omega = model.ptc.angular_frequency_rad_s
    return complex(model.ptc_heat_to_thermometer.frequency_response(omega)) * 1j * omega \
        * model.ptc.heat_capacity_J_per_K


def _same_function(a: TransferFunction, b: TransferFunction) -> bool:
    if len(a.numerator) != len(b.numerator) or len(a.denominator) != len(b.denominator):
        return False
    scale = b.denominator[-1] / a.denominator[-1] if a.denominator[-1] else 1.0
    pairs = list(zip(a.numerator, b.numerator)) + list(zip(a.denominator, b.denominator))
    size = max(max(abs(x) for x in a.numerator + a.denominator), 1e-300)
    return all(abs(x * scale - y) <= CONSISTENCY_TOLERANCE * max(abs(y), size * 1e-6) for x, y in pairs)


def inconsistencies(model: "CryostatModel", uncertainty: ModelUncertainty) -> list[str]:
    """What in ``model`` does not follow from the stated parameter values ([] when all does)."""
    rebuilt = apply_parameters(model, uncertainty.as_dict())
    found = []
    for key in ("heater_to_flange", "flange_to_thermometer", "heater_to_ptc_stage", "ptc_to_flange"):
        if not _same_function(getattr(model, key), getattr(rebuilt, key)):
            found.append(f"transfer_functions.{key}")
    for group in ("operating_point", "ptc"):
        if getattr(model, group) != getattr(rebuilt, group):
            found.append(group)
    return found


def check_consistent(model: "CryostatModel", uncertainty: ModelUncertainty) -> None:
    """Raise :class:`UncertaintyError` when the model's values do not follow from the stated parameters."""
    found = inconsistencies(model, uncertainty)
    if found:
        raise UncertaintyError(f"{', '.join(found)} do not follow from the stated parameter values (the model was "
                               "changed after identification): identify it again, or remove the uncertainty section")


def magnitude_and_lag(line_gain: complex) -> tuple[float, float]:
    """|T2/T5| and T2's lag behind T5 (rad) of a line gain."""
    return abs(line_gain), -cmath.phase(line_gain)


__all__ = ["ModelUncertainty", "UncertaintyError", "apply_parameters", "check_consistent", "inconsistencies",
           "line_gain_of", "link_from_line_gain", "magnitude_and_lag", "parameter_known", "sum_of_lags",
           "terms_of", "thermometer_paths", "SCALAR_PARAMETERS"]
