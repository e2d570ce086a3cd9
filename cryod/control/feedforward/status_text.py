"""What ``cryod ctl feedforward status`` says, in words, from a snapshot of the feedforward.

The loop's thread only takes the snapshot (:class:`FeedforwardStatus`, :meth:`FeedforwardStatus.of` the
term, through :meth:`cryod.control.feedforward.FeedforwardTerm.status_snapshot`: plain values, immutable
objects and read-only copies of a few small arrays, a few microseconds); the words are put
together from it on another thread (:func:`status_text`: the waveform's extremes over a period,
the plant per harmonic, what binds the physical limit, a tenth of a millisecond and more), so a
status request costs the 80 ms cycle nothing but the snapshot. What the lines say:
docs/how-to/feedforward.md ("Using it", "What it says").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cryod.control.feedforward.bounded_waveform import waveform_values
from cryod.control.feedforward.learning_step import BOUND_POINTS
from cryod.control.feedforward.limit import REPORTED_HARMONICS
from cryod.control.feedforward.limit_binding import limit_binding, measured_against_limit
from cryod.control.feedforward.plant_learner import LearnedPlant
from cryod.control.feedforward.plant_probe import ProbeState
from cryod.cooler.phase import CoolerPhase


def read_only(values) -> np.ndarray:
    """A copy of ``values`` nobody can change (for a snapshot handed to another thread)."""
    copy = np.array(values)
    copy.flags.writeable = False
    return copy


@dataclass(frozen=True, eq=False)
class FeedforwardStatus:
    """The feedforward as the status text needs it, at one instant.

    Attributes
    ----------
    switched_on : bool
        The operator's switch.
    scale : float
        The fade, 0 (out) to 1 (full).
    fade_time_s : float
        How long a fade takes (s).
    harmonics : int
        Harmonics of the waveform.
    cooler : CoolerPhase or None
        The cooler's phase as tracked (None: not tracked).
    line_amplitude_K : float
        T2's synchronous part as estimated at the last learning step (K; NaN before the first).
    synchronous_K : tuple of complex
        T2's synchronous part per harmonic with the waveform now (K).
    line_K : numpy.ndarray
        The cooler's line per harmonic, without the waveform (K, complex).
    coefficients_W : numpy.ndarray
        The waveform's coefficients (W, complex; the probe not included).
    played_W : numpy.ndarray
        What the heater plays: the waveform and the probe (W, complex).
    base_W : float
        The feedback terms' power the waveform rides on (W).
    margin_W, maximum_W : float
        The distance kept from 0 W and from the heater's maximum, and that maximum (W).
    model_source : str
        Where the controller's model came from.
    plant : LearnedPlant
        The plant as the last learning step knew it.
    probe_state : ProbeState
        Where the probe is.
    probe_W : numpy.ndarray
        The probe's coefficients (W, complex).
    probe_cost_K : float
        T2's answer to the probe at the last learning step (K).
    plant_precision : float
        The precision the probe learns the plant to (relative).
    cycles_on_time : bool
        The loop's cycles keep their deadlines.
    divergence : str or None
        Why the waveform is fading out after a divergence (None: it is not).
    divergences : int
        Learning divergences since the start.
    retry_in_s : float
        How long learning still waits after a divergence (s; 0 or less: it does not).
    limit : FeedforwardLimit or None
        The physical limit at the setpoint in use (None: not computed yet).
    limit_from : str or None
        ``model`` or ``learned``: what the limit was computed from.
    limit_changes : tuple
        What would change the limit (LimitChange).
    """

    switched_on: bool
    scale: float
    fade_time_s: float
    harmonics: int
    cooler: CoolerPhase | None
    line_amplitude_K: float
    synchronous_K: tuple[complex, ...]
    line_K: np.ndarray
    coefficients_W: np.ndarray
    played_W: np.ndarray
    base_W: float
    margin_W: float
    maximum_W: float
    model_source: str
    plant: LearnedPlant
    probe_state: ProbeState
    probe_W: np.ndarray
    probe_cost_K: float
    plant_precision: float
    cycles_on_time: bool
    divergence: str | None
    divergences: int
    retry_in_s: float
    limit: object | None
    limit_from: str | None
    limit_changes: tuple

    @classmethod
    def of(cls, term) -> "FeedforwardStatus":
        """The snapshot of a :class:`~cryod.control.feedforward.FeedforwardTerm` now (on the loop's thread)."""
        steps, settings, waveform, estimate = term.steps, term.settings, term.waveform, term.steps.estimate
        return cls(
            switched_on=term.switched_on, scale=term.scale, fade_time_s=settings.fade_time_s,
            harmonics=settings.harmonics, cooler=term.phase, line_amplitude_K=estimate.line_amplitude_K,
            synchronous_K=tuple(steps.synchronous(waveform.effect(term.plant))), line_K=read_only(estimate.line),
            coefficients_W=read_only(waveform.coefficients), played_W=read_only(waveform.played),
            base_W=term.levels.other_terms_w or 0.0, margin_W=settings.margin_W, maximum_W=term.output_max,
            model_source=settings.model_source, plant=estimate.learned, probe_state=steps.probe_state,
            probe_W=read_only(waveform.probe), probe_cost_K=estimate.probe_cost_K,
            plant_precision=settings.plant_precision, cycles_on_time=term.on_time, divergence=steps.retry.reason,
            divergences=steps.retry.count, retry_in_s=steps.retry.learn_again_s - term.time_s,
            limit=term.limits.limit, limit_from=term.limits.source, limit_changes=term.limits.changes)


def status_text(status: FeedforwardStatus) -> str:
    """The feedforward's state in a few lines (``cryod ctl feedforward status``)."""
    lines = [f"feedforward {'on' if status.switched_on else 'off'}, waveform at {100 * status.scale:.0f} % "
             f"(fade {status.fade_time_s:g} s)", _cooler(status.cooler)]
    if math.isfinite(status.line_amplitude_K):
        harmonics = ", ".join(f"{1e6 * abs(value):.1f}" for value in status.synchronous_K)
        lines.append(f"T2's part synchronous with the cooler: {1e6 * status.line_amplitude_K:.1f} µK (harmonics 1-"
                     f"{status.harmonics}: {harmonics} µK); without the waveform it would be "
                     f"{1e6 * float(np.sqrt(np.sum(np.abs(status.line_K) ** 2))):.1f} µK")
    amplitude = np.abs(status.coefficients_W)
    values = waveform_values(status.played_W, status.base_W, BOUND_POINTS)
    lines.append(f"waveform: {', '.join(f'{1e3 * a:.1f}' for a in amplitude)} mW per harmonic, "
                 f"{1e3 * values.min():.1f} to {1e3 * values.max():.1f} mW with the probe and the "
                 f"{1e3 * status.base_W:.1f} mW from PI, within {1e3 * status.margin_W:g} mW "
                 f"of 0 and {1e3 * status.maximum_W:.0f} mW")
    plant = status.plant
    lines.append(f"plant, heater to T2's readings (model: {status.model_source}; "
                 f"{'learned' if plant.learned.any() else 'nothing learned yet'}):")
    lines.append(plant.describe())
    if plant.differences_said():
        lines.append(plant.differences_said())
    lines.append(_probe(status))
    if not status.cycles_on_time:
        lines.append("the loop's cycles are late many in a row: the waveform fades out and learning pauses "
                     "until they keep their deadlines again")
    if status.divergence is not None:
        lines.append(f"learning diverged ({status.divergence}): fading out")
    elif status.retry_in_s > 0.0:
        lines.append(f"learning diverged {status.divergences} time(s); starts again in {status.retry_in_s:.0f} s")
    elif status.divergences:
        lines.append(f"learning diverged {status.divergences} time(s) since start, reset each time")
    lines += _limit(status)
    return "\n".join(lines)


def _cooler(cooler: CoolerPhase | None) -> str:
    if cooler is None:
        return "cooler phase: not tracked (off, or no reading yet)"
    return (f"cooler phase {'locked' if cooler.locked else 'NOT locked'}: {cooler.frequency_rad_s:.4f} rad/s "
            f"({cooler.frequency_rad_s / (2 * math.pi):.4f} Hz), T5 line {1e3 * cooler.amplitude_K:.1f} mK")


def _probe(status: FeedforwardStatus) -> str:
    probing = [index + 1 for index, on in enumerate(status.probe_state.probing) if on]
    short = status.probe_state.given_up()
    playing = [index + 1 for index, value in enumerate(status.probe_W) if value]
    precision = f"{100 * status.plant_precision:g} %"
    if playing and status.probe_cost_K > 0.0:
        return (f"probe: {1e3 * abs(status.probe_W[playing[0] - 1]):.1f} mW at harmonic {playing[0]}, moving T2 by "
                f"{1e6 * status.probe_cost_K:.1f} µK (to learn the plant to {precision}; "
                f"harmonics {', '.join(map(str, probing))} to go)")
    if probing:
        return (f"probe: waiting (harmonics {', '.join(map(str, probing))} to go: no room now, or a plant too "
                f"weak for the room there is)")
    return f"probe: off (plant known to {precision}" + \
        (")" if not short else f" where it could be; harmonics {', '.join(map(str, short))} left at what "
                               f"the probe could tell within its share of the heater's room)")


def _limit(status: FeedforwardStatus) -> list[str]:
    limit = status.limit
    if limit is None:
        return ["physical limit: not computed yet (the daemon computes it for the setpoint in use)"]
    learned = status.limit_from == "learned"
    source = ("from the learned plant and line, and the mean power PI found" if learned
              else "from the controller's model")
    lines = [f"physical limit at {limit.setpoint_K:g} K ({source}): {1e6 * limit.ptc_periodic_limit_K:.1f} "
             f"µK of the {1e6 * limit.open_line_K:.1f} µK line; {limit.limited_by}-limited (authority "
             f"{limit.authority:.2f}: the heater can put {1e3 * limit.largest_line_power_W:.0f} mW at the "
             f"line of the {1e3 * limit.line_power_needed_W:.0f} mW needed around "
             f"{1e3 * limit.mean_heater_power_W:.0f} mW); predicted best "
             f"{1e6 * limit.predicted_best_residual_K:.1f} µK",
             "what binds it: " + limit_binding(limit, status.limit_changes).explanation]
    if status.limit_changes:
        lines.append("what would change it: " + "; ".join(change.describe() for change in status.limit_changes)
                     + " (R I_max^2 x 2: R x 2 or I_max x 1.41; more: cryod feedforward-limit)")
    synchronous = status.synchronous_K[:REPORTED_HARMONICS]
    if synchronous and math.isfinite(status.line_amplitude_K):
        measured = float(np.sqrt(np.sum(np.abs(synchronous) ** 2)))
        lines.append("T2 now against the limit: " + measured_against_limit(
            measured, limit.ptc_periodic_limit_K, limit.noise_floor_K, "the learned plant" if learned else "the model"))
    return lines


__all__ = ["FeedforwardStatus", "read_only", "status_text"]
