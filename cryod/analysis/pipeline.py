"""One analysis of one record: replay, noise, recalibration, candidates, decision, every cause present.

:func:`analyze` is what ``cryod analyze`` runs; the figures, the report and the
JSON are made from the :class:`Analysis` it returns.

Steps:

1. Split the record into fit and held-out blocks (:mod:`cryod.analysis.record_data`).
2. Measure the PTC line in T5 in the form the model has (its harmonic orders,
   its drift or none), replay the record with the base model, estimate the
   operating point and the initial state (:mod:`cryod.analysis.replay`).
3. Measure the noise of T2 and T5 in the base model's residuals
   (:mod:`cryod.analysis.noise`); it weights the two thermometers in the fits.
4. Recalibrate: refit the base model's own gains and time constants and the
   line's gain and phase on T2, within their tolerances
   (:mod:`cryod.analysis.recalibration`). When the base model as given shows a
   discrepancy, every later step starts from the recalibrated model and refits
   the recalibration alongside each cause.
5. Fit every candidate cause (:mod:`cryod.analysis.candidates`). The noise
   used for judging is the lowest white floor of any replay's residuals (a
   large misfit leaks a little into the base model's floor).
6. Judge the candidates on the held-out blocks (:mod:`cryod.analysis.decision`);
   refit the best one jointly with the recalibration
   (:mod:`cryod.analysis.refinement`) and add it to the model. While a
   discrepancy remains, look for the next cause on top of it: a further cause
   is named when it counts and removes at least 70 % of what is left.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from cryod.analysis.candidates import CANDIDATE_CAUSES, FITTERS, CandidateFit, FitContext
from cryod.analysis.decision import (
    CANDIDATE_MINIMUM_IMPROVEMENT, CANDIDATE_SIGMA, EXPLAINED_FRACTION, BaseDiscrepancy, CandidateScore, Decision, Gain, base_discrepancy, decide, gain_between,
    score_candidate,
)
from cryod.analysis.noise import white_noise_rms
from cryod.cooler.line import PtcLine
from cryod.analysis.recalibration import (
    LINK_PARAMETERS, RecalibratedBase, Recalibration, linear_basis, recalibrate,
)
from cryod.analysis.record_data import RecordData, fit_block_mask
from cryod.analysis.refinement import NamedEffect, combined_effect, joint_basis, refine
from cryod.analysis.replay import Replay, Replayer
from cryod.analysis.usability import check_usable
from cryod.model import CryostatModel

#: Causes named in one record at most.
MOST_CAUSES = 3


@dataclass
class NamedCause:
    """A cause named in the record, with what it brought when it was added to the model.

    Attributes
    ----------
    cause : str
    fit : CandidateFit
        Refitted jointly with the recalibration.
    score : CandidateScore
        Against the model it was added to.
    explained_fraction : float
        Its held-out improvement over the recalibrated model's excess.
    gain : Gain
        Held-out residual of the model before it and with it.
    """

    cause: str
    fit: CandidateFit
    score: CandidateScore
    explained_fraction: float
    gain: Gain


@dataclass
class Analysis:
    """Everything one analysis found.

    Attributes
    ----------
    data : RecordData
    base_model : CryostatModel
        The model as given.
    base_line : PtcLine
        The line measured in T5, in the base model's form.
    base_replay : Replay
        The record replayed with the base model as given.
    noise_rms_K : tuple of float
        Measured (T2, T5) noise.
    fits : dict of str to CandidateFit
        The candidates of the first round (on the recalibrated model).
    scores : dict of str to CandidateScore
    decision : Decision
        The cause named and why; its ``base`` is the recalibrated model's discrepancy.
    context : FitContext
        Where the first round's candidates were fitted.
    timings_s : dict of str to float
        Wall time of each step.
    recalibration : Recalibration or None
        The recalibration of the base model alone.
    final_recalibration : Recalibration or None
        The recalibration as refitted with the causes named (what the extended model has).
    recalibrated : bool
        Whether the recalibration is part of the extended model (it is when the
        base model as given shows a discrepancy).
    recalibration_gain : Gain or None
        Held-out residual of the base model as given and recalibrated.
    causes : list of NamedCause
        Every cause named, strongest (first added) first; empty for ``none``.
    final_model : CryostatModel
        The recalibrated model plus every cause named (the base model for ``none`` without recalibration).
    final_replay : Replay
    base_discrepancy : BaseDiscrepancy
        The base model as given, on the held-out blocks.
    """

    data: RecordData
    base_model: CryostatModel
    base_line: PtcLine
    base_replay: Replay
    noise_rms_K: tuple[float, float]
    fits: dict[str, CandidateFit]
    scores: dict[str, CandidateScore]
    decision: Decision
    context: FitContext
    timings_s: dict[str, float] = field(default_factory=dict)
    recalibration: Recalibration | None = None
    recalibrated: bool = False
    recalibration_gain: Gain | None = None
    causes: list = field(default_factory=list)
    final_model: CryostatModel | None = None
    final_replay: Replay | None = None
    base_discrepancy: BaseDiscrepancy | None = None
    final_recalibration: Recalibration | None = None

    @property
    def cause(self) -> str:
        return self.decision.cause

    @property
    def extended_model(self) -> CryostatModel:
        """The recalibrated base model plus every cause named (the base model itself when nothing changed)."""
        return self.final_model if self.final_model is not None else self.base_model

    @property
    def extended_replay(self) -> Replay:
        return self.final_replay if self.final_replay is not None else self.base_replay

    @property
    def extended(self) -> bool:
        """Whether the extended model differs from the base model."""
        return self.extended_model is not self.base_model

    @property
    def cause_names(self) -> list[str]:
        return [named.cause for named in self.causes]


def measured_noise(data: RecordData, replay: Replay, line: PtcLine) -> tuple[float, float]:
    """(T2, T5) white noise rms in a replay's residuals."""
    interval, frequency = data.sample_interval_s, line.angular_frequency_rad_s
    return (white_noise_rms(replay.flange_residual_K[data.valid], interval, frequency),
            white_noise_rms(replay.ptc_stage_residual_K[data.valid], interval, frequency))


def _carried(reference: CryostatModel | None):
    """``model -> model`` with ``reference``'s effects, PTC source and operating point (the causes named so far)."""
    if reference is None:
        return None
    return lambda model: dataclasses.replace(model, effects=reference.effects, ptc=reference.ptc,
                                             operating_point=reference.operating_point)


def _context_on(data, replayer: Replayer, base: RecalibratedBase, model: CryostatModel, line: PtcLine,
                state: Replay, noise, masks, reference: CryostatModel | None, against: Replay | None = None,
                line_model: CryostatModel | None = None, named=()) -> FitContext:
    """Candidates' context: ``model`` (the recalibration ``base`` plus the causes named so far, ``reference``),
    with the recalibration (and the ``named`` causes' own numbers) linearised there fitted in every replay;
    candidates are judged against ``against`` (default: ``model``'s replay)."""
    cache = {}
    carry = _carried(reference)
    effect = combined_effect([item.effect for item in named])
    excluded = tuple(sorted(set().union(*[set(item.excluded) for item in named])))

    def basis_for(replayed_line):
        key = id(replayed_line)
        if key not in cache:
            if effect is None:
                made = linear_basis(replayer, base.shipped, replayed_line, base.parameters, base.log_factors,
                                    state=state, apply=carry)
            else:
                wrapped = dataclasses.replace(effect, apply=lambda m, v: effect.apply(carry(m), v))
                made = joint_basis(replayer, base, replayed_line, wrapped, np.asarray(effect.values), state)
            cache[key] = (replayed_line, made.without(excluded) if excluded else made)
        return cache[key][1]

    replayer.basis_for = basis_for
    replay = against if against is not None else replayer.replay(model, line)
    return FitContext(data, replayer, model, line, replay, noise, masks[0], masks[1],
                      link_reference=base.model(without=LINK_PARAMETERS).ptc_to_flange, recalibrated=base,
                      line_model=line_model)


def _distinctness(context: FitContext, fits: dict):
    mask, noise = context.held_out_mask, context.noise_rms_K

    def distinctness(first: str, second: str) -> float:
        a, b = fits[first].replay, fits[second].replay
        flange = (a.flange_K - b.flange_K)[mask] / noise[0]
        stage = (a.ptc_stage_K - b.ptc_stage_K)[mask] / noise[1]
        return float(flange @ flange + stage @ stage)

    return distinctness


def _fit_candidates(context: FitContext, causes, timings: dict, label: str = "") -> dict:
    fits = {}
    for cause in causes:
        started = time.perf_counter()
        fits[cause] = FITTERS[cause](context)
        timings[cause + label] = timings.get(cause + label, 0.0) + time.perf_counter() - started
    return fits


def analyze(data: RecordData, base_model: CryostatModel, causes=CANDIDATE_CAUSES) -> Analysis:
    """Analyse one record against a model.

    Parameters
    ----------
    data : RecordData
    base_model : CryostatModel
    causes : sequence of str
        Candidate causes to try (default: all).

    Returns
    -------
    Analysis

    Raises
    ------
    cryod.analysis.usability.UnusableRecordError
        When the record cannot be analysed, saying what it is missing.
    """
    timings = {}
    started = time.perf_counter()
    check_usable(data)
    fit_mask = fit_block_mask(data.time_s) & data.valid
    held_out_mask = ~fit_block_mask(data.time_s) & data.valid
    masks = (fit_mask, held_out_mask)
    replayer = Replayer(data, fit_mask)
    orders = (1,) + tuple(h.order for h in base_model.ptc.harmonics)
    drift = base_model.effects.ptc_frequency_drift is not None
    base_line = replayer.stage_line(base_model, orders=orders, measured_phase=drift)
    replayer.settle_from(replayer.replay(base_model, base_line))
    base_replay = replayer.replay(base_model, base_line)
    noise = measured_noise(data, base_replay, base_line)
    replayer.noise_rms_K = noise
    shipped_context = FitContext(data, replayer, base_model, base_line, base_replay, noise, fit_mask, held_out_mask)
    timings["base replay and noise"] = time.perf_counter() - started

    started = time.perf_counter()
    recalibration = recalibrate(replayer, base_model, base_line)
    applied = base_discrepancy(shipped_context).present
    context, recalibrated_replay = shipped_context, recalibration.replay
    if applied:
        # Candidates are screened against the base model with the recalibration linearised at the shipped
        # parameters, as they are fitted themselves; whether anything needs a cause is judged on the
        # recalibrated model itself.
        line = replayer.stage_line(recalibration.model, orders=orders, measured_phase=drift)
        centre = dataclasses.replace(recalibration.base, log_factors=np.zeros(len(recalibration.parameters)))
        recalibrated_replay = replayer.replay(recalibration.model, line, basis=None)
        context = _context_on(data, replayer, centre, base_model, line, recalibration.replay, noise, masks, None,
                              line_model=recalibration.model)
    timings["recalibration"] = time.perf_counter() - started

    fits = _fit_candidates(context, causes, timings)
    # A large misfit leaks into the base model's noise floor; the best-fitting replay gives the truer noise.
    replays = [base_replay, recalibration.replay, context.base_replay] + [fit.replay for fit in fits.values()]
    lines = [base_line, base_line, context.base_line] + [fit.line for fit in fits.values()]
    noise = tuple(min(measured_noise(data, replay, line)[channel] for replay, line in zip(replays, lines))
                  for channel in (0, 1))
    shipped_context.noise_rms_K = context.noise_rms_K = noise
    shipped = base_discrepancy(shipped_context)
    first_base = base_discrepancy(context)
    scores = {cause: score_candidate(context, fits[cause], first_base) for cause in causes}
    counts = {cause: fit.parameter_count for cause, fit in fits.items()}
    first = decide(first_base, list(scores.values()), _distinctness(context, fits), counts)

    recalibrated_sum = sum(shipped_context.chi_square(recalibration.replay, held_out_mask))
    analysis = Analysis(data, base_model, base_line, base_replay, noise, fits, scores, first, context, timings,
                        recalibration, False, gain_between(shipped.sum_of_squares, recalibrated_sum, shipped.terms),
                        [], base_model, base_replay, shipped)
    if not shipped.present:
        analysis.decision = decide(shipped, [], None, None)
        analysis.decision = dataclasses.replace(
            analysis.decision, reason=analysis.decision.reason + "; the base model is kept as given")
        return analysis
    analysis.recalibrated = True
    analysis.final_model, analysis.final_replay = recalibration.model, recalibrated_replay
    recalibrated_context = dataclasses.replace(context, base_replay=recalibrated_replay)
    started = time.perf_counter()
    _name_causes(analysis, replayer, context, fits, scores, first, causes, masks,
                 base_discrepancy(recalibrated_context))
    timings["naming the causes"] = time.perf_counter() - started
    return analysis


@dataclass
class _Path:
    """Causes named one after another from a first choice, and where that leaves the model."""

    causes: list
    context: FitContext
    base: BaseDiscrepancy
    named_effects: list
    recalibration_base: RecalibratedBase
    reasons: list


def _name_causes(analysis: Analysis, replayer: Replayer, context: FitContext, fits: dict, scores: dict,
                 first: Decision, causes, masks, recalibrated: BaseDiscrepancy) -> None:
    """Add causes to the recalibrated model while the record shows a discrepancy (see the module doc).

    The best candidate is added first and the next ones on top of it. When that leaves a discrepancy, the
    path that starts from the second-best candidate is followed too (one cause can stand in for most of two:
    a thermometer lag with the stage lagging alike looks much like a dead time plus a link that differs), and
    the path that explains clearly more is kept.
    """
    recalibrated_base = base = recalibrated
    shipped = analysis.base_discrepancy
    if not base.present:
        analysis.decision = dataclasses.replace(
            first, cause="none", best=None, gain=analysis.recalibration_gain,
            reason=(f"the recalibrated base model leaves no discrepancy beyond the noise (held-out excess "
                    f"{base.excess:.4g}, {base.significance:.1f} sigma, {100.0 * base.excess / base.terms:.2f} % of "
                    f"the noise power); the base model as given left {shipped.excess:.4g} "
                    f"({shipped.significance:.1f} sigma): its parameters differ, no effect is needed"))
        return
    path = None
    if first.best is not None and first.best.cause in fits:
        decision, refined = _refined_decision(replayer, context, base, fits, scores, context.recalibrated)
        if decision.best is not None:
            path = _follow(analysis, replayer, context, base, decision.best, refined, causes, masks, recalibrated_base)
            alternatives = sorted((score_candidate(context, refined[cause][0], base) for cause in refined
                                   if cause != decision.best.cause), key=lambda score: -score.improvement)
            alternatives = [score for score in alternatives if score.counts]
            if path.base.present and alternatives:
                other = _follow(analysis, replayer, context, base, alternatives[0], refined, causes, masks,
                                recalibrated_base)
                if other.base.excess < ALTERNATIVE_FRACTION * path.base.excess and len(other.causes) > 1:
                    path = other
    excess_text = (f"the recalibrated base model's held-out excess is {recalibrated_base.excess:.4g} "
                   f"({recalibrated_base.significance:.1f} sigma, "
                   f"{100.0 * recalibrated_base.excess / recalibrated_base.terms:.2f} % of the noise power)")
    if path is None or not path.causes:
        analysis.decision = Decision("unexplained", f"{excess_text}, and no candidate improves it significantly",
                                     first.best, recalibrated_base,
                                     gain_between(shipped.sum_of_squares, recalibrated_base.sum_of_squares,
                                                  shipped.terms))
        analysis.final_model, analysis.final_replay = analysis.recalibration.model, analysis.final_replay
        return
    analysis.causes = path.causes
    base = path.base
    explained = (recalibrated_base.excess - base.excess) / recalibrated_base.excess
    total_gain = gain_between(shipped.sum_of_squares, shipped.sum_of_squares - shipped.excess + base.excess,
                              shipped.terms)
    if explained >= EXPLAINED_FRACTION or not base.present:
        named = analysis.causes[0]
        reason = f"{excess_text}; " + ", then ".join(path.reasons)
        tie = first.reason.find("this record cannot tell")
        if len(analysis.causes) == 1 and first.best is not None and first.best.cause == named.cause and tie >= 0:
            reason += "; " + first.reason[tie:]
        analysis.decision = Decision(named.cause, reason, named.score, recalibrated_base, total_gain)
        analysis.final_model, analysis.final_replay = path.context.base_model, path.context.base_replay
        analysis.final_recalibration = Recalibration.refitted(path.recalibration_base, path.context.base_replay)
        return
    analysis.decision = Decision(
        "unexplained",
        f"{excess_text}; {'; '.join(path.reasons)}: together {100.0 * explained:.1f} % of it, and a discrepancy "
        f"of {base.significance:.1f} sigma is left", first.best, recalibrated_base,
        gain_between(shipped.sum_of_squares, recalibrated_base.sum_of_squares, shipped.terms))
    analysis.final_model, analysis.final_replay = analysis.recalibration.model, analysis.final_replay


#: The path from the second-best first cause is kept when it leaves less than this fraction of the other's excess.
ALTERNATIVE_FRACTION = 0.5


def _follow(analysis: Analysis, replayer: Replayer, context: FitContext, base: BaseDiscrepancy, choice, refined,
            causes, masks, recalibrated_base: BaseDiscrepancy) -> _Path:
    """Name ``choice`` (a refined candidate's score) first, then causes on top of it while one counts and removes
    at least 70 % of what is left."""
    path = _Path([], context, base, [], context.recalibrated, [])
    remaining = list(causes)
    best = choice
    for round_index in range(MOST_CAUSES):
        if round_index > 0:
            fits = _fit_candidates(path.context, [c for c in remaining if not _already_in(c, path.context.base_model)],
                                   analysis.timings_s, " (next cause)")
            if not fits:
                break
            scores = {cause: score_candidate(path.context, fit, path.base) for cause, fit in fits.items()}
            if not any(score.counts for score in scores.values()):
                break
            decision, refined = _refined_decision(replayer, path.context, path.base, fits, scores,
                                                  path.recalibration_base, path.named_effects)
            best = decision.best
            if best is None or not (best.counts and best.explained_fraction >= EXPLAINED_FRACTION):
                if best is not None:
                    path.reasons.append(f"{best.cause} would remove {100.0 * best.explained_fraction:.1f} % of "
                                        "what is left, too little for a further cause")
                break
        if not best.counts:
            break
        fit, refined_base, others = refined[best.cause]
        after = gain_between(path.base.sum_of_squares, path.base.sum_of_squares - best.improvement, path.base.terms)
        earlier = [named for named in path.causes if named.fit.effect is not None]
        path.causes = [dataclasses.replace(named, fit=dataclasses.replace(
            named.fit, effect=other.effect, parameters=other.effect.describe(fit.extended_model)))
            if named in earlier else named for named, other in _pair_up(path.causes, earlier, others)]
        path.causes.append(NamedCause(best.cause, fit, best, best.improvement / recalibrated_base.excess, after))
        path.reasons.append(f"{best.cause} removes {100.0 * best.improvement / recalibrated_base.excess:.1f} % "
                            f"({best.significance:.1f} sigma)")
        remaining.remove(best.cause)
        _settle(path, analysis, replayer, masks, best.cause, fit, refined_base, others)
        if len(path.causes) > 1:
            _drop_unneeded(analysis, replayer, path, masks)
        if not path.base.present or len(path.causes) == MOST_CAUSES:
            break
    return path


def _pair_up(causes: list, earlier: list, others: list):
    """Each named cause with its refitted effect (None for causes without an effect form)."""
    refitted = dict(zip([id(named) for named in earlier], others))
    return [(named, refitted.get(id(named))) for named in causes]


def _settle(path: _Path, analysis: Analysis, replayer: Replayer, masks, cause: str, fit, refined_base,
            others) -> None:
    """The path on the model ``fit`` extends (``cause`` refitted with the other named effects ``others`` and the
    recalibration ``refined_base``): its named effects, recalibration, fit context and discrepancy."""
    path.named_effects = others + ([NamedEffect(cause, fit.effect, tuple(fit.excluded))]
                                   if fit.effect is not None else [])
    path.recalibration_base = refined_base
    path.context = _context_on(analysis.data, replayer, refined_base, fit.extended_model, fit.line, fit.replay,
                               path.context.noise_rms_K, masks, fit.extended_model, named=path.named_effects)
    path.base = base_discrepancy(path.context)


def _drop_unneeded(analysis: Analysis, replayer: Replayer, path: _Path, masks) -> None:
    """Leave out an earlier cause that the later ones have made unnecessary (it no longer counts on top of them).

    Once a further cause is named and all are refitted together, each earlier one is tried without: if what it
    adds no longer counts (5 sigma and 25), it is left out.
    """
    newest = path.causes[-1]
    for named in list(path.causes[:-1]):
        if named.fit.effect is None or len(path.named_effects) < 2:
            continue
        context = path.context
        kept = [item for item in path.named_effects if item.cause != named.cause]
        own = next((item.effect for item in kept if item.cause == newest.cause), newest.fit.effect)
        without = dataclasses.replace(newest.fit, extended_model=context.base_model.with_effects(**{named.cause: None}),
                                      replay=context.base_replay, effect=own)
        others = [item for item in kept if item.cause != newest.cause]
        fit, refined_base, others = refine(replayer, path.recalibration_base, without, others)
        mask, noise = context.held_out_mask, context.noise_rms_K
        flange = (fit.replay.flange_K - context.base_replay.flange_K)[mask] / noise[0]
        stage = (fit.replay.ptc_stage_K - context.base_replay.ptc_stage_K)[mask] / noise[1]
        distinct = float(flange @ flange + stage @ stage)
        adds = sum(context.chi_square(fit.replay, mask)) - path.base.sum_of_squares
        sigma = adds / (2.0 * math.sqrt(distinct)) if distinct > 0 else 0.0
        if adds >= CANDIDATE_MINIMUM_IMPROVEMENT and sigma >= CANDIDATE_SIGMA:
            continue
        path.reasons.append(f"{named.cause} left out: with {newest.cause} it adds only {adds:.4g} "
                            f"({sigma:.1f} sigma)")
        earlier = [item for item in path.causes if item is not named and item is not newest
                   and item.fit.effect is not None]
        refitted = dict(zip([id(item) for item in earlier], others))
        updated = []
        for item in path.causes:
            if item is named:
                continue
            if item is newest:
                item = dataclasses.replace(item, fit=dataclasses.replace(
                    item.fit, effect=fit.effect, parameters=fit.parameters if fit.effect else item.fit.parameters,
                    extended_model=fit.extended_model, replay=fit.replay))
            elif id(item) in refitted:
                item = dataclasses.replace(item, fit=dataclasses.replace(
                    item.fit, effect=refitted[id(item)].effect,
                    parameters=refitted[id(item)].effect.describe(fit.extended_model)))
            updated.append(item)
        path.causes = updated
        _settle(path, analysis, replayer, masks, newest.cause, fit, refined_base, others)
        newest = path.causes[-1]


#: Candidates refitted with the recalibration before one is chosen: those counting whose improvement is at least
#: this fraction of the best one's, at most this many.
REFINED_FRACTION = 0.5
REFINED_MOST = 3


def _refined_decision(replayer: Replayer, context: FitContext, base: BaseDiscrepancy, fits: dict, scores: dict,
                      recalibration_base: RecalibratedBase, named_effects=()):
    """Refit the leading candidates jointly with the recalibration (and the causes named so far), then apply
    the rules to them. Returns the decision and, per leading cause, (fit, recalibration, named effects)."""
    counting = sorted((score for score in scores.values() if score.counts), key=lambda score: -score.improvement)
    leading = [score.cause for score in counting
               if score.improvement >= REFINED_FRACTION * counting[0].improvement][:REFINED_MOST] if counting else []
    refined, refined_fits, refined_scores = {}, {}, {}
    for cause in leading:
        refined[cause] = refine(replayer, recalibration_base, fits[cause], named_effects)
        refined_fits[cause] = refined[cause][0]
        refined_scores[cause] = score_candidate(context, refined_fits[cause], base)
    decision = decide(base, list(refined_scores.values()), _distinctness(context, refined_fits),
                      {cause: fit.parameter_count for cause, fit in refined_fits.items()},
                      {cause: _strained(fit.replay) for cause, fit in refined_fits.items()})
    return decision, refined


#: A recalibration factor beyond this fraction of its tolerance is beyond the spread expected of a base model.
EXPECTED_SPREAD = 0.5


def _strained(replay: Replay) -> bool:
    """Whether a fit needed the recalibration to move a parameter beyond the spread expected of a base model."""
    basis = replay.basis
    if basis is None:
        return False
    values = (basis.values + replay.basis_change) / basis.widths
    return bool(np.any(np.abs(values) > EXPECTED_SPREAD))


def _already_in(cause: str, model: CryostatModel) -> bool:
    return cause in model.effect_names()


__all__ = ["Analysis", "NamedCause", "analyze"]
