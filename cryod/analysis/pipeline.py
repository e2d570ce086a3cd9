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
import time
from dataclasses import dataclass, field

import numpy as np

from cryod.analysis.base_model_off import explained_by_widening, judged_beyond_recalibration
from cryod.analysis.candidates import CANDIDATE_CAUSES, CandidateFit, FitContext
from cryod.analysis.fitters import FITTERS
from cryod.analysis.generic_extension import containing_families, fit_generic_extension
from cryod.analysis.equivalence import other_way_round, path_reading
from cryod.analysis.decision import (
    CANDIDATE_MINIMUM_IMPROVEMENT, CANDIDATE_SIGMA, EXPLAINED_FRACTION, BaseDiscrepancy, CandidateScore, Decision,
    Gain, base_discrepancy, decide, gain_between, score_candidate, significance,
)
from cryod.analysis.noise import white_noise_rms
from cryod.cooler.line import PtcLine
from cryod.analysis.recalibration import (
    LINK_PARAMETERS, RecalibratedBase, Recalibration, linear_basis, recalibrate,
)
from cryod.analysis.record_data import RecordData, fit_block_mask
from cryod.analysis.refinement import NamedEffect, combined_effect, joint_basis, refine
from cryod.analysis.replay import Replay, Replayer
from cryod.analysis.residual_signature import describe_residual
from cryod.analysis.usability import check_usable
from cryod.model import CryostatModel

#: Causes named in one record at most.
MOST_CAUSES = 3
#: The noise is the lowest white floor of the base model's, the recalibration's and this many candidates' replays
#: (those closest to the record on the fit blocks).
NOISE_FROM_FITS = 3


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
    final_recalibration : Recalibration or None
        The recalibration as refitted with the causes named (what the extended model has).
    remaining : BaseDiscrepancy or None
        What the extended model (the causes named, or the recalibrated model when none is) still shows on the
        held-out blocks, by the rule that calls for a cause.
    beyond_recalibration : object or None
        For ``base_model_off``: the parameters the record asks beyond the recalibration's tolerance
        (:class:`cryod.analysis.base_model_off.BeyondRecalibration`).
    generic : object or None
        The generic extension fitted on top of the extended model, when a discrepancy remains
        (:class:`cryod.analysis.generic_extension.GenericExtension`).
    residual_signature : object or None
        What the extended model leaves, described (:class:`cryod.analysis.residual_signature.ResidualSignature`).
    widened : Recalibration or None
        The base model alone recalibrated with the wider tolerances of :mod:`cryod.analysis.base_model_off`,
        once a parameter reached its usual tolerance.
    other_paths : list of dict
        Readings of other causes that fit the record as well as the causes named
        (:mod:`cryod.analysis.equivalence`; each with ``reading``, ``causes`` and ``told_apart_by``).
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
    remaining: BaseDiscrepancy | None = None
    beyond_recalibration: object = None
    generic: object = None
    residual_signature: object = None
    widened: Recalibration | None = None
    other_paths: list = field(default_factory=list)

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


def _distinctness(context: FitContext, fits: dict):
    def distinctness(first: str, second: str) -> float:
        return context.distinctness(fits[first].replay, fits[second].replay)

    return distinctness


@dataclass(frozen=True)
class ModelPoint:
    """Where candidates are fitted: a recalibration and the model the causes named so far make of it.

    Attributes
    ----------
    recalibration : RecalibratedBase
        The recalibration, linearised at its log factors in every replay.
    model : CryostatModel
        The recalibrated model plus the causes named so far.
    line : PtcLine
        The measured line the replays use.
    state : Replay
        A replay whose fitted initial state the linearisation holds.
    named : tuple of NamedEffect
        The causes named so far whose own numbers are refitted alongside the recalibration.
    carries_effects : bool
        Whether ``model``'s effects, PTC source and operating point go into the linearised
        recalibration's models (they do once a cause is named).
    """

    recalibration: RecalibratedBase
    model: CryostatModel
    line: PtcLine
    state: Replay
    named: tuple = ()
    carries_effects: bool = False

    def carried(self):
        """``model -> model`` with this point's effects, PTC source and operating point (None: nothing carried)."""
        if not self.carries_effects:
            return None
        reference = self.model
        return lambda model: dataclasses.replace(model, effects=reference.effects, ptc=reference.ptc,
                                                 operating_point=reference.operating_point)


@dataclass
class _Path:
    """Causes named one after another from a first choice, and where that leaves the model."""

    causes: list
    context: FitContext
    base: BaseDiscrepancy
    named_effects: list
    recalibration_base: RecalibratedBase
    reasons: list


@dataclass(frozen=True)
class SearchScope:
    """Which causes a :class:`CauseSearch` tries and how far it goes.

    Attributes
    ----------
    causes : tuple of str
        Candidate causes to try.
    screen_when_fitting : bool
        Fit the candidates (for the report's table) even when the base model as given shows no discrepancy.
    widen : bool
        When the recalibration leaves a parameter at its tolerance, recalibrate with the wider tolerances of
        :mod:`cryod.analysis.base_model_off`; if that alone explains the record, only the first cause is looked
        for within the tolerance (what a catalogue cause alone would say), not a path of several.
    most_causes : int
        Causes named at most (with 1, no second path is followed either).
    """

    causes: tuple = tuple(CANDIDATE_CAUSES)
    screen_when_fitting: bool = True
    widen: bool = True
    most_causes: int = MOST_CAUSES


class CauseSearch:
    """The search for the causes of one record's discrepancy (see the module doc).

    Holds the record, its fit and held-out masks, the replayer and the noise
    that weights the fits; :meth:`run` makes the :class:`Analysis`.

    Parameters
    ----------
    data : RecordData
    base_model : CryostatModel
    scope : SearchScope
        The causes tried and how far the search goes (default: every cause, the whole search).
    cycle_from : Replayer, optional
        A replayer of the same record whose cooler's phase, measured sample by sample in T5, is reused (the
        phase hardly depends on the model's heater part taken out of T5).
    """

    def __init__(self, data: RecordData, base_model: CryostatModel, scope: SearchScope = SearchScope(),
                 cycle_from: Replayer | None = None):
        self.data = data
        self.most_causes = scope.most_causes
        self.screen_when_fitting = scope.screen_when_fitting
        self.widen = scope.widen
        self.base_model = base_model
        self.causes = tuple(scope.causes)
        self.fit_mask = fit_block_mask(data.time_s) & data.valid
        self.held_out_mask = ~fit_block_mask(data.time_s) & data.valid
        self.replayer = Replayer(data, self.fit_mask)
        if cycle_from is not None:
            self.replayer.share_measured_cycle(cycle_from)
        self.noise_rms_K: tuple[float, float] = self.replayer.noise_rms_K
        self.timings_s: dict[str, float] = {}
        self.analysis: Analysis | None = None

    # -- contexts ----------------------------------------------------------
    def context_on(self, point: ModelPoint, against: Replay | None = None,
                   line_model: CryostatModel | None = None) -> FitContext:
        """Candidates' context on ``point``: its recalibration (and its named causes' own numbers) linearised there
        and fitted in every replay; candidates are judged against ``against`` (default: the point's model replayed)."""
        cache = {}
        carry = point.carried()
        effect = combined_effect([item.effect for item in point.named])
        excluded = tuple(sorted(set().union(*[set(item.excluded) for item in point.named])))
        replayer, base = self.replayer, point.recalibration

        def basis_for(replayed_line):
            key = id(replayed_line)
            if key not in cache:
                if effect is None:
                    made = linear_basis(replayer, base, replayed_line, state=point.state, apply=carry)
                else:
                    wrapped = dataclasses.replace(effect, apply=lambda m, v: effect.apply(carry(m), v))
                    made = joint_basis(replayer, base, replayed_line, wrapped, point.state)
                cache[key] = (replayed_line, made.without(excluded) if excluded else made)
            return cache[key][1]

        context = FitContext(self.data, replayer, point.model, point.line, against, self.noise_rms_K, self.fit_mask,
                             self.held_out_mask, link_reference=base.model(without=LINK_PARAMETERS).ptc_to_flange,
                             recalibrated=base, line_model=line_model, basis_for=basis_for)
        if against is None:
            context = dataclasses.replace(context, base_replay=context.replay(point.model, point.line))
        return context

    def fit_candidates(self, context: FitContext, causes, label: str = "") -> dict:
        """Each cause fitted in ``context``, timed under ``cause + label``."""
        fits = {}
        for cause in causes:
            started = time.perf_counter()
            fits[cause] = FITTERS[cause](context)
            self.timings_s[cause + label] = self.timings_s.get(cause + label, 0.0) + time.perf_counter() - started
        return fits

    # -- the analysis --------------------------------------------------------
    def run(self) -> Analysis:
        """Analyse the record (see :func:`analyze`)."""
        data, base_model, timings = self.data, self.base_model, self.timings_s
        started = time.perf_counter()
        check_usable(data)
        orders = (1,) + tuple(h.order for h in base_model.ptc.harmonics)
        drift = base_model.effects.ptc_frequency_drift is not None
        base_line = self.replayer.stage_line(base_model, orders=orders, measured_phase=drift)
        self.replayer.settle_from(self.replayer.replay(base_model, base_line))
        base_replay = self.replayer.replay(base_model, base_line)
        self.noise_rms_K = noise = measured_noise(data, base_replay, base_line)
        self.replayer = replayer = self.replayer.weighted(noise)
        shipped_context = FitContext(data, replayer, base_model, base_line, base_replay, noise, self.fit_mask,
                                     self.held_out_mask)
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
            recalibrated_replay = replayer.replay(recalibration.model, line)
            context = self.context_on(ModelPoint(centre, base_model, line, recalibration.replay),
                                      line_model=recalibration.model)
        timings["recalibration"] = time.perf_counter() - started

        fits = self.fit_candidates(context, self.causes if applied or self.screen_when_fitting else ())
        # A large misfit leaks into the base model's noise floor; the best-fitting replays give the truer noise.
        closest = sorted(fits.values(), key=lambda fit: context.fit_chi_square(fit.replay))[:NOISE_FROM_FITS]
        replays = [base_replay, recalibration.replay, context.base_replay] + [fit.replay for fit in closest]
        lines = [base_line, base_line, context.base_line] + [fit.line for fit in closest]
        self.noise_rms_K = noise = tuple(
            min(measured_noise(data, replay, line)[channel] for replay, line in zip(replays, lines))
            for channel in (0, 1))
        shipped_context = dataclasses.replace(shipped_context, noise_rms_K=noise)
        context = dataclasses.replace(context, noise_rms_K=noise)
        shipped = base_discrepancy(shipped_context)
        first_base = base_discrepancy(context)
        scores = {cause: score_candidate(context, fits[cause], first_base) for cause in fits}
        counts = {cause: fit.parameter_count for cause, fit in fits.items()}
        first = decide(first_base, list(scores.values()), _distinctness(context, fits), counts)

        recalibrated_sum = sum(shipped_context.chi_square(recalibration.replay, self.held_out_mask))
        analysis = self.analysis = Analysis(
            data, base_model, base_line, base_replay, noise, fits, scores, first, context, timings, recalibration,
            False, gain_between(shipped.sum_of_squares, recalibrated_sum, shipped.terms), [], base_model,
            base_replay, shipped)
        if not shipped.present:
            analysis.decision = decide(shipped, [], None, None)
            analysis.decision = dataclasses.replace(
                analysis.decision, reason=analysis.decision.reason + "; the base model is kept as given")
            analysis.remaining = shipped
            return analysis
        analysis.recalibrated = True
        analysis.final_model, analysis.final_replay = recalibration.model, recalibrated_replay
        recalibrated_context = dataclasses.replace(context, base_replay=recalibrated_replay)
        first_only = self.widen and any(row.at_tolerance for row in recalibration.table()) \
            and explained_by_widening(self, analysis)
        started = time.perf_counter()
        self._name_causes(base_discrepancy(recalibrated_context), 1 if first_only else self.most_causes)
        timings["naming the causes"] = time.perf_counter() - started
        return analysis

    def _name_causes(self, recalibrated: BaseDiscrepancy, most: int) -> None:
        """Add causes to the recalibrated model while the record shows a discrepancy (see the module doc).

        The best candidate is added first and the next ones on top of it. When that leaves a discrepancy, the path
        that starts from the second-best candidate is followed too (one cause can stand in for most of two: a
        thermometer lag with the stage lagging alike looks much like a dead time plus a link that differs), and
        when the first path would name its causes (they remove 70 % of the excess) the paths from the other leading
        candidates as well (refitted with the recalibration, counting: a lag of seconds on both thermometers takes
        most of a heat capacity plus a link); of the paths with more than one cause that leave less than half the
        first path's excess, the one that leaves least is kept. At most ``most`` causes; with 1, no second path.
        """
        analysis = self.analysis
        context, fits, scores, first = analysis.context, analysis.fits, analysis.scores, analysis.decision
        recalibrated_base = base = recalibrated
        shipped = analysis.base_discrepancy
        if not base.present:
            analysis.decision = dataclasses.replace(
                first, cause="none", best=None, gain=analysis.recalibration_gain,
                reason=(f"the recalibrated base model leaves no discrepancy beyond the noise (held-out excess "
                        f"{base.excess:.4g}, {base.significance:.1f} sigma, {100.0 * base.excess / base.terms:.2f} % "
                        f"of the noise power); the base model as given left {shipped.excess:.4g} "
                        f"({shipped.significance:.1f} sigma): its parameters differ, no effect is needed"))
            analysis.remaining = base
            return
        path, refined = None, {}
        if first.best is not None and first.best.cause in fits:
            start = _Path([], context, base, [], context.recalibrated, [])
            decision, refined = self._refined_decision(start, fits, scores)
            if decision.best is not None:
                path = self._follow(decision.best, refined, recalibrated_base, most)
                alternatives = [] if most == 1 else sorted(
                    (score_candidate(context, refined[cause][0], base) for cause in refined
                     if cause != decision.best.cause), key=lambda score: -score.improvement)
                alternatives = [score for score in alternatives if score.counts]
                first_path = path
                removed = recalibrated_base.excess - path.base.excess
                names_a_cause = removed >= EXPLAINED_FRACTION * recalibrated_base.excess
                for alternative in (alternatives if names_a_cause else alternatives[:1]) if path.base.present else []:
                    other = self._follow(alternative, refined, recalibrated_base, most)
                    if (other.base.excess < ALTERNATIVE_FRACTION * first_path.base.excess and len(other.causes) > 1
                            and other.base.excess < path.base.excess):
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
            analysis.remaining = recalibrated_base
            return
        turned = self._the_other_way_round(path, fits, refined, recalibrated_base) if most > 1 else None
        if turned is not None:
            other, better, sigma = turned
            if better >= CANDIDATE_MINIMUM_IMPROVEMENT and sigma >= CANDIDATE_SIGMA:
                other.reasons.append(f"these leave {better:.4g} less than "
                                     f"{' + '.join(named.cause for named in path.causes)} ({sigma:.1f} sigma), "
                                     "which they stand for")
                path = other
            else:
                analysis.other_paths = [path_reading(other.causes, better, sigma)]
        analysis.causes = path.causes
        base = path.base
        explained = (recalibrated_base.excess - base.excess) / recalibrated_base.excess
        total_gain = gain_between(shipped.sum_of_squares, shipped.sum_of_squares - shipped.excess + base.excess,
                                  shipped.terms)
        if base.present and explained >= EXPLAINED_FRACTION:
            beaten = self._against_generic(path, recalibrated_base)
            if beaten:
                analysis.causes = []
                analysis.decision = Decision(
                    "unexplained", f"{excess_text}; {'; '.join(path.reasons)}: together {100.0 * explained:.1f} % of "
                    f"it, and a discrepancy of {base.significance:.1f} sigma is left; {beaten}", first.best,
                    recalibrated_base, gain_between(shipped.sum_of_squares, recalibrated_base.sum_of_squares,
                                                    shipped.terms))
                analysis.remaining = recalibrated_base
                return
        if explained >= EXPLAINED_FRACTION or not base.present:
            named = analysis.causes[0]
            reason = f"{excess_text}; " + ", then ".join(path.reasons)
            tie = first.reason.find("this record cannot tell")
            if len(analysis.causes) == 1 and first.best is not None and first.best.cause == named.cause and tie >= 0:
                reason += "; " + first.reason[tie:]
            tied = first.tied if tie >= 0 and len(analysis.causes) == 1 and first.best.cause == named.cause else ()
            analysis.decision = Decision(named.cause, reason, named.score, recalibrated_base, total_gain, tied)
            analysis.final_model, analysis.final_replay = path.context.base_model, path.context.base_replay
            analysis.final_recalibration = Recalibration.refitted(path.recalibration_base, path.context.base_replay)
            analysis.remaining = base
            return
        analysis.causes = []                   # too little of the discrepancy explained: none is named
        analysis.decision = Decision(
            "unexplained",
            f"{excess_text}; {'; '.join(path.reasons)}: together {100.0 * explained:.1f} % of it, and a discrepancy "
            f"of {base.significance:.1f} sigma is left", first.best, recalibrated_base,
            gain_between(shipped.sum_of_squares, recalibrated_base.sum_of_squares, shipped.terms))
        analysis.final_model, analysis.final_replay = analysis.recalibration.model, analysis.final_replay
        analysis.remaining = recalibrated_base

    def _the_other_way_round(self, path: _Path, fits: dict, refined: dict, recalibrated_base: BaseDiscrepancy):
        """The causes named on ``path``, leaving no discrepancy, read the other way round
        (:func:`cryod.analysis.equivalence.other_way_round`: a flange thermometer's lag alone as a dead time with
        a link; a link with a dead time as the lag with a dead time). Returns (that path, how much lower it leaves
        the held-out sum of squares, in standard deviations of the difference between the two predictions), or
        None when no such reading applies or it leaves a discrepancy. ``refined``: the first round's candidates
        already refitted with the recalibration (:meth:`_refined_decision`), reused when the reading starts
        with one of them.

        The lag delays T2 on every path: on the heater's like a dead time (as far as the heater's content is
        slow against the lag), on the line's like a link that lags. The other reading is followed as any path
        is, its first cause first. When it adds what a cause must (5 sigma and 25) it is named instead;
        otherwise the record cannot tell it from the causes named, and it is their equivalent reading
        (:func:`cryod.analysis.equivalence.path_reading`)."""
        other_causes = other_way_round(path.causes)
        if other_causes is None or path.base.present or other_causes[0] not in fits:
            return None
        context, first = self.analysis.context, other_causes[0]
        refined = {first: refined.get(first) or refine(self.replayer, context.recalibrated, fits[first], [])}
        score = score_candidate(context, refined[first][0], recalibrated_base)
        if not score.counts:
            return None
        other = self._follow(score, refined, recalibrated_base, len(other_causes), causes=other_causes)
        if tuple(named.cause for named in other.causes) != other_causes or other.base.present:
            return None
        better = path.base.sum_of_squares - other.base.sum_of_squares
        return other, better, significance(better, context.distinctness(path.context.base_replay,
                                                                        other.context.base_replay))

    def _against_generic(self, path: _Path, recalibrated_base: BaseDiscrepancy) -> str:
        """When the causes on ``path`` leave a discrepancy: whether they add anything significant to the generic
        extension. The extension fitted on the recalibrated model alone is compared, on the held-out blocks, with
        the extension fitted on top of the causes; if the causes add less than a candidate must (5 sigma and 25),
        they stand in for something the catalogue does not have, and the reason is returned ('' when they add).
        A family that can itself represent a cause named (:data:`~cryod.analysis.generic_extension.
        CONTAINING_FAMILIES`: the reading offsets, a free slow series on T2 and on T5, contain the cold end's
        drift) is left out of this comparison: against it a cause cannot add, whether it is right or not, and the
        cause says with two numbers (its coupling) what the family says with a free series.
        The extension that goes with the verdict is kept for the analysis (fitted again with every family when
        one was left out)."""
        analysis = self.analysis
        left_out = containing_families(cause.cause for cause in path.causes)
        adds, sigma, alone, on_causes = self._added_to_generic(
            (analysis.final_model, analysis.final_replay, recalibrated_base),
            (path.context.base_model, path.context.base_replay, path.base), left_out)
        if adds >= CANDIDATE_MINIMUM_IMPROVEMENT and sigma >= CANDIDATE_SIGMA:
            analysis.generic = None if left_out else on_causes
            return ""
        analysis.generic = None if left_out else alone
        return (f"with the generic extension ({' + '.join(alone.used)}) the causes add only {adds:.4g} "
                f"({sigma:.1f} sigma) on the held-out blocks: they stand in for something outside the catalogue, "
                "and no physical cause is named")

    def _added_to_generic(self, without: tuple, with_: tuple, left_out: tuple = ()):
        """What the causes of one model add to the generic extension over another's: each given as (model, replay,
        its held-out discrepancy); ``left_out``: families of the extension not fitted. Returns (held-out
        improvement, its significance, the extension on each)."""
        first = fit_generic_extension(self._extension_context(without[0], without[1]), without[2], left_out)
        second = fit_generic_extension(self._extension_context(with_[0], with_[1]), with_[2], left_out)
        context = self.analysis.context
        a, b = first.fit.replay, second.fit.replay
        adds = sum(context.chi_square(a, context.held_out_mask)) - sum(context.chi_square(b, context.held_out_mask))
        return adds, significance(adds, context.distinctness(a, b)), first, second

    def _extension_context(self, model: CryostatModel, replay: Replay) -> FitContext:
        """A context on ``model`` and its replay, without a linearised recalibration (for the generic extension)."""
        context = self.analysis.context
        return FitContext(self.data, self.replayer, model, context.base_line, replay, self.noise_rms_K,
                          self.fit_mask, self.held_out_mask)

    def _follow(self, choice: CandidateScore, refined: dict, recalibrated_base: BaseDiscrepancy,
                most: int = MOST_CAUSES, causes=None) -> _Path:
        """Name ``choice`` (a refined candidate's score) first, then causes on top of it while one counts and
        removes at least 70 % of what is left (``most`` causes in all). A further cause that leaves a discrepancy
        must also add significantly to the generic extension on the model without it: a leftover of the causes
        named (a drift's spline that is a little too stiff) is not taken for another cause. Every cause of the
        search is tried on top of those named, also one that made the first round worse: with a much larger effect
        unnamed, a small one's fit takes that effect's misfit (a thermometer's lag of 60 ms beside a heat capacity
        that removes 99.8 %), and only once the larger one is named does it fit what it stands for.
        ``causes``: those tried (default: the search's)."""
        context = self.analysis.context
        path = _Path([], context, recalibrated_base, [], context.recalibrated, [])
        remaining = list(self.causes if causes is None else causes)
        if choice.cause not in remaining:
            remaining.append(choice.cause)
        best = choice
        for round_index in range(most):
            if round_index > 0:
                fits = self.fit_candidates(path.context, [c for c in remaining
                                                          if not _already_in(c, path.context.base_model)],
                                           " (next cause)")
                if not fits:
                    break
                scores = {cause: score_candidate(path.context, fit, path.base) for cause, fit in fits.items()}
                if not any(score.counts for score in scores.values()):
                    break
                decision, refined = self._refined_decision(path, fits, scores)
                best = decision.best
                if best is None or not (best.counts and best.explained_fraction >= EXPLAINED_FRACTION):
                    if best is not None:
                        path.reasons.append(f"{best.cause} would remove {100.0 * best.explained_fraction:.1f} % of "
                                            "what is left, too little for a further cause")
                    break
            if not best.counts:
                break
            before = dataclasses.replace(path, causes=list(path.causes), named_effects=list(path.named_effects),
                                         reasons=list(path.reasons))
            fit, refined_base, others = refined[best.cause]
            after = gain_between(path.base.sum_of_squares, path.base.sum_of_squares - best.improvement,
                                 path.base.terms)
            earlier = [named for named in path.causes if named.fit.effect is not None]
            path.causes = [dataclasses.replace(named, fit=dataclasses.replace(
                named.fit, effect=other.effect, parameters=other.effect.describe(fit.extended_model)))
                if named in earlier else named for named, other in _pair_up(path.causes, earlier, others)]
            path.causes.append(NamedCause(best.cause, fit, best, best.improvement / recalibrated_base.excess, after))
            path.reasons.append(f"{best.cause} removes {100.0 * best.improvement / recalibrated_base.excess:.1f} % "
                                f"({best.significance:.1f} sigma)")
            remaining.remove(best.cause)
            self._settle(path, best.cause, refined[best.cause])
            if len(path.causes) > 1:
                self._drop_unneeded(path)
            if round_index > 0 and path.base.present:
                adds, sigma, _, _ = self._added_to_generic(
                    (before.context.base_model, before.context.base_replay, before.base),
                    (path.context.base_model, path.context.base_replay, path.base),
                    containing_families([best.cause]))
                if not (adds >= CANDIDATE_MINIMUM_IMPROVEMENT and sigma >= CANDIDATE_SIGMA):
                    before.reasons.append(f"{best.cause} would remove {100.0 * best.explained_fraction:.1f} % of what "
                                          f"is left but adds only {adds:.4g} ({sigma:.1f} sigma) to the generic "
                                          "extension: not a further cause")
                    path.__dict__.update(vars(before))
                    break
            if not path.base.present or len(path.causes) == most:
                break
        return path

    def _settle(self, path: _Path, cause: str, refined: tuple) -> None:
        """The path on the model a refined fit extends (``refined``: ``cause``'s fit refitted with the recalibration
        and the other named effects, :func:`cryod.analysis.refinement.refine`): its named effects,
        recalibration, fit context and discrepancy."""
        fit, refined_base, others = refined
        path.named_effects = others + ([NamedEffect(cause, fit.effect, tuple(fit.excluded))]
                                       if fit.effect is not None else [])
        path.recalibration_base = refined_base
        point = ModelPoint(refined_base, fit.extended_model, fit.line, fit.replay, tuple(path.named_effects),
                           carries_effects=True)
        path.context = self.context_on(point)
        path.base = base_discrepancy(path.context)

    def _drop_unneeded(self, path: _Path) -> None:
        """Leave out an earlier cause that the later ones have made unnecessary.

        Once a further cause is named and all are refitted together, each earlier one is tried without, and judged
        as a further cause on top of the others would be: it stays when what it adds counts (5 sigma and 25) and,
        while the model with it still shows a discrepancy, removes at least 70 % of what the model without it
        leaves. On a record whose discrepancy is a million times the noise, a cause that the later ones made
        unnecessary still adds far more than 25 (it refits the recalibration a little better); against what is
        left it is a percent or so.
        """
        newest = path.causes[-1]
        for named in list(path.causes[:-1]):
            if named.fit.effect is None or len(path.named_effects) < 2:
                continue
            context = path.context
            kept = [item for item in path.named_effects if item.cause != named.cause]
            own = next((item.effect for item in kept if item.cause == newest.cause), newest.fit.effect)
            without = dataclasses.replace(newest.fit,
                                          extended_model=context.base_model.with_effects(**{named.cause: None}),
                                          replay=context.base_replay, effect=own)
            others = [item for item in kept if item.cause != newest.cause]
            fit, refined_base, others = refine(self.replayer, path.recalibration_base, without, others)
            distinct = context.distinctness(fit.replay, context.base_replay)
            adds = sum(context.chi_square(fit.replay, context.held_out_mask)) - path.base.sum_of_squares
            sigma = significance(adds, distinct)
            without_excess = path.base.excess + adds
            if (adds >= CANDIDATE_MINIMUM_IMPROVEMENT and sigma >= CANDIDATE_SIGMA
                    and (not path.base.present or adds >= EXPLAINED_FRACTION * without_excess)):
                continue
            path.reasons.append(f"{named.cause} left out: with {newest.cause} it adds only {adds:.4g} "
                                f"({sigma:.1f} sigma, {100.0 * adds / max(without_excess, 1e-300):.1f} % of what is "
                                "left without it)")
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
            self._settle(path, newest.cause, (fit, refined_base, others))
            newest = path.causes[-1]

    def _refined_decision(self, path: _Path, fits: dict, scores: dict):
        """Refit the leading candidates jointly with the recalibration (and the causes named so far on ``path``),
        then apply the rules to them. Returns the decision and, per leading cause, (fit, recalibration, named
        effects)."""
        context, base = path.context, path.base
        counting = sorted((score for score in scores.values() if score.counts), key=lambda score: -score.improvement)
        leading = [score.cause for score in counting
                   if score.improvement >= REFINED_FRACTION * counting[0].improvement][:REFINED_MOST] \
            if counting else []
        refined, refined_fits, refined_scores = {}, {}, {}
        for cause in leading:
            refined[cause] = refine(self.replayer, path.recalibration_base, fits[cause], path.named_effects)
            refined_fits[cause] = refined[cause][0]
            refined_scores[cause] = score_candidate(context, refined_fits[cause], base)
        decision = decide(base, list(refined_scores.values()), _distinctness(context, refined_fits),
                          {cause: fit.parameter_count for cause, fit in refined_fits.items()},
                          {cause: _strained(fit.replay) for cause, fit in refined_fits.items()})
        return decision, refined


def improving_causes(scores: dict) -> list[str]:
    """The causes whose first fit improved the held-out residual at all: the only ones tried on a base model
    widened beyond the recalibration (one cause at most, on top of a change of the base model that stands for the
    record's largest misfit); one that makes the first round worse fits the fit blocks' noise or that misfit."""
    return [cause for cause, score in scores.items() if score.improvement > 0.0]


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
    search = CauseSearch(data, base_model, SearchScope(tuple(causes)))
    analysis = judged_beyond_recalibration(
        search, search.run(), lambda model: CauseSearch(
            data, model, SearchScope(tuple(improving_causes(search.analysis.scores) or causes),
                                     screen_when_fitting=False, widen=False, most_causes=1),
            cycle_from=search.replayer).run())
    started = time.perf_counter()
    described_and_extended(analysis)
    analysis.timings_s["residual and generic extension"] = time.perf_counter() - started
    return analysis


def described_and_extended(analysis: Analysis) -> None:
    """The residual's signature, and the generic extension added where the extended model leaves a discrepancy
    (the one fitted when the causes were weighed against it, if they were); the gain is then the base model's
    against the model extended by both."""
    analysis.residual_signature = describe_residual(analysis)
    if analysis.remaining is None or not analysis.remaining.present:
        analysis.generic = None
        return
    if analysis.generic is None or analysis.generic.on_model is not analysis.extended_model:
        context = analysis.context
        on_extended = FitContext(analysis.data, context.replayer, analysis.extended_model, analysis.base_line,
                                 analysis.extended_replay, analysis.noise_rms_K, context.fit_mask,
                                 context.held_out_mask)
        analysis.generic = fit_generic_extension(on_extended, analysis.remaining)
    if analysis.generic.added:
        analysis.final_model = analysis.generic.fit.extended_model
        analysis.final_replay = analysis.generic.fit.replay
        score, shipped = analysis.generic.score, analysis.base_discrepancy
        analysis.decision = dataclasses.replace(analysis.decision, gain=gain_between(
            shipped.sum_of_squares, score.held_out_flange + score.held_out_stage, shipped.terms))


def _pair_up(causes: list, earlier: list, others: list):
    """Each named cause with its refitted effect (None for causes without an effect form)."""
    refitted = dict(zip([id(named) for named in earlier], others))
    return [(named, refitted.get(id(named))) for named in causes]


#: The path from the second-best first cause is kept when it leaves less than this fraction of the other's excess.
ALTERNATIVE_FRACTION = 0.5
#: Candidates refitted with the recalibration before one is chosen: those counting whose improvement is at least
#: this fraction of the best one's, at most this many.
REFINED_FRACTION = 0.5
REFINED_MOST = 3


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


__all__ = ["Analysis", "CauseSearch", "ModelPoint", "NamedCause", "analyze", "improving_causes"]
