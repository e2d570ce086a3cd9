"""The generic extension: a data-driven model of what no cause explains, fitted and judged like a cause.

Where the extended model (the recalibration and the causes named) still shows
a discrepancy, ``cryod analyze`` extends it anyway. Four families of terms,
each linear in its coefficients (columns fitted by least squares on the fit
blocks, with the nuisance parameters):

=========================  ======================================================================
family                     terms
=========================  ======================================================================
heater_path_correction     first-order terms of fixed time constants (:data:`TIME_CONSTANTS_S`)
                           in parallel with G1 (heater to flange, so through G2 and every
                           thermometer effect to T2) and with G3 (heater to T5): an error of the
                           heater's paths (:class:`cryod.model.HeaterPathCorrection`)
unrecorded_heat            a slow heat input nobody recorded, reaching T2 and T5 as the heater's
                           power does: straight lines between knots two blocks apart
                           (:func:`cryod.analysis.slow_series.slow_splines`) through the heater
                           paths, one coefficient per spline for both thermometers
reading_offsets            slow offsets of the T2 and of the T5 reading (the same splines, each
                           thermometer its own): a thermometer drifting
pickups                    a sinusoid at each significant peak of the residual's spectrum away
                           from the cooler's harmonics and their sidebands
                           (:mod:`cryod.analysis.residual_signature`): a reading picking up a
                           vibration or a ground loop
=========================  ======================================================================

Each family is fitted alone on top of the extended model and judged on the
held-out blocks by the rules of a cause (:mod:`cryod.analysis.decision`):
what it removes tells what the residual is. Starting from the family that
removes most, each further family that counts alone (5 sigma and an
improvement of 25) is fitted together with those taken and kept when it
improves on them by as much; the extension is added to the model when it
counts, with its gain. It is marked generic in
the model file (effects ``heater_path_correction`` and ``disturbance``, no
cause), and ``cryod --simulate --sim-model`` runs it: the heater-path terms as
they are, the slow series as random processes of the rms and correlation time
found (:class:`cryod.model.SlowProcess`), the pickups as found.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from cryod.analysis.candidates import CandidateFit, FitContext
from cryod.analysis.decision import (
    CANDIDATE_MINIMUM_IMPROVEMENT,
    CANDIDATE_SIGMA,
    CandidateScore,
    score_candidate,
    significance,
)
from cryod.analysis.residual_signature import NOT_AT_HARMONICS, spectral_peaks
from cryod.analysis.slow_series import correlation_time_s, slow_splines
from cryod.model import CryostatModel, Disturbance, HeaterPathCorrection, Pickup, SlowProcess, TransferFunction

#: Time constants of the heater-path correction's terms (s): log-spaced from the fastest the records resolve to the
#: slowest.
TIME_CONSTANTS_S = tuple(float(tau) for tau in np.geomspace(1.0, 1000.0, 8))
#: The slow series are straight lines between knots two blocks apart (knots one block apart, each shared by a fit
#: and a held-out block, leave the families free to trade against each other there).
SPLINE_DEGREE = 1
SPLINE_BLOCKS = 2.0
#: The families, in the order they are reported.
FAMILIES = ("heater_path_correction", "unrecorded_heat", "reading_offsets", "pickups")
#: What each family stands for, in words.
MEANING = {
    "heater_path_correction": "an error of the heater's paths (first-order terms beside G1 and G3)",
    "unrecorded_heat": "a slow heat load nobody recorded, reaching T2 and T5 as the heater's power does",
    "reading_offsets": "slow offsets of the T2 and T5 readings (a thermometer drifting)",
    "pickups": "sinusoids on a reading at the residual's own spectral peaks (a pickup)",
}


@dataclass
class FamilyFit:
    """One family's columns and what it does alone on top of the extended model."""

    family: str
    columns: tuple
    labels: tuple
    score: CandidateScore | None = None


@dataclass(frozen=True, eq=False)
class MeasuredDisturbance:
    """The disturbance as fitted to a record: its offsets at the record's instants, and their parts.

    Stands in the model for :class:`cryod.model.Disturbance` while the record is replayed (it has the same
    :meth:`offsets_K`); :meth:`model_form` is what the model file keeps.
    """

    elapsed_s: np.ndarray
    flange_K: np.ndarray
    stage_K: np.ndarray
    unrecorded_heat_w: np.ndarray | None = None
    flange_offset_K: np.ndarray | None = None
    stage_offset_K: np.ndarray | None = None
    pickups: tuple = ()

    def offsets_K(self, time_s, heat_to_flange=None, heat_to_stage=None):
        """(flange, stage) offsets at ``time_s`` after the record's start (K)."""
        return np.interp(time_s, self.elapsed_s, self.flange_K), np.interp(time_s, self.elapsed_s, self.stage_K)

    def model_form(self) -> Disturbance:
        """The disturbance as the model file has it: random processes of the same rms and correlation time."""
        interval = float(np.median(np.diff(self.elapsed_s)))

        def process(values, seed):
            if values is None:
                return None
            return SlowProcess(float(np.std(values)), correlation_time_s(values, interval), seed)

        return Disturbance(process(self.unrecorded_heat_w, 1), process(self.flange_offset_K, 2),
                           process(self.stage_offset_K, 3), tuple(self.pickups))

    def parameters(self) -> dict:
        form = self.model_form()
        found = {}
        for name, unit in (("unrecorded_heat", "W"), ("flange_offset", "K"), ("ptc_stage_offset", "K")):
            process = getattr(form, name)
            if process is not None:
                found[f"{name}_rms_{unit}"] = process.rms
                found[f"{name}_correlation_time_s"] = process.correlation_time_s
        for index, pickup in enumerate(form.pickups):
            found[f"pickup_{index + 1}"] = (f"{pickup.thermometer} {pickup.frequency_hz:.5g} Hz "
                                            f"{pickup.amplitude_K * 1e6:.3g} µK")
        return found


@dataclass
class GenericExtension:
    """The generic extension fitted on top of a model.

    Attributes
    ----------
    fit : CandidateFit
        The families that count alone, fitted together (``cause`` is ``"generic"``); the model is the extended
        one plus the extension.
    score : CandidateScore
        On the held-out blocks against the extended model.
    added : bool
        Whether it counts, and so is part of the extended model.
    families : list of FamilyFit
        Each family alone, with its score.
    used : tuple of str
        The families in ``fit``.
    on_model : CryostatModel or None
        The model it extends.
    """

    fit: CandidateFit
    score: CandidateScore
    added: bool
    families: list = field(default_factory=list)
    used: tuple = ()
    on_model: CryostatModel | None = None

    def as_dict(self) -> dict:
        effects = self.fit.extended_model.effects
        correction = effects.heater_path_correction if "heater_path_correction" in self.used else None
        return {"generic": True, "added": self.added, "families_used": list(self.used),
                "families": [{"family": item.family, "meaning": MEANING[item.family], "terms": len(item.labels),
                              "held_out_improvement": item.score.improvement if item.score else None,
                              "significance": item.score.significance if item.score else None,
                              "explained_fraction": item.score.explained_fraction if item.score else None,
                              "gain": item.score.gain.as_dict() if item.score else None,
                              "counts": bool(item.score and item.score.counts)} for item in self.families],
                "heater_path_correction": None if correction is None else {
                    "time_constants_s": list(correction.time_constants_s),
                    "flange_gains_K_per_W": list(correction.flange_gains_K_per_W),
                    "ptc_stage_gains_K_per_W": list(correction.ptc_stage_gains_K_per_W)},
                "disturbance": self.fit.parameters.get("disturbance"),
                "held_out_improvement": self.score.improvement, "significance": self.score.significance,
                "explained_fraction": self.score.explained_fraction, "gain": self.score.gain.as_dict()}

    def sentences(self) -> list[str]:
        """What each family removes alone, in words, the largest first."""
        found = []
        for item in sorted(self.families, key=lambda item: -(item.score.improvement if item.score else -math.inf)):
            if item.score is None:
                found.append(f"{item.family} ({MEANING[item.family]}): no term to fit")
                continue
            found.append(f"{item.family} ({MEANING[item.family]}) alone removes "
                         f"{100.0 * item.score.explained_fraction:.1f} % of what is left "
                         f"({item.score.significance:.1f} sigma, held-out gain {item.score.gain.ratio:.3g})")
        return found


def _quiet(model: CryostatModel) -> CryostatModel:
    """``model`` with no cooler and no effect that is not a linear path of the heater's power."""
    return model.with_ptc(ptc_stage_amplitude_K=0.0, harmonics=()).with_effects(
        ptc_frequency_drift=None, ptc_amplitude_modulation=None, ptc_stage_drift=None, heater_path_correction=None,
        heat_capacity_temperature=None, heater_nonlinearity=None, dead_time=None, disturbance=None)


def _responses(context: FitContext, model: CryostatModel, heater_power_w=None):
    """T2's and T5's response (K) of ``model`` (quiet) to a heater power (default: the record's)."""
    simulated = context.replayer.simulate(model, heater_power_w)
    point = model.operating_point
    return simulated.flange_K - point.flange_temperature_K, simulated.ptc_stage_K - point.ptc_stage_temperature_K


def _heater_path_columns(context: FitContext, model: CryostatModel):
    quiet = _quiet(model)
    flange_columns, stage_columns = [], []
    for tau in TIME_CONSTANTS_S:
        lag = TransferFunction.first_order_lag(tau)
        flange, stage = _responses(context, dataclasses.replace(quiet, heater_to_flange=lag, heater_to_ptc_stage=lag))
        flange_columns.append(flange)
        stage_columns.append(stage)
    zeros = np.zeros((context.data.time_s.size, len(TIME_CONSTANTS_S)))
    labels = tuple(f"{path} {tau:.3g} s" for path in ("G1", "G3") for tau in TIME_CONSTANTS_S)
    return (np.column_stack(flange_columns + [zeros]), np.column_stack([zeros] + stage_columns)), labels


def _unrecorded_heat_columns(context: FitContext, model: CryostatModel, splines: np.ndarray):
    quiet = _quiet(model)
    flange_columns, stage_columns = [], []
    for index in range(splines.shape[1]):
        flange, stage = _responses(context, quiet, splines[:, index])
        flange_columns.append(flange)
        stage_columns.append(stage)
    return (np.column_stack(flange_columns), np.column_stack(stage_columns)), \
        tuple(f"heat spline {index + 1}" for index in range(splines.shape[1]))


def _offset_columns(splines: np.ndarray):
    zeros = np.zeros_like(splines)
    labels = tuple(f"{name} spline {index + 1}" for name in ("T2", "T5") for index in range(splines.shape[1]))
    return (np.column_stack([splines, zeros]), np.column_stack([zeros, splines])), labels


def pickup_frequencies(context: FitContext, replay) -> list[tuple[str, float]]:
    """(thermometer, frequency in Hz) of the residual's spectral peaks away from the cooler's harmonics and their
    sidebands (a peak where the heater has a line too is taken: under PI the heater answers a pickup)."""
    data = context.data
    valid = data.valid
    sample_hz = 1.0 / data.sample_interval_s
    line_hz = context.base_line.angular_frequency_rad_s / (2.0 * math.pi)
    found = []
    for thermometer, residual in (("flange", replay.flange_residual_K), ("ptc_stage", replay.ptc_stage_residual_K)):
        for peak in spectral_peaks(residual[valid], thermometer, sample_hz, line_hz):
            if peak.relation == NOT_AT_HARMONICS:
                found.append((thermometer, peak.frequency_hz))
    return found


def _pickup_columns(context: FitContext, frequencies):
    elapsed = context.data.elapsed_s
    count = elapsed.size
    flange_columns, stage_columns, labels = [], [], []
    for thermometer, frequency in frequencies:
        angle = 2.0 * math.pi * frequency * elapsed
        for part, values in (("sin", np.sin(angle)), ("cos", np.cos(angle))):
            on_flange = thermometer == "flange"
            flange_columns.append(values if on_flange else np.zeros(count))
            stage_columns.append(np.zeros(count) if on_flange else values)
            labels.append(f"{thermometer} {frequency:.5g} Hz {part}")
    return (np.column_stack(flange_columns), np.column_stack(stage_columns)), tuple(labels)


def family_columns(context: FitContext, model: CryostatModel, replay) -> list[FamilyFit]:
    """Every family's columns on the record (a family without terms has none)."""
    splines = slow_splines(context.data, SPLINE_DEGREE, SPLINE_BLOCKS)
    found = []
    columns, labels = _heater_path_columns(context, model)
    found.append(FamilyFit("heater_path_correction", columns, labels))
    columns, labels = _unrecorded_heat_columns(context, model, splines)
    found.append(FamilyFit("unrecorded_heat", columns, labels))
    columns, labels = _offset_columns(splines)
    found.append(FamilyFit("reading_offsets", columns, labels))
    frequencies = pickup_frequencies(context, replay)
    if frequencies:
        columns, labels = _pickup_columns(context, frequencies)
        found.append(FamilyFit("pickups", columns, labels))
    else:
        found.append(FamilyFit("pickups", (), ()))
    return found


def _extended(model: CryostatModel, context: FitContext, families: list, coefficients: np.ndarray):
    """``model`` plus the generic effects of ``families`` with their fitted ``coefficients``."""
    elapsed = context.data.elapsed_s
    count = elapsed.size
    flange_total, stage_total = np.zeros(count), np.zeros(count)
    parts, pickups, correction = {}, [], None
    start = 0
    splines = None
    for item in families:
        stop = start + len(item.labels)
        values = coefficients[start:stop]
        if item.family == "heater_path_correction":
            half = len(TIME_CONSTANTS_S)
            correction = HeaterPathCorrection(TIME_CONSTANTS_S, tuple(float(g) for g in values[:half]),
                                              tuple(float(g) for g in values[half:]))
        else:
            flange_total = flange_total + item.columns[0] @ values
            stage_total = stage_total + item.columns[1] @ values
            if item.family in ("unrecorded_heat", "reading_offsets"):
                splines = slow_splines(context.data, SPLINE_DEGREE, SPLINE_BLOCKS) if splines is None else splines
                if item.family == "unrecorded_heat":
                    parts["unrecorded_heat_w"] = splines @ values
                else:
                    half = splines.shape[1]
                    parts["flange_offset_K"] = splines @ values[:half]
                    parts["stage_offset_K"] = splines @ values[half:]
            elif item.family == "pickups":
                for index in range(0, len(item.labels), 2):
                    thermometer, frequency = item.labels[index].split(" ")[:2]
                    sine, cosine = float(values[index]), float(values[index + 1])
                    pickups.append(Pickup(thermometer, float(frequency), math.hypot(sine, cosine),
                                          math.atan2(cosine, sine)))
        start = stop
    disturbance = None
    if parts or pickups:
        disturbance = MeasuredDisturbance(elapsed, flange_total, stage_total, pickups=tuple(pickups), **parts)
    return model.with_effects(heater_path_correction=correction, disturbance=disturbance), disturbance


def _fit(context: FitContext, model: CryostatModel, replay, families: list, base, label: str) -> CandidateFit:
    columns = (np.column_stack([item.columns[0] for item in families]),
               np.column_stack([item.columns[1] for item in families]))
    fitted = context.replayer.replay_simulated(replay.model, replay.flange_K, replay.ptc_stage_K, columns)
    extended, disturbance = _extended(model, context, families, fitted.shared_coefficients)
    terms = sum(len(item.labels) for item in families)
    parameters = {"families": [item.family for item in families], "terms": terms}
    if disturbance is not None:
        parameters["disturbance"] = disturbance.parameters()
    return CandidateFit("generic", parameters, extended, fitted, context.base_line, label, parameter_count=terms)


#: Causes whose effect a family of the extension can represent, and those families: the cold end's drift is a slow
#: series on T5 and its response on T2, which the reading offsets (a free slow series on each reading) contain.
CONTAINING_FAMILIES = {"ptc_stage_drift": ("reading_offsets",)}


def containing_families(causes) -> tuple:
    """The families of the extension that can represent one of ``causes`` (:data:`CONTAINING_FAMILIES`)."""
    return tuple(sorted({family for cause in causes for family in CONTAINING_FAMILIES.get(cause, ())}))


def fit_generic_extension(context: FitContext, base, without: tuple = ()) -> GenericExtension:
    """The generic extension fitted on top of ``context``'s model and replay, judged against ``base`` (its
    discrepancy on the held-out blocks); ``without``: families left out."""
    model, replay = context.base_model, context.base_replay
    families = [item for item in family_columns(context, model, replay) if item.family not in without]
    for item in families:
        if item.labels:
            item.score = score_candidate(context, _fit(context, model, replay, [item], base, item.family), base)
    ranked = sorted(((item, item.score) for item in families if item.score is not None),
                    key=lambda scored: -scored[1].improvement)
    used = [item for item, _ in ranked[:1]]
    fit = _fit(context, model, replay, used, base, "generic: not a physical cause")
    for item, item_score in ranked[1:]:
        if not item_score.counts:
            break
        trial = _fit(context, model, replay, used + [item], base, "generic: not a physical cause")
        if _adds(context, fit, trial):
            used, fit = used + [item], trial
    score = score_candidate(context, fit, base)
    return GenericExtension(fit, score, score.counts, families, tuple(item.family for item in used), model)


def _adds(context: FitContext, before: CandidateFit, after: CandidateFit) -> bool:
    """Whether ``after`` improves on ``before`` on the held-out blocks as a cause must (5 sigma and 25)."""
    mask = context.held_out_mask
    improvement = sum(context.chi_square(before.replay, mask)) - sum(context.chi_square(after.replay, mask))
    sigma = significance(improvement, context.distinctness(before.replay, after.replay))
    return improvement >= CANDIDATE_MINIMUM_IMPROVEMENT and sigma >= CANDIDATE_SIGMA


__all__ = ["CONTAINING_FAMILIES", "FAMILIES", "GenericExtension", "containing_families", "MeasuredDisturbance", "TIME_CONSTANTS_S", "family_columns",
           "fit_generic_extension", "pickup_frequencies"]
