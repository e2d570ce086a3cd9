"""The candidate causes: each one an extension of the model, fitted to the record.

Every candidate is the base model plus one effect of :mod:`cryod.model`, with
its parameters fitted on the *fit* blocks of the record by the same replay
(:mod:`cryod.analysis.replay`) and the same weighted least squares: the sum of
squared residuals of T2 and T5, each divided by its measured noise. How each
is fitted:

===========================  ===================================================================
cause                        parameters and fit
===========================  ===================================================================
sensor_lag                   flange thermometer time constant: grid (10 ms to 20 s, log) then
                             bounded Brent; the PTC-stage thermometer's follows from it and the
                             phase of the line (:func:`fit_sensor_lag`)
link_dynamics                gain factor and time constant: the PTC path to T2 is linear in the
                             complex factor F = g / (1 + j omega tau) at the line, so F is a
                             linear least-squares coefficient; a lead (tau < 0), which the
                             effect cannot express, refits the link itself as g' / (tau' s + 1)
dead_time                    heater-to-flange delay: grid (0.05 s steps to 2 s, then log to 60 s)
                             then bounded Brent (heater content at the line makes the cost
                             ripple with a 0.58 s period)
heat_capacity_temperature    exponent n of (T / T_ref)^n, T_ref the base model's T2_0: grid
                             then bounded Brent
heater_nonlinearity          quadratic coefficient k: the delivered power P + k P^2 makes every
                             heater path linear in k, so k is a linear least-squares coefficient
                             (response of both thermometers to P^2)
ptc_harmonics                harmonics of T5 up to order 5 (aliased ones too), kept if above 5
                             standard errors (linear fit of T5)
ptc_frequency_drift          the record replayed at the phase measured sample by sample in T5;
                             rate (and wander) are the model's form fitted to that phase
===========================  ===================================================================

When the base model is recalibrated (:mod:`cryod.analysis.recalibration`),
every replay also fits the recalibration linearised about the model
(:attr:`FitContext.basis_for`): a cause and the
recalibration are fitted together. The link cause replaces the line's gain and
phase on T2, which it leaves out. Each fit that has numbers of its own says so
(:class:`EffectForm`), for the joint refit of :mod:`cryod.analysis.refinement`.

The score of each is on the held-out blocks (:mod:`cryod.analysis.decision`).
"""

from __future__ import annotations

import cmath
import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import optimize

from cryod.analysis.recalibration import LINE_PHASE_TOLERANCE_RAD, LINK_PARAMETERS, RecalibratedBase
from cryod.analysis.record_data import RecordData
from cryod.analysis.replay import LinearBasis, Replay, Replayer
from cryod.cooler.line import PtcLine, measurable_orders
from cryod.model import (
    EFFECT_NAMES,
    CryostatModel,
    DeadTime,
    HeatCapacityTemperature,
    HeaterNonlinearity,
    LinkDynamics,
    SensorLag,
)
from cryod.model.cooler_path import CoolerDrive, CoolerPath
from cryod.model.dynamics import flange_transfer_functions
from cryod.model.transfer_function import TransferFunction, TransferFunctionError, first_order_link

#: A PTC-stage thermometer lag shifting the line by less than this (rad) is taken as none: 1e-4 rad of a
#: 1.7 mK line (0.17 µK) is below any record's resolution.
STAGE_LAG_SMALLEST_PHASE_RAD = 1e-4

#: Causes in the order they are tried: the model file's optional effects.
CANDIDATE_CAUSES = EFFECT_NAMES


@dataclass
class FitContext:
    """What every candidate fit needs: the record, its replay machinery, the base model's replay."""

    data: RecordData
    replayer: Replayer
    base_model: CryostatModel
    base_line: PtcLine
    base_replay: Replay
    noise_rms_K: tuple[float, float]
    fit_mask: np.ndarray
    held_out_mask: np.ndarray
    #: The base model's link before recalibration: the link cause is measured against it, since a link that
    #: differs is what the recalibration of the link's gain and time scale moved towards (None: the model's own).
    link_reference: TransferFunction | None = None
    #: The recalibration the context's model carries (None: the base model as given).
    recalibrated: RecalibratedBase | None = None
    #: The model whose heater part of T5 is taken out before the line is measured in it (None: ``base_model``).
    line_model: CryostatModel | None = None
    #: ``basis_for(line)``: the linearised model change (a :class:`~cryod.analysis.replay.LinearBasis`, the
    #: recalibration's) fitted in every replay with that line, or None (see :mod:`cryod.analysis.recalibration`).
    basis_for: Callable[[PtcLine | None], LinearBasis | None] | None = None

    @property
    def recalibration(self) -> RecalibratedBase:
        """The recalibration the context's model carries: the cause search follows causes on a recalibrated model
        (ValueError for a context on the base model as given)."""
        if self.recalibrated is None:
            raise ValueError("the context's model is the base model as given: it carries no recalibration")
        return self.recalibrated

    def basis(self, line: PtcLine | None, without=()) -> LinearBasis | None:
        """The linearised model change fitted in replays with ``line`` (None: none), less ``without``."""
        if self.basis_for is None:
            return None
        basis = self.basis_for(line)
        return basis.without(without) if basis is not None and without else basis

    def replay(self, model: CryostatModel, line: PtcLine | None = None, shared_columns=None, *,
               basis_without=()) -> Replay:
        """The record replayed with ``model`` (see :meth:`cryod.analysis.replay.Replayer.replay`), the context's
        linearised model change fitted alongside, less the parameters ``basis_without``."""
        return self.replayer.replay(model, line, shared_columns, basis=self.basis(line, basis_without))

    def fit_chi_square(self, replay: Replay) -> float:
        """Weighted sum of squares of both thermometers on the fit samples."""
        return sum(self.chi_square(replay, self.fit_mask))

    def chi_square(self, replay: Replay, mask: np.ndarray) -> tuple[float, float]:
        """(T2, T5) sums of squared residuals over ``mask``, each in units of its noise variance."""
        flange = replay.flange_residual_K[mask] / self.noise_rms_K[0]
        stage = replay.ptc_stage_residual_K[mask] / self.noise_rms_K[1]
        return float(flange @ flange), float(stage @ stage)

    def distinctness(self, first: Replay, second: Replay) -> float:
        """How much two replays' predictions differ on the held-out samples: the sum of squares of their
        difference, each thermometer in units of its noise variance (D of :mod:`cryod.analysis.decision`)."""
        mask = self.held_out_mask
        flange = (first.flange_K - second.flange_K)[mask] / self.noise_rms_K[0]
        stage = (first.ptc_stage_K - second.ptc_stage_K)[mask] / self.noise_rms_K[1]
        return float(flange @ flange + stage @ stage)

    def estimated_model(self, model: CryostatModel) -> CryostatModel:
        """``model`` at the record's estimated operating point (what the heat-capacity effect needs)."""
        return dataclasses.replace(model, operating_point=self.base_replay.operating_point)


@dataclass
class CandidateFit:
    """One candidate cause fitted to the record.

    Attributes
    ----------
    cause : str
    parameters : dict
        Fitted parameters, names with units.
    extended_model : CryostatModel
        The base model plus the fitted effect (what is written to the model file).
    replay : Replay
        The record replayed with it.
    line : PtcLine
        The measured line the replay used.
    note : str
        How the fit went, in words.
    parameter_count : int
        Parameters actually fitted (decides a tie between candidates).
    effect : EffectForm or None
        The effect as a vector of numbers, for refitting it jointly with the
        recalibration (:mod:`cryod.analysis.refinement`); None when the
        effect is measured (the cooler's own line) or has no such form.
    excluded : tuple of str
        Recalibration parameters this cause replaces (left out of its replays).
    """

    cause: str
    parameters: dict
    extended_model: CryostatModel
    replay: Replay
    line: PtcLine
    note: str = ""
    parameter_count: int = 1
    effect: "EffectForm | None" = None
    excluded: tuple = ()

    @property
    def at_limit(self) -> bool:
        """Whether the effect's values sit at a physical limit of the effect (:attr:`EffectForm.at_limit`)."""
        effect = self.effect
        return bool(effect is not None and effect.at_limit is not None and effect.at_limit(effect.values))


@dataclass(frozen=True)
class EffectForm:
    """An effect as numbers: its values, their bounds and steps, and how to put it into a model.

    Attributes
    ----------
    values : tuple of float
    lower, upper : tuple of float
        Bounds of each value.
    steps : tuple of float
        Forward-difference step of each value.
    apply : callable
        ``apply(model, values)``: the model with the effect at these values.
    describe : callable
        ``describe(model)``: the fitted parameters (a dict) of a model with the effect.
    at_limit : callable, optional
        ``at_limit(values)``: whether these values sit at a physical limit of the effect (a bound the physics
        sets, not the search's).
    """

    values: tuple
    lower: tuple
    upper: tuple
    steps: tuple
    apply: Callable[[CryostatModel, tuple], CryostatModel]
    describe: Callable[[CryostatModel], dict]
    at_limit: Callable[[tuple], bool] | None = None


def _effect_parameters(name: str):
    return lambda model: dataclasses.asdict(getattr(model.effects, name))


def scalar_search(objective, grid, bounds, tolerance):
    """Minimise a 1-D cost: the best of a grid, then bounded Brent between its neighbours."""
    grid = np.asarray(grid, dtype=float)
    values = np.array([objective(x) for x in grid])
    best = int(np.argmin(values))
    low = grid[best - 1] if best > 0 else bounds[0]
    high = grid[best + 1] if best < grid.size - 1 else bounds[1]
    result = optimize.minimize_scalar(objective, bounds=(low, high), method="bounded",
                                      options={"xatol": tolerance, "maxiter": 40})
    if result.fun <= values[best]:
        return float(result.x)
    return float(grid[best])


class _CachedObjective:
    """Chi-square of a one-parameter family of models, remembering each replay.

    ``replay_for(value)`` makes the replay (default: the family's model
    replayed with ``line``).
    """

    def __init__(self, context: FitContext, make_model, line: PtcLine, replay_for=None):
        self.context = context
        self.replay_for = replay_for or (lambda value: context.replay(make_model(value), line))
        self.replays: dict[float, Replay] = {}

    def __call__(self, value: float) -> float:
        value = float(value)
        if value not in self.replays:
            self.replays[value] = self.replay_for(value)
        return self.context.fit_chi_square(self.replays[value])

    def replay(self, value: float) -> Replay:
        self(value)
        return self.replays[float(value)]


# ---------------------------------------------------------------------------
# the candidates
# ---------------------------------------------------------------------------
def fit_sensor_lag(context: FitContext) -> CandidateFit:
    """First-order lag of the flange thermometer on every T2 path, and of the PTC-stage one on T5.

    The flange thermometer's time constant tau2 is searched (grid, then
    Brent). For each tau2 the stage thermometer's tau5 follows: the line
    measured in T5 is the source lagged by tau5, so with the flange lag alone
    the model's line on T2 is off by exactly the factor F = 1 + j w tau5;
    F is a linear least-squares coefficient (:func:`line_factor`), and
    ``tau5 = tan(arg F) / w`` (0 below 1e-4 rad, or below the recalibration's
    tolerance on the line's phase when the model is recalibrated: that much is
    the recalibration's). A pair of thermometers lagging
    alike leaves the line alone and shows only in the heater's paths.
    """
    omega = context.base_line.angular_frequency_rad_s
    stage_taus: dict[float, float] = {}

    def model(tau, stage=0.0):
        if tau <= 0.0 and stage <= 0.0:
            return context.base_model
        return context.base_model.with_effects(sensor_lag=SensorLag(max(tau, 1e-9), stage))

    # with a recalibration, a phase within its tolerance is the recalibration's, not a second thermometer's
    smallest = LINE_PHASE_TOLERANCE_RAD if context.recalibrated is not None else STAGE_LAG_SMALLEST_PHASE_RAD

    def replay_at(tau):
        flange_only = model(tau)
        factor, own_replay = _line_factor(context, flange_only)
        angle = cmath.phase(factor)
        stage = float(min(math.tan(angle) / omega, 30.0)) if smallest < angle < math.pi / 2 else 0.0
        stage_taus[tau] = stage
        return own_replay() if stage == 0.0 else context.replay(model(tau, stage), context.base_line)

    objective = _CachedObjective(context, model, context.base_line, replay_at)
    tau = scalar_search(objective, np.geomspace(0.01, 20.0, 15), (0.0, 30.0), 1e-6)
    best = objective.replay(tau)
    stage = stage_taus[float(tau)]
    if stage > 0.0:
        effect = EffectForm((tau, stage), (1e-6, 0.0), (30.0, 30.0), (1e-3, 1e-3),
                            lambda base, v: base.with_effects(sensor_lag=SensorLag(v[0], v[1])),
                            _effect_parameters("sensor_lag"))
    else:
        effect = EffectForm((tau,), (1e-6,), (30.0,), (1e-3,),
                            lambda base, v: base.with_effects(sensor_lag=SensorLag(v[0], 0.0)),
                            _effect_parameters("sensor_lag"))
    return CandidateFit("sensor_lag", {"flange_thermometer_time_constant_s": tau,
                                       "ptc_stage_thermometer_time_constant_s": stage},
                        model(tau, stage), best, context.base_line, parameter_count=1 + (stage > 0.0), effect=effect)


def fit_dead_time(context: FitContext) -> CandidateFit:
    """Pure delay between the heater and the flange thermometer."""
    longest = float(min(60.0, max(context.data.duration_s / 10.0, 2.5)))

    def model(delay):
        return context.base_model.with_effects(dead_time=DeadTime(max(delay, 0.0)))

    grid = np.concatenate([np.arange(0.05, 2.0, 0.1), np.geomspace(2.0, longest, 10)])
    objective = _CachedObjective(context, model, context.base_line)
    delay = scalar_search(objective, grid, (0.0, longest), 1e-5)
    effect = EffectForm((delay,), (0.0,), (longest,), (2e-3,),
                        lambda base, v: base.with_effects(dead_time=DeadTime(max(v[0], 0.0))),
                        _effect_parameters("dead_time"))
    return CandidateFit("dead_time", {"heater_to_flange_s": delay}, model(delay), objective.replay(delay),
                        context.base_line, effect=effect)


def fit_heat_capacity_temperature(context: FitContext) -> CandidateFit:
    """Flange time constants scaling as (T / T_ref)^n, T_ref the base model's zero-heater T2."""
    reference = context.base_model.operating_point.flange_temperature_K
    at_record = context.estimated_model(context.base_model)

    def model(exponent, base=at_record):
        if exponent == 0.0:
            return base
        return base.with_effects(heat_capacity_temperature=HeatCapacityTemperature(exponent, reference))

    objective = _CachedObjective(context, model, context.base_line)
    exponent = scalar_search(objective, [-4.0, -2.0, -1.0, -0.5, 0.5, 1.0, 2.0, 4.0], (-6.0, 6.0), 1e-5)
    point = context.base_replay.operating_point
    effect = EffectForm(
        (exponent,), (-6.0,), (6.0,), (1e-2,),
        lambda base, v: dataclasses.replace(base, operating_point=point).with_effects(
            heat_capacity_temperature=HeatCapacityTemperature(v[0], reference)),
        _effect_parameters("heat_capacity_temperature"))
    return CandidateFit("heat_capacity_temperature",
                        {"exponent": exponent, "reference_temperature_K": reference},
                        model(exponent, context.base_model), objective.replay(exponent), context.base_line,
                        effect=effect)


def fit_heater_nonlinearity(context: FitContext) -> CandidateFit:
    """Delivered power P + k P^2: k from the linear response of both thermometers to P^2."""
    replayer, data = context.replayer, context.data
    quiet = context.base_line.applied_to(context.base_model).with_ptc(ptc_stage_amplitude_K=0.0, harmonics=()) \
        .with_effects(ptc_frequency_drift=None, heater_nonlinearity=None)
    present = context.base_model.effects.heater_nonlinearity
    already = present.quadratic_coefficient_per_W if present is not None else 0.0
    settled = replayer.initial_heater_power_w if replayer.initial_heater_power_w is not None else data.heater_w[0]
    squared = replayer.simulate(quiet, data.heater_w ** 2, settled ** 2)
    point = quiet.operating_point
    columns = (squared.flange_K - point.flange_temperature_K, squared.ptc_stage_K - point.ptc_stage_temperature_K)
    base_simulation = replayer.simulate(context.base_line.applied_to(context.base_model),
                                        cycle=context.base_line.cycle)
    linear = replayer.replay_simulated(context.base_line.applied_to(context.base_model), base_simulation.flange_K,
                                       base_simulation.ptc_stage_K, shared_columns=columns,
                                       basis=context.basis(context.base_line))
    found = already + float(linear.shared_coefficients[0])
    coefficient = float(np.clip(found, -1.0, 10.0))
    model = context.base_model.with_effects(heater_nonlinearity=HeaterNonlinearity(coefficient))
    note = "" if coefficient == found else f"least squares gave {found:.4g} /W, held to the model's range -1..10 /W"
    effect = EffectForm((coefficient,), (-1.0,), (10.0,), (1e-2,),
                        lambda base, v: base.with_effects(heater_nonlinearity=HeaterNonlinearity(v[0])),
                        _effect_parameters("heater_nonlinearity"))
    return CandidateFit("heater_nonlinearity", {"quadratic_coefficient_per_W": coefficient}, model,
                        context.replay(model, context.base_line), context.base_line, note, effect=effect)


def _ptc_fundamental_on_flange(model: CryostatModel, elapsed_s: np.ndarray, cycle=None) -> np.ndarray:
    """Complex T2 response to the PTC fundamental, Z(t): T2's line is Re(Z) (K); ``cycle``: the measured one."""
    drive = CoolerDrive(model, cycle)
    path = CoolerPath(drive, flange_transfer_functions(model)[1], input_is_heat=True)
    phase, frequency = drive.cycle.phase_and_frequency(elapsed_s)
    component = drive.components[0]
    phasor = path.output_phasors(frequency)[0]
    return phasor * np.exp(1j * (phase + component.phase_rad))


def line_factor(context: FitContext, model: CryostatModel | None = None) -> tuple[complex, Replay]:
    """Complex factor F on a model's PTC path to T2 that fits the record's line best, and that replay.

    T2's line is linear in F (``Re(F Z(t))``, Z the model's response to the
    measured line's fundamental), so F is a linear least-squares coefficient,
    fitted on the fit blocks jointly with the nuisance parameters. The replay
    returned is the model's own (F = 1); ``model`` None: the base model.
    """
    factor, own_replay = _line_factor(context, model)
    return factor, own_replay()


def _line_factor(context: FitContext, model: CryostatModel | None = None):
    """:func:`line_factor`'s factor, and the model's own replay as a function (made only when asked for)."""
    data = context.data
    aligned = context.base_line.applied_to(model if model is not None else context.base_model)
    cycle = context.base_line.cycle
    response = _ptc_fundamental_on_flange(aligned, data.elapsed_s, cycle)
    simulated = context.replayer.simulate(aligned, cycle=cycle)
    basis = context.basis(context.base_line, without=LINK_PARAMETERS)
    linear = context.replayer.replay_simulated(aligned, simulated.flange_K, simulated.ptc_stage_K,
                                               shared_columns=(np.column_stack([response.real, -response.imag]),
                                                               np.zeros((data.time_s.size, 2))), basis=basis)
    return (complex(1.0 + linear.shared_coefficients[0], linear.shared_coefficients[1]),
            lambda: context.replayer.replay_simulated(aligned, simulated.flange_K, simulated.ptc_stage_K,
                                                      basis=basis))


def fit_link_dynamics(context: FitContext) -> CandidateFit:
    """PTC-to-flange path: complex factor at the line by linear least squares, then its physical form.

    The factor is measured against the base model's link before recalibration
    (:attr:`FitContext.link_reference`), with the recalibration of the link
    left out: it and this cause are the same freedom at the line.
    """
    base = context.base_model
    if context.link_reference is not None:
        base = dataclasses.replace(base, ptc_to_flange=context.link_reference)
    factor, _ = _line_factor(context, base)
    omega = context.base_line.angular_frequency_rad_s
    note = ""
    inverse = 1.0 / factor if factor != 0 else complex(math.inf)
    tau = inverse.imag / (omega * inverse.real) if inverse.real > 0 else -1.0
    effect = None
    if base.effects.link_dynamics is None and inverse.real > 0 and tau >= 0.0:
        gain = 1.0 / inverse.real
        model = base.with_effects(link_dynamics=LinkDynamics(tau, gain))
        parameters = {"time_constant_s": tau, "gain_factor": gain}
        effect = EffectForm((tau, gain), (0.0, 1e-3), (30.0, 100.0), (1e-4, 1e-3),
                            lambda reference, v: reference.with_effects(link_dynamics=LinkDynamics(max(v[0], 0.0), v[1])),
                            _effect_parameters("link_dynamics"))
    else:
        link_at_line = factor * base.ptc_to_flange.frequency_response(omega)
        if base.effects.link_dynamics is not None:
            extra = TransferFunction.first_order_lag(base.effects.link_dynamics.time_constant_s,
                                                     base.effects.link_dynamics.gain_factor)
            link_at_line *= extra.frequency_response(omega)
        try:
            link = first_order_link(link_at_line, omega)
        except TransferFunctionError:
            link = base.ptc_to_flange
        model = dataclasses.replace(base, ptc_to_flange=link).with_effects(link_dynamics=None)
        parameters = {"ptc_to_flange_numerator": list(link.numerator),
                      "ptc_to_flange_denominator": list(link.denominator),
                      "factor_at_line_gain": abs(factor), "factor_at_line_phase_rad": cmath.phase(factor)}
        note = ("the measured line leads the model's by {:.3f} rad: no lag g/(tau s + 1) gives that, so the "
                "PTC-to-flange link itself is refitted".format(cmath.phase(factor)))
    return CandidateFit("link_dynamics", parameters, model,
                        context.replay(model, context.base_line, basis_without=LINK_PARAMETERS),
                        context.base_line, note, parameter_count=2, effect=effect, excluded=LINK_PARAMETERS)


def fit_ptc_harmonics(context: FitContext) -> CandidateFit:
    """Harmonics of the stage oscillation measured in T5: every order the sampling can tell apart, up to 5."""
    base = context.base_model
    orders = measurable_orders(context.base_line.angular_frequency_rad_s, context.data.sample_interval_s)
    orders = tuple(sorted(set(orders) | set(context.base_line.orders)))
    line = context.replayer.stage_line(context.line_model or base, orders=orders,
                                       angular_frequency_rad_s=context.base_line.angular_frequency_rad_s,
                                       significant_only=True, measured_phase=context.base_line.cycle is not None)
    parameters = {}
    for component in line.components[1:]:
        parameters[f"order_{component.order}_amplitude_K"] = component.amplitude_K
        parameters[f"order_{component.order}_phase_rad"] = component.phase_rad
    note = "" if parameters else "no harmonic of T5 above 5 standard errors"
    return CandidateFit("ptc_harmonics", parameters, line.shape_for(base), context.replay(base, line),
                        line, note, parameter_count=max(2 * (len(line.components) - 1), 1))


def fit_ptc_frequency_drift(context: FitContext) -> CandidateFit:
    """The cooler's frequency changing over the record: the record replayed at the phase measured in T5.

    The phase is followed sample by sample (:func:`cryod.cooler.line.measured_cycle`);
    the drift's parameters are the model's form fitted to it
    (:func:`cryod.cooler.line.fit_drift_to_phase`).
    """
    base = context.base_model
    line = context.replayer.stage_line(context.line_model or base, orders=context.base_line.orders,
                                       angular_frequency_rad_s=context.base_line.angular_frequency_rad_s,
                                       measured_phase=True)
    drift = line.drift
    assert drift is not None                # a line at the measured phase carries the drift fitted to it
    parameters = dataclasses.asdict(drift)
    parameters["angular_frequency_at_start_rad_s"] = line.angular_frequency_rad_s
    return CandidateFit("ptc_frequency_drift", parameters, base.with_effects(ptc_frequency_drift=drift),
                        context.replay(base, line), line,
                        parameter_count=2 + 2 * (drift.wander_amplitude_rad_s > 0.0))


#: The fitters of this module's causes (every cause's: :data:`cryod.analysis.fitters.FITTERS`).
CORE_FITTERS = {
    "sensor_lag": fit_sensor_lag,
    "link_dynamics": fit_link_dynamics,
    "dead_time": fit_dead_time,
    "heat_capacity_temperature": fit_heat_capacity_temperature,
    "heater_nonlinearity": fit_heater_nonlinearity,
    "ptc_harmonics": fit_ptc_harmonics,
    "ptc_frequency_drift": fit_ptc_frequency_drift,
}
