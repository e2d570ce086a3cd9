"""The cooler's slow causes: its stroke breathing and its cold end drifting.

Both are fitted like every candidate (:mod:`cryod.analysis.candidates`): on the
fit blocks, by the same replay and weighted least squares, with the
recalibration alongside.

===========================  ===================================================================
cause                        parameters and fit
===========================  ===================================================================
ptc_amplitude_modulation     depth m, period P and phase of ``1 + m sin(2 pi t / P + phi)`` on the
                             whole oscillation: for each P the change is linear in
                             (m cos phi, m sin phi) (columns: the model's line in T2 and in T5
                             times sin and cos of 2 pi t / P), so P is searched (grid, then
                             bounded Brent on log P) and the rest is linear least squares
ptc_stage_drift              the drift d(t) of T5, measured in T5 over the whole record as the
                             cooler's line is: a cubic B-spline with knots two blocks apart fitted
                             with the nuisance parameters on the fit blocks, plus what it leaves
                             in T5 averaged over 30 s, less what the stage's own path does (its
                             free decay, its response to the heater); its response on T2
                             ``g / (tau s + 1)`` applied to d: g linear within 0 to 1, tau
                             searched (grid, then bounded Brent on log tau); d measured again
                             with T2 through that coupling beside T5, and g, tau again
===========================  ===================================================================

The drift found in the record is the record's own (:class:`MeasuredStageDrift`);
the model file keeps its statistics (:class:`cryod.model.PtcStageDrift`:
rms, correlation time, coupling), which the simulator realises as a random
process of the same spectrum.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage, signal

from cryod.analysis.candidates import CandidateFit, EffectForm, FitContext, scalar_search
from cryod.analysis.decision import CANDIDATE_MINIMUM_IMPROVEMENT
from cryod.analysis.slow_series import correlation_time_s, slow_splines
from cryod.model import CryostatModel, CoolerAmplitudeModulation, PtcStageDrift

#: Periods of the amplitude modulation searched: from this many seconds to this many record durations.
SHORTEST_MODULATION_PERIOD_S = 60.0
LONGEST_MODULATION_PERIOD_DURATIONS = 3.0
#: The cold end's drift is measured in T5 over the whole record, as the cooler's line is: T5's residual averaged
#: over about this long (s), a whole number of line periods. At T5's 0.3 mK of noise the mean carries 15 µK, which
#: the flange's coupling (a lag of minutes) averages further.
DRIFT_SMOOTHING_S = 30.0
#: Time constants of the drift's path to the flange searched (s).
COUPLING_TIME_CONSTANTS_S = (1.0, 1000.0)
#: Largest depth of a modulation the model takes.
LARGEST_DEPTH = 0.9
#: The drift's gain on the flange: a passive link carries at most the stage's own change to the flange (the
#: flange's other heat paths and the link's conductance rising with temperature make it less).
FLANGE_COUPLING_BOUNDS = (0.0, 1.0)


def _line_parts(context: FitContext, model: CryostatModel):
    """The aligned model, its simulation, and the cooler's part of T2 and of T5 in it (K)."""
    replayer, line = context.replayer, context.base_line
    aligned = line.applied_to(model)
    simulated = replayer.simulate(aligned, cycle=line.cycle)
    quiet = replayer.simulate(aligned.with_ptc(ptc_stage_amplitude_K=0.0, harmonics=()), cycle=line.cycle)
    return aligned, simulated, simulated.flange_K - quiet.flange_K, simulated.ptc_stage_K - quiet.ptc_stage_K


def fit_ptc_amplitude_modulation(context: FitContext) -> CandidateFit:
    """The whole oscillation scaled by ``1 + m sin(2 pi t / P + phi)``: T2's and T5's lines move together."""
    data, replayer, base = context.data, context.replayer, context.base_model
    aligned, simulated, flange_line, stage_line = _line_parts(context, base)
    elapsed = data.elapsed_s
    basis = context.basis(context.base_line)
    solutions = {}

    def replay_at(log_period):
        angle = 2.0 * math.pi * elapsed / math.exp(log_period)
        columns = (np.column_stack([flange_line * np.sin(angle), flange_line * np.cos(angle)]),
                   np.column_stack([stage_line * np.sin(angle), stage_line * np.cos(angle)]))
        replay = replayer.replay_simulated(aligned, simulated.flange_K, simulated.ptc_stage_K, columns, basis)
        solutions[log_period] = replay.shared_coefficients
        return replay

    replays = {}

    def objective(log_period):
        log_period = float(log_period)
        if log_period not in replays:
            replays[log_period] = replay_at(log_period)
        return context.fit_chi_square(replays[log_period])

    shortest = math.log(SHORTEST_MODULATION_PERIOD_S)
    longest = math.log(max(LONGEST_MODULATION_PERIOD_DURATIONS * data.duration_s, 2.0 * SHORTEST_MODULATION_PERIOD_S))
    log_period = scalar_search(objective, np.linspace(shortest, longest, 24), (shortest, longest), 1e-4)
    objective(log_period)
    sine, cosine = solutions[float(log_period)]
    depth, phase = float(min(math.hypot(sine, cosine), LARGEST_DEPTH)), float(math.atan2(cosine, sine))
    period = float(math.exp(log_period))

    def apply(model, values):
        return model.with_effects(ptc_amplitude_modulation=CoolerAmplitudeModulation(
            float(np.clip(values[0], 0.0, LARGEST_DEPTH)), max(float(values[1]), 1.0), float(values[2])))

    model = apply(base, (depth, period, phase))
    effect = EffectForm((depth, period, phase), (0.0, SHORTEST_MODULATION_PERIOD_S / 2, -10.0),
                        (LARGEST_DEPTH, math.exp(longest) * 2, 10.0), (1e-3, 1e-3 * period, 1e-3), apply,
                        lambda extended: dataclasses.asdict(extended.effects.ptc_amplitude_modulation))
    return CandidateFit("ptc_amplitude_modulation", {"depth": depth, "period_s": period, "phase_rad": phase},
                        model, context.replay(model, context.base_line), context.base_line, parameter_count=3,
                        effect=effect)


def first_order_response(values: np.ndarray, sample_interval_s: float, time_constant_s: float) -> np.ndarray:
    """``values`` through ``1 / (time_constant_s s + 1)`` at a uniform interval, settled at the first value."""
    if time_constant_s <= 0.0:
        return np.asarray(values, dtype=float).copy()
    decay = math.exp(-sample_interval_s / time_constant_s)
    filtered, _ = signal.lfilter([0.0, 1.0 - decay], [1.0, -decay], values, zi=[decay * values[0]])
    return filtered


@dataclass(frozen=True, eq=False)
class MeasuredStageDrift:
    """The cold end's drift as measured in a record: d(t) at the record's instants, and its coupling to T2.

    Stands in the model for :class:`cryod.model.PtcStageDrift` while the record
    is replayed (it has the same :meth:`offsets_K`); :meth:`model_form` is what
    the model file keeps.
    """

    elapsed_s: np.ndarray
    drift_K: np.ndarray
    flange_coupling: float
    coupling_time_constant_s: float
    flange_K: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        interval = float(np.median(np.diff(self.elapsed_s)))
        object.__setattr__(self, "flange_K", self.flange_coupling * first_order_response(
            self.drift_K, interval, self.coupling_time_constant_s))

    def offsets_K(self, time_s):
        """(flange, stage) offsets at ``time_s`` after the record's start (K)."""
        return (np.interp(time_s, self.elapsed_s, self.flange_K), np.interp(time_s, self.elapsed_s, self.drift_K))

    def correlation_time_s(self) -> float:
        """Where the drift's autocorrelation falls to 1/e (s)."""
        return correlation_time_s(self.drift_K, float(np.median(np.diff(self.elapsed_s))))

    def parameters(self) -> dict:
        """What the model file keeps: rms, correlation time, coupling gain and time constant."""
        return {"rms_K": float(np.std(self.drift_K)), "correlation_time_s": self.correlation_time_s(),
                "flange_coupling": self.flange_coupling, "coupling_time_constant_s": self.coupling_time_constant_s}

    def model_form(self) -> PtcStageDrift:
        """The drift as the model file has it: a random process of the same rms and correlation time."""
        return PtcStageDrift(**self.parameters())


def measured_remainder(residual_K: np.ndarray, valid: np.ndarray, sample_interval_s: float,
                       line_angular_frequency_rad_s: float) -> np.ndarray:
    """A T5 residual's slow part over the whole record: its means over :data:`DRIFT_SMOOTHING_S`, taken over a
    whole number of the line's periods (which cancels the line and its harmonics), missing readings filled in
    from their neighbours."""
    values = np.asarray(residual_K, dtype=float)
    good = np.asarray(valid, dtype=bool) & np.isfinite(values)
    if not np.any(good):
        return np.zeros_like(values)
    indexes = np.arange(values.size)
    filled = np.interp(indexes, indexes[good], values[good])
    period_samples = 2.0 * math.pi / line_angular_frequency_rad_s / sample_interval_s
    periods = max(1, round(DRIFT_SMOOTHING_S / (period_samples * sample_interval_s)))
    samples = max(1, int(round(periods * period_samples)))
    return ndimage.uniform_filter1d(filled, samples, mode="nearest")


def _stage_path_columns(context: FitContext, model: CryostatModel) -> np.ndarray:
    """What the stage's own path does to T5 on its own from its state at the first sample: a constant and its
    free decays (one per time constant of the heater's path to T5). Its response to the heater is not among
    them: with the drift measured beside that too, a PI-only record's drift was named with a heat capacity on
    top (benchmarks/results/analysis_causes.md, section 6a, records 31 and 33)."""
    elapsed = context.data.elapsed_s
    decays = [np.exp(-elapsed / tau) for tau in model.heater_to_ptc_stage.time_constants_s if tau > 0.0]
    return np.column_stack([np.ones(elapsed.size), *decays])


def _beside_stage_path(drift: np.ndarray, columns: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``drift`` less its least-squares part (on ``mask``) along ``columns``: a drift is what the stage's own path
    (its state at the first sample) does not do. A record that starts inside the stage's transient cannot tell a
    slow drift from that state a little off; the replay's initial state takes that part, and the drift is
    measured beside it."""
    coefficients, *_ = np.linalg.lstsq(columns[mask], drift[mask], rcond=None)
    return drift - columns @ coefficients


def fit_ptc_stage_drift(context: FitContext) -> CandidateFit:
    """T5 drifting slowly, reaching T2 through ``g / (tau s + 1)``: the drift measured in T5, then g and tau; then
    the drift measured again with T2 (through the coupling found) beside T5, then g and tau again."""
    data, replayer, base, line = context.data, context.replayer, context.base_model, context.base_line
    aligned, simulated, _, _ = _line_parts(context, base)
    basis = context.basis(line)
    splines = slow_splines(data)
    interval = data.sample_interval_s

    def measured(flange_columns):
        # the splines fitted with the offset, the state and the recalibration, plus what they leave in T5,
        # smoothed: the cold end's temperature measured wherever T5 is, against the model as refitted with it (a
        # model refitted without the drift has taken part of it into the stage's gain and time constant)
        found = replayer.replay_simulated(aligned, simulated.flange_K, simulated.ptc_stage_K,
                                          (flange_columns, splines), basis)
        drift = splines @ np.asarray(found.shared_coefficients) + measured_remainder(
            found.ptc_stage_residual_K, data.valid, interval, line.angular_frequency_rad_s)
        return _beside_stage_path(drift, stage_columns, context.fit_mask)

    stage_columns = _stage_path_columns(context, aligned)

    def coupling(drift):
        stage = simulated.ptc_stage_K + drift
        gains, replays = {}, {}

        def objective(log_tau):
            log_tau = float(log_tau)
            if log_tau not in replays:
                response = first_order_response(drift, interval, math.exp(log_tau))
                replay = replayer.replay_simulated(aligned, simulated.flange_K, stage,
                                                   (response[:, None], np.zeros((response.size, 1))), basis)
                gain = float(replay.shared_coefficients[0])
                bounded = float(np.clip(gain, *FLANGE_COUPLING_BOUNDS))
                if bounded != gain:             # the gain at its bound, the rest refitted without it
                    replay = replayer.replay_simulated(aligned, simulated.flange_K + bounded * response, stage,
                                                       basis=basis)
                replays[log_tau], gains[log_tau] = replay, bounded
            return context.fit_chi_square(replays[log_tau])

        low, high = (math.log(value) for value in COUPLING_TIME_CONSTANTS_S)
        log_tau = scalar_search(objective, np.linspace(low, high, 10), (low, high), 1e-4)
        return gains[float(log_tau)], math.exp(log_tau), objective(log_tau)

    drift = measured(np.zeros_like(splines))
    gain, tau, chi_square = coupling(drift)
    # T5 alone cannot tell the drift's slow part from the stage's start when the record starts inside a transient;
    # T2, which the drift reaches through the coupling and the heater through G1, can. Only for a drift that
    # counts on the fit blocks: on a record without one the second measurement would change nothing.
    if gain > 0.0 and context.fit_chi_square(context.base_replay) - chi_square >= CANDIDATE_MINIMUM_IMPROVEMENT:
        drift = measured(np.column_stack([gain * first_order_response(column, interval, tau) for column in splines.T]))
        gain, tau, _ = coupling(drift)

    def apply(model, values):
        return model.with_effects(ptc_stage_drift=MeasuredStageDrift(data.elapsed_s, drift, float(values[0]),
                                                                     max(float(values[1]), 0.0)))

    model = apply(base, (gain, tau))
    measured = model.effects.ptc_stage_drift
    effect = EffectForm((gain, tau), (FLANGE_COUPLING_BOUNDS[0], 0.0),
                        (FLANGE_COUPLING_BOUNDS[1], 10.0 * COUPLING_TIME_CONSTANTS_S[1]), (1e-3, 1e-2 * tau),
                        apply, lambda extended: extended.effects.ptc_stage_drift.parameters(),
                        lambda values: not (FLANGE_COUPLING_BOUNDS[0] + 1e-6 < values[0]
                                            < FLANGE_COUPLING_BOUNDS[1] * (1.0 - 1e-6)))
    note = ""
    if gain >= FLANGE_COUPLING_BOUNDS[1] * (1.0 - 1e-6):
        note = ("the flange follows the drift at its physical limit (coupling 1): the record asks for more than a "
                "passive link carries, so it does not count")
    elif gain <= FLANGE_COUPLING_BOUNDS[0] + 1e-6:
        note = ("the flange does not follow T5's slow change (coupling 0): that is T5's reading drifting, not the "
                "cold end, so it does not count")
    return CandidateFit("ptc_stage_drift", measured.parameters(), model, context.replay(model, line), line, note,
                        parameter_count=2 + splines.shape[1], effect=effect)


__all__ = ["MeasuredStageDrift", "fit_ptc_amplitude_modulation", "fit_ptc_stage_drift"]
