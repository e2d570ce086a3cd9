"""Recalibration: the base model's own parameters refitted to the record, within the model's structure.

Real records never come from exactly the shipped model: its gains and time
constants are known to a few percent (the paper's own numbers differ by that
much among themselves), and at 20 µK of noise over an hour a 1 % error of a
mode's gain is a discrepancy of thousands of standard errors. Before any cause
is looked for, the analysis refits the parameters the model's structure
already has, on the fit blocks, the way ``cryod identify`` does:

==============================  ====================================================================
parameter                       what it is
==============================  ====================================================================
heater_to_flange static gain    G1 at s = 0 (K/W)
heater_to_flange zero/pole      each real time constant of G1's numerator and denominator (s)
flange_to_thermometer pole      G2's time constant (s)
heater_to_ptc_stage gain, pole  G3 (K/W, s)
line gain on T2                 the link's gain: T2's line amplitude over T5's
line phase on T2                every time constant of the link scaled together: T2's lag behind T5
==============================  ====================================================================

(the operating point, the state at the first sample and the cooler's line
are fitted in every replay anyway: :mod:`cryod.analysis.replay`). Each
parameter is a factor ``exp(x)`` on its shipped value.

**What a recalibration may do.** Each factor is held within a tolerance:
:data:`TOLERANCE` (10 %) on gains and time constants, and for the link's time
scale whatever moves the line's phase on T2 by :data:`LINE_PHASE_TOLERANCE_RAD`
(0.1 rad). A record that needs more is not a recalibration: the misfit that is
left is for the causes (:mod:`cryod.analysis.candidates`) to explain. Within
the tolerance a penalty ``sum((x / tolerance)^2)`` (at most 1 per parameter)
decides between fits the data cannot tell apart: the smaller change is taken,
so an effect that has the same signature as a recalibration (a link whose phase
differs, a thermometer that lags) is fitted as the effect.

**How.** Gauss-Newton: at the present factors, the change of the predicted T2
and T5 per unit of each ``x`` (forward differences of the simulator over the
whole record) is a :class:`cryod.analysis.replay.LinearBasis`, fitted with the
nuisance parameters by one bounded least-squares solve; the factors move by
the result and the columns are taken again, until no factor moves by more than
1e-4. Every later replay (the candidates) fits the same basis, so a cause and
the recalibration are fitted together and the recalibration never absorbs an
effect it cannot represent: a dead time is fitted as a dead time, with the time
constants free alongside.

Examples
--------
>>> from cryod.model import load_model
>>> model = load_model()
>>> [parameter.name for parameter in structure_parameters(model)][-3:]
['heater_to_ptc_stage time constant', 'line gain on T2', 'line phase on T2']
>>> changed = with_factors(model, structure_parameters(model), [0.01, 0, 0, 0, 0, 0, 0, 0])
>>> round(changed.heater_to_flange.dc_gain / model.heater_to_flange.dc_gain, 4)
1.0101
"""

from __future__ import annotations

import cmath
import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import optimize

from cryod.analysis.replay import LinearBasis, Replay, Replayer, flange_mode_columns, stage_release_response
from cryod.cooler.line import PtcLine
from cryod.model import CryostatModel
from cryod.model.transfer_function import TransferFunction

#: Largest change of a gain or a time constant a recalibration may make (relative, as log factor).
TOLERANCE = 0.10
#: Largest change of the line's phase on T2 the link's time scale may make (rad).
LINE_PHASE_TOLERANCE_RAD = 0.10


@dataclass(frozen=True)
class Tolerances:
    """How far a recalibration may move the base model's parameters.

    Attributes
    ----------
    relative : float
        Largest |log factor| of a gain or a time constant.
    line_phase_rad : float
        Largest change of the line's phase on T2 (rad) the link's time scale may make.
    """

    relative: float = TOLERANCE
    line_phase_rad: float = LINE_PHASE_TOLERANCE_RAD


#: The recalibration's tolerances (what a base model's parameters are expected to be off by).
USUAL = Tolerances()
#: Largest log factor of the link's time scale, whatever its phase sensitivity.
LARGEST_TIME_SCALE = 0.5
#: Forward-difference step of the columns (log factor).
DIFFERENCE_STEP = 1e-3
#: Gauss-Newton stops when no factor moves by more than this, or after this many steps.
CONVERGED_STEP = 1e-4
MOST_STEPS = 8

#: Transfer functions of the model and whether their static gain is recalibrated (G2's is 1 by definition).
PATHS = (("heater_to_flange", True), ("flange_to_thermometer", False), ("heater_to_ptc_stage", True),
         ("ptc_to_flange", True))
#: The link's parameters: the line's amplitude and phase on T2 (a link cause replaces them).
LINK_PARAMETERS = ("line gain on T2", "line phase on T2")


@dataclass(frozen=True)
class StructureParameter:
    """One parameter of the model's structure that a recalibration may change.

    Attributes
    ----------
    name : str
        ``"<transfer function> static gain"``, ``"... zero time constant"``,
        ``"... time constant"`` (a pole), ``"line gain on T2"`` (the link's
        gain) or ``"line phase on T2"`` (the link's time constants scaled together).
    path : str
        The transfer function's attribute of :class:`cryod.model.CryostatModel`.
    kind : str
        ``"gain"``, ``"zero"``, ``"pole"`` or ``"time_scale"``.
    index : int
        Which zero or pole (by time constant, largest first).
    unit : str
    shipped : float
        Its value in the base model: K/W, s; for the line, T2's line amplitude over T5's and T2's lag
        behind T5 (rad).
    tolerance : float
        Largest |log factor| a recalibration may apply.
    """

    name: str
    path: str
    kind: str
    index: int
    unit: str
    shipped: float
    tolerance: float


def _real_time_constants(roots: np.ndarray) -> list[float] | None:
    """Time constants -1/r of real roots (largest first); None if a root is complex or zero."""
    if np.any(np.abs(roots.imag) > 1e-9 * np.maximum(np.abs(roots), 1e-300)) or np.any(roots == 0):
        return None
    return sorted((-1.0 / r.real for r in roots), key=lambda tau: -abs(tau))


def _factored(transfer_function: TransferFunction):
    """(static gain, zero time constants, pole time constants), or None without that form."""
    zeros = _real_time_constants(np.roots(transfer_function.numerator).astype(complex)) \
        if len(transfer_function.numerator) > 1 else []
    poles = _real_time_constants(transfer_function.poles)
    if zeros is None or poles is None or transfer_function.dc_gain == 0.0:
        return None
    return transfer_function.dc_gain, zeros, poles


def _from_factored(gain: float, zeros, poles) -> TransferFunction:
    numerator, denominator = np.array([gain]), np.array([1.0])
    for tau in zeros:
        numerator = np.polymul(numerator, [tau, 1.0])
    for tau in poles:
        denominator = np.polymul(denominator, [tau, 1.0])
    return TransferFunction(tuple(numerator), tuple(denominator))


def _phase_per_time_scale(link: TransferFunction, angular_frequency_rad_s: float) -> float:
    """d arg(link(j omega)) / d(log time scale) at the line (rad)."""
    step = 1e-4
    before = link.frequency_response(angular_frequency_rad_s)
    after = link.frequency_response(angular_frequency_rad_s * math.exp(step))
    return cmath.phase(after / before) / step


def _time_scale_tolerance(link: TransferFunction, model: CryostatModel, line_phase_rad: float) -> float:
    """Largest |log time scale| of the link that moves its phase at the line by at most the tolerance,
    either way (the smaller of the two scales that move it by exactly the tolerance)."""
    omega = model.ptc.angular_frequency_rad_s
    reference = link.frequency_response(omega)

    def shift(x):
        return abs(cmath.phase(link.frequency_response(omega * math.exp(x)) / reference))

    limits = []
    for direction in (1.0, -1.0):
        if shift(direction * LARGEST_TIME_SCALE) <= line_phase_rad:
            limits.append(LARGEST_TIME_SCALE)
            continue
        limits.append(optimize.brentq(lambda x: shift(direction * x) - line_phase_rad, 0.0,
                                      LARGEST_TIME_SCALE, xtol=1e-10))
    return float(min(limits))


def structure_parameters(model: CryostatModel, tolerances: Tolerances = USUAL) -> list[StructureParameter]:
    """The parameters of ``model``'s structure a recalibration may change, with their tolerances.

    A transfer function whose zeros or poles are not all real keeps its time
    constants (only its gain is recalibrated).
    """
    found = []
    for path, with_gain in PATHS:
        transfer_function = getattr(model, path)
        factored = _factored(transfer_function)
        if path == "ptc_to_flange":
            line = line_on_flange(model)
            found.append(StructureParameter("line gain on T2", path, "gain", 0, "K/K", abs(line),
                                            tolerances.relative))
            sensitivity = abs(_phase_per_time_scale(transfer_function, model.ptc.angular_frequency_rad_s))
            if factored is not None and sensitivity > 0.0:
                found.append(StructureParameter("line phase on T2", path, "time_scale", 0, "rad",
                                                -cmath.phase(line),
                                                _time_scale_tolerance(transfer_function, model,
                                                                      tolerances.line_phase_rad)))
            continue
        if with_gain:
            found.append(StructureParameter(f"{path} static gain", path, "gain", 0, "K/W",
                                            transfer_function.dc_gain, tolerances.relative))
        if factored is None:
            continue
        _, zeros, poles = factored
        for index, tau in enumerate(zeros):
            name = f"{path} zero time constant" if len(zeros) == 1 else f"{path} zero time constant {index + 1}"
            found.append(StructureParameter(name, path, "zero", index, "s", tau, tolerances.relative))
        for index, tau in enumerate(poles):
            name = f"{path} time constant" if len(poles) == 1 else f"{path} time constant {index + 1}"
            found.append(StructureParameter(name, path, "pole", index, "s", tau, tolerances.relative))
    return found


def _time_scaled_by_phase(link: TransferFunction, phase_change_rad: float, angular_frequency_rad_s: float):
    """``link`` time-scaled so that its phase at the frequency moves by ``phase_change_rad`` (Newton)."""
    per_unit = _phase_per_time_scale(link, angular_frequency_rad_s)
    if per_unit == 0.0 or phase_change_rad == 0.0:
        return link
    reference = link.frequency_response(angular_frequency_rad_s)
    factor = 0.0
    for _ in range(8):
        moved = cmath.phase(link.frequency_response(angular_frequency_rad_s * math.exp(factor)) / reference)
        step = (phase_change_rad - moved) / per_unit
        factor += step
        if abs(step) < 1e-13:
            break
    return link.time_scaled(math.exp(factor))


def with_factors(model: CryostatModel, parameters, log_factors) -> CryostatModel:
    """``model`` with each parameter multiplied by ``exp(log_factor)``.

    The line on T2 belongs to the link's parameters alone: when G2 changes, the
    link is changed by the inverse of G2's change at the line (gain and phase),
    so that G2's time constant is the heater path's and the line's gain and
    phase are the link's two parameters.
    """
    changes: dict[str, list] = {}
    for parameter, x in zip(parameters, log_factors):
        changes.setdefault(parameter.path, []).append((parameter, float(x)))
    replaced: dict[str, Any] = {}           # transfer functions by the model's field names, for dataclasses.replace
    for path, items in changes.items():
        original = getattr(model, path)
        factored = _factored(original)
        if factored is None:
            gain = math.exp(sum(x for parameter, x in items if parameter.kind == "gain"))
            replaced[path] = TransferFunction(tuple(gain * c for c in original.numerator), original.denominator)
            continue
        gain, zeros, poles = factored
        zeros, poles = list(zeros), list(poles)
        for parameter, x in items:
            factor = math.exp(x)
            if parameter.kind == "gain":
                gain *= factor
            elif parameter.kind == "zero":
                zeros[parameter.index] *= factor
            elif parameter.kind == "pole":
                poles[parameter.index] *= factor
            else:
                zeros = [tau * factor for tau in zeros]
                poles = [tau * factor for tau in poles]
        replaced[path] = _from_factored(gain, zeros, poles)
    if "flange_to_thermometer" in replaced:
        omega = model.ptc.angular_frequency_rad_s
        ratio = model.flange_to_thermometer.frequency_response(omega) \
            / replaced["flange_to_thermometer"].frequency_response(omega)
        link = replaced.get("ptc_to_flange", model.ptc_to_flange)
        target = link.frequency_response(omega) * ratio
        link = _time_scaled_by_phase(link, cmath.phase(ratio), omega)
        gain = abs(target) / abs(link.frequency_response(omega))
        replaced["ptc_to_flange"] = TransferFunction(tuple(gain * c for c in link.numerator), link.denominator)
    return dataclasses.replace(model, **replaced)


def line_on_flange(model: CryostatModel, angular_frequency_rad_s: float | None = None) -> complex:
    """T2's line over T5's at the model's line frequency (or the one given; complex): j G2 G_link C omega.

    T5's line is ``B sin(theta)``, the heat it drives ``C omega B cos(theta)``,
    so T2's line is ``Re(G2 G_link(j omega) C omega B exp(j theta))`` and its
    ratio to T5's is ``j G2 G_link C omega``; T2 lags T5 by minus its phase.
    """
    omega = angular_frequency_rad_s or model.ptc.angular_frequency_rad_s
    return 1j * model.ptc_heat_to_thermometer.frequency_response(omega) * model.ptc.heat_capacity_J_per_K * omega


def fitted_value(parameter: StructureParameter, model: CryostatModel, log_factor: float) -> float:
    """The parameter's value in the recalibrated ``model`` (K/W, s; the line's gain and lag)."""
    if parameter.path == "ptc_to_flange":
        line = line_on_flange(model)
        return abs(line) if parameter.kind == "gain" else -cmath.phase(line)
    return parameter.shipped * math.exp(log_factor)


def linear_basis(replayer: Replayer, base: RecalibratedBase, line: PtcLine | None, state: Replay | None = None,
                 apply=None) -> LinearBasis:
    """Columns of the change of T2 and T5 per unit log factor, at ``base``'s log factors.

    The prediction differentiated is the simulation plus the record's state at
    the first sample as ``state`` fitted it (each T2 mode's free decay and
    T5's settling): the modes decay with the model's own time constants, so a
    changed time constant changes them too (without this, a record whose start
    is fitted with large mode amplitudes would see a freedom the model does
    not have).

    Parameters
    ----------
    replayer : Replayer
    base : RecalibratedBase
        The base model (factors 0), the structure's parameters and the log factors where the columns are taken.
    line : PtcLine or None
        The measured line the replays use.
    state : Replay, optional
        A replay at the log factors whose fitted initial state is held (default: none).
    apply : callable, optional
        ``apply(model)``: what to add to the recalibrated model before
        simulating (a cause's effect), default nothing.
    """
    model, parameters = base.shipped, base.parameters
    log_factors = np.asarray(base.log_factors, dtype=float)
    data = replayer.data
    cycle = line.cycle if line is not None else None

    def aligned_at(x):
        changed = with_factors(model, parameters, x)
        if apply is not None:
            changed = apply(changed)
        return line.applied_to(changed) if line is not None else changed

    def with_state(aligned, flange, stage):
        if state is not None:
            modes = flange_mode_columns(aligned, data.elapsed_s, data.sample_interval_s)
            if modes.shape[1] == state.initial_mode_amplitudes_K.size:
                flange = flange + modes @ state.initial_mode_amplitudes_K
            stage = stage + stage_release_response(aligned, data.elapsed_s) * state.initial_power_offset_w
        return flange, stage

    def simulated(x):
        aligned = aligned_at(x)
        result = replayer.simulate(aligned, cycle=cycle)
        return with_state(aligned, result.flange_K, result.ptc_stage_K)

    aligned = aligned_at(log_factors)
    whole = replayer.simulate(aligned, cycle=cycle)
    flange, stage = with_state(aligned, whole.flange_K, whole.ptc_stage_K)
    flange_columns = np.empty((flange.size, len(parameters)))
    stage_columns = np.empty((flange.size, len(parameters)))
    # A gain scales its own path's output exactly (unless the time constants depend on that output): its column
    # is that output, from one simulation without the line, instead of a simulation per gain.
    parts = None
    if aligned.effects.heat_capacity_temperature is None:
        quiet = aligned.with_ptc(ptc_stage_amplitude_K=0.0, harmonics=())
        heater_only = replayer.simulate(quiet)
        point = quiet.operating_point
        parts = {"heater_to_flange": (heater_only.flange_K - point.flange_temperature_K, 0.0),
                 "heater_to_ptc_stage": (0.0, heater_only.ptc_stage_K - point.ptc_stage_temperature_K
                                         + (stage_release_response(aligned, data.elapsed_s)
                                            * state.initial_power_offset_w if state is not None else 0.0)),
                 "ptc_to_flange": (whole.flange_K - heater_only.flange_K, 0.0)}
    for index, parameter in enumerate(parameters):
        if parts is not None and parameter.kind == "gain" and parameter.path in parts:
            flange_columns[:, index], stage_columns[:, index] = parts[parameter.path]
            continue
        moved = log_factors.copy()
        moved[index] += DIFFERENCE_STEP
        moved_flange, moved_stage = simulated(moved)
        flange_columns[:, index] = (moved_flange - flange) / DIFFERENCE_STEP
        stage_columns[:, index] = (moved_stage - stage) / DIFFERENCE_STEP
    tolerances = np.array([parameter.tolerance for parameter in parameters])
    return LinearBasis(tuple(parameter.name for parameter in parameters), flange_columns, stage_columns,
                       log_factors.copy(), -tolerances, tolerances, tolerances)


@dataclass(frozen=True)
class RecalibratedBase:
    """A base model and log factors on its structure's parameters: the recalibrated model, lazily.

    Attributes
    ----------
    shipped : CryostatModel
        The model as given (factors 0).
    parameters : tuple of StructureParameter
    log_factors : numpy.ndarray
    """

    shipped: CryostatModel
    parameters: tuple
    log_factors: np.ndarray

    def model(self, without=()) -> CryostatModel:
        """The recalibrated model, with the named parameters left at their shipped values."""
        x = np.array([0.0 if parameter.name in without else value
                      for parameter, value in zip(self.parameters, self.log_factors)])
        return with_factors(self.shipped, self.parameters, x)


@dataclass(frozen=True)
class RecalibratedParameter:
    """One parameter of the recalibration: shipped and fitted value, uncertainty, significance."""

    parameter: str
    unit: str
    shipped: float
    fitted: float
    uncertainty: float
    significance: float
    at_tolerance: bool = False

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class Recalibration:
    """The base model refitted within its structure.

    Attributes
    ----------
    parameters : list of StructureParameter
    log_factors : numpy.ndarray
        The fitted factors (log).
    uncertainties : numpy.ndarray
        Standard error of each log factor (from the data alone).
    model : CryostatModel
        The base model with the fitted factors.
    replay : Replay
        The record replayed with it.
    steps : int
        Gauss-Newton steps taken.
    shipped : CryostatModel
        The base model as given.
    """

    parameters: list
    log_factors: np.ndarray
    uncertainties: np.ndarray
    model: CryostatModel
    replay: Replay
    steps: int
    shipped: CryostatModel

    @property
    def base(self) -> RecalibratedBase:
        return RecalibratedBase(self.shipped, tuple(self.parameters), self.log_factors)

    @classmethod
    def refitted(cls, base: RecalibratedBase, replay: Replay) -> "Recalibration":
        """The recalibration as refitted with the causes: ``base``'s factors, the uncertainties from ``replay``
        (whose fit had the recalibration's columns; a parameter a cause replaced has none)."""
        errors = np.full(len(base.parameters), np.nan)
        if replay.basis is not None and replay.normal_inverse is not None:
            count = len(replay.basis.names)
            diagonal = np.diag(replay.normal_inverse)[-count:]
            for name, variance in zip(replay.basis.names, diagonal):
                names = [parameter.name for parameter in base.parameters]
                if name in names:
                    errors[names.index(name)] = math.sqrt(max(float(variance), 0.0))
        return cls(list(base.parameters), base.log_factors, errors, base.model(), replay, 0, base.shipped)

    def table(self) -> list[RecalibratedParameter]:
        """Each structure parameter: shipped and fitted value, standard error, significance."""
        rows = []
        for parameter, x, error in zip(self.parameters, self.log_factors, self.uncertainties):
            fitted = fitted_value(parameter, self.model, x)
            if parameter.kind == "time_scale":
                per_unit = abs(_phase_per_time_scale(self.model.ptc_to_flange, self.model.ptc.angular_frequency_rad_s))
                uncertainty = per_unit * float(error)
            else:
                uncertainty = abs(fitted) * float(error)
            rows.append(RecalibratedParameter(
                parameter.name, parameter.unit, parameter.shipped, fitted, uncertainty,
                abs(float(x)) / float(error) if error > 0 else (0.0 if x == 0 else math.inf),
                bool(abs(x) >= parameter.tolerance * (1.0 - 1e-6))))
        return rows


def recalibrate(replayer: Replayer, model: CryostatModel, line: PtcLine | None,
                tolerances: Tolerances = USUAL) -> Recalibration:
    """Refit the structure's parameters of ``model`` on the replayer's fit samples (Gauss-Newton).

    Parameters
    ----------
    replayer : Replayer
        Its noise weights the two thermometers.
    model : CryostatModel
        The base model.
    line : PtcLine or None
        The measured line.
    tolerances : Tolerances
        How far each parameter may move (default: :data:`USUAL`).

    Returns
    -------
    Recalibration
    """
    parameters = structure_parameters(model, tolerances)
    x = np.zeros(len(parameters))
    limits = np.array([parameter.tolerance for parameter in parameters])
    steps = 0
    state = replayer.replay(model, line, basis=None)
    for steps in range(1, MOST_STEPS + 1):
        basis = linear_basis(replayer, RecalibratedBase(model, tuple(parameters), x), line, state)
        replay = replayer.replay(with_factors(model, parameters, x), line, basis=basis)
        change = replay.basis_change
        x = np.clip(x + change, -limits, limits)
        state = replayer.replay(with_factors(model, parameters, x), line, basis=None)
        if np.max(np.abs(change)) <= CONVERGED_STEP:
            break
    basis = linear_basis(replayer, RecalibratedBase(model, tuple(parameters), x), line, state)
    recalibrated = with_factors(model, parameters, x)
    replay = replayer.replay(recalibrated, line, basis=basis)
    count = len(parameters)
    covariance = replay.normal_inverse[-count:, -count:] if replay.normal_inverse is not None else None
    errors = np.sqrt(np.maximum(np.diag(covariance), 0.0)) if covariance is not None else np.full(count, np.nan)
    return Recalibration(parameters, x, errors, recalibrated, replay, steps, model)


__all__ = ["LINK_PARAMETERS", "LINE_PHASE_TOLERANCE_RAD", "TOLERANCE", "USUAL", "RecalibratedBase",
           "RecalibratedParameter", "Recalibration", "Tolerances",
           "StructureParameter", "linear_basis", "recalibrate", "structure_parameters", "with_factors"]
