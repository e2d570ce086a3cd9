"""The cause search's first steps: replay the record, recalibrate the base model, rank the candidates.

1. :func:`replay_record`: the line measured in T5 in the base model's form, the
   record replayed with the base model as given, the noise of T2 and T5 in its
   residuals (it weights the two thermometers in every fit from then on).
2. :func:`recalibrate_base`: the base model's own gains and time constants and
   the line's gain and phase on T2 refitted within their tolerances
   (:mod:`cryod.analysis.recalibration`). When the base model as given shows a
   discrepancy, the candidates are fitted with the recalibration linearised at
   the shipped parameters, beside their own numbers.
3. :func:`rank_candidates`: every candidate cause fitted
   (:mod:`cryod.analysis.candidates`), the noise measured again in the closest
   fits (a large misfit leaks into the base model's noise floor), each
   candidate scored on the held-out blocks and the rules of
   :mod:`cryod.analysis.decision` applied to them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from cryod.analysis.candidates import CandidateFit, FitContext
from cryod.analysis.cause_search.at_signature import scores_at_signature
from cryod.analysis.cause_search.record_search import ModelPoint, RecordSearch
from cryod.analysis.cause_search.rules import NOISE_FROM_FITS
from cryod.analysis.cause_signature import BandLayout
from cryod.analysis.decision import (
    BaseDiscrepancy,
    CandidateScore,
    Decision,
    Gain,
    base_discrepancy,
    decide,
    gain_between,
    score_candidate,
)
from cryod.analysis.noise import white_noise_rms
from cryod.analysis.recalibration import Recalibration, recalibrate
from cryod.analysis.record_data import RecordData
from cryod.analysis.replay import Replay
from cryod.analysis.usability import check_usable
from cryod.cooler.line import PtcLine


@dataclass(frozen=True, kw_only=True)
class ReplayedRecord:
    """The record replayed with the base model as given (:func:`replay_record`).

    Attributes
    ----------
    search : RecordSearch
        Weighted by the noise measured in the replay.
    orders : tuple of int
        The line's harmonic orders in the base model's form.
    measured_phase : bool
        Whether the line is replayed at the cooler's phase measured in T5 (the base model has a frequency drift).
    base_line : PtcLine
    base_replay : Replay
    as_given : FitContext
        The base model as given, replayed.
    """

    search: RecordSearch
    orders: tuple[int, ...]
    measured_phase: bool
    base_line: PtcLine
    base_replay: Replay
    as_given: FitContext


@dataclass(frozen=True, kw_only=True)
class RecalibratedRecord:
    """The base model recalibrated, and where the candidates are fitted (:func:`recalibrate_base`).

    Attributes
    ----------
    replayed : ReplayedRecord
    recalibration : Recalibration
    applied : bool
        Whether the base model as given shows a discrepancy (by the noise of its replay): the candidates are then
        fitted with the recalibration.
    context : FitContext
        Where the candidates are fitted: the base model with the recalibration linearised at the shipped
        parameters (the base model as given when not ``applied``).
    recalibrated_replay : Replay
        The recalibrated model replayed with the line measured for it.
    """

    replayed: ReplayedRecord
    recalibration: Recalibration
    applied: bool
    context: FitContext
    recalibrated_replay: Replay


@dataclass(frozen=True, kw_only=True)
class FirstRound:
    """The candidates fitted and ranked (:func:`rank_candidates`): what every later step starts from.

    Attributes
    ----------
    search : RecordSearch
        Weighted and judging by the noise measured again in the closest fits.
    base_line, base_replay : PtcLine, Replay
        The base model as given.
    recalibration : Recalibration
    recalibrated_replay : Replay
    context : FitContext
        Where the candidates were fitted, judging by the search's noise.
    as_given : BaseDiscrepancy
        The base model as given, on the held-out blocks.
    recalibrated : BaseDiscrepancy
        The recalibrated model, on the held-out blocks: what the causes are to explain.
    recalibration_gain : Gain
        Held-out residual of the base model as given and recalibrated.
    fits : dict of str to CandidateFit
    scores : dict of str to CandidateScore
        Against ``context``'s model.
    decision : Decision
        The rules of :mod:`cryod.analysis.decision` on ``scores``.
    bands : BandLayout
        Where each cause's signature is measured on the held-out blocks (:mod:`cryod.analysis.cause_signature`).
    """

    search: RecordSearch
    base_line: PtcLine
    base_replay: Replay
    recalibration: Recalibration
    recalibrated_replay: Replay
    context: FitContext
    as_given: BaseDiscrepancy
    recalibrated: BaseDiscrepancy
    recalibration_gain: Gain
    fits: dict[str, CandidateFit]
    scores: dict[str, CandidateScore]
    decision: Decision
    bands: BandLayout


def measured_noise(data: RecordData, replay: Replay, line: PtcLine) -> tuple[float, float]:
    """(T2, T5) white noise rms in a replay's residuals."""
    interval, frequency = data.sample_interval_s, line.angular_frequency_rad_s
    return (white_noise_rms(replay.flange_residual_K[data.valid], interval, frequency),
            white_noise_rms(replay.ptc_stage_residual_K[data.valid], interval, frequency))


def replay_record(search: RecordSearch) -> ReplayedRecord:
    """Step 1: the record replayed with the base model as given, and the noise measured in its residuals.

    Raises :class:`cryod.analysis.usability.UnusableRecordError` for a record the analysis cannot use. The
    replayer takes, from a first replay, the power the cryostat had settled at before the record.
    """
    with search.timed("base replay and noise"):
        check_usable(search.data)
        model, replayer = search.base_model, search.replayer
        orders = (1,) + tuple(harmonic.order for harmonic in model.ptc.harmonics)
        measured_phase = model.effects.ptc_frequency_drift is not None
        base_line = replayer.stage_line(model, orders=orders, measured_phase=measured_phase)
        replayer.settle_from(replayer.replay(model, base_line))
        base_replay = replayer.replay(model, base_line)
        noise = measured_noise(search.data, base_replay, base_line)
        weighted = dataclasses.replace(search, replayer=replayer.weighted(noise), noise_rms_K=noise)
        as_given = weighted.context(model, base_line, base_replay)
    return ReplayedRecord(search=weighted, orders=orders, measured_phase=measured_phase, base_line=base_line,
                          base_replay=base_replay, as_given=as_given)


def recalibrate_base(replayed: ReplayedRecord) -> RecalibratedRecord:
    """Step 2: the base model's own parameters refitted within their tolerances, and the candidates' context.

    Candidates are screened against the base model with the recalibration linearised at the shipped parameters,
    as they are fitted themselves; whether anything needs a cause is judged on the recalibrated model itself.
    """
    search = replayed.search
    with search.timed("recalibration"):
        replayer = search.replayer
        recalibration = recalibrate(replayer, search.base_model, replayed.base_line)
        applied = base_discrepancy(replayed.as_given).present
        context, recalibrated_replay = replayed.as_given, recalibration.replay
        if applied:
            line = replayer.stage_line(recalibration.model, orders=replayed.orders,
                                       measured_phase=replayed.measured_phase)
            centre = dataclasses.replace(recalibration.base, log_factors=np.zeros(len(recalibration.parameters)))
            recalibrated_replay = replayer.replay(recalibration.model, line)
            point = ModelPoint(recalibration=centre, model=search.base_model, line=line, state=recalibration.replay)
            context = search.context_on(point, line_model=recalibration.model)
    return RecalibratedRecord(replayed=replayed, recalibration=recalibration, applied=applied, context=context,
                              recalibrated_replay=recalibrated_replay)


def judging_noise(recalibrated: RecalibratedRecord, fits: dict[str, CandidateFit]) -> tuple[float, float]:
    """The (T2, T5) noise the candidates are judged by: the lowest white floor of the base model's, the
    recalibration's, the candidates' context's and the :data:`~cryod.analysis.cause_search.rules.NOISE_FROM_FITS`
    closest candidates' replays (a large misfit leaks into the base model's noise floor; the best-fitting replays
    give the truer noise)."""
    replayed, context = recalibrated.replayed, recalibrated.context
    closest = sorted(fits.values(), key=lambda fit: context.fit_chi_square(fit.replay))[:NOISE_FROM_FITS]
    replays = [replayed.base_replay, recalibrated.recalibration.replay, context.base_replay] + [
        fit.replay for fit in closest]
    lines = [replayed.base_line, replayed.base_line, context.base_line] + [fit.line for fit in closest]
    data = replayed.search.data
    flange, stage = (min(measured_noise(data, replay, line)[channel] for replay, line in zip(replays, lines))
                     for channel in (0, 1))
    return flange, stage


def rank_candidates(recalibrated: RecalibratedRecord) -> FirstRound:
    """Step 3: every candidate fitted in the candidates' context, the noise measured again, the candidates scored
    on the held-out blocks, held to its own signature (:mod:`cryod.analysis.cause_search.at_signature`) and the
    rules of :mod:`cryod.analysis.decision` applied to them (the first choice; ties between candidates the record
    cannot tell apart go to the one with fewer parameters)."""
    replayed, search = recalibrated.replayed, recalibrated.replayed.search
    causes = search.scope.causes if recalibrated.applied or search.scope.screen_when_fitting else ()
    fits = search.fit_candidates(recalibrated.context, causes)
    noise = judging_noise(recalibrated, fits)
    as_given_context = dataclasses.replace(replayed.as_given, noise_rms_K=noise)
    context = dataclasses.replace(recalibrated.context, noise_rms_K=noise)
    as_given = base_discrepancy(as_given_context)
    first_base = base_discrepancy(context)
    bands = BandLayout.of(search.data, search.held_out_mask, context.base_line, noise)
    scores = scores_at_signature(bands, context.base_replay,
                                 {cause: score_candidate(context, fits[cause], first_base) for cause in fits},
                                 {cause: fit.replay for cause, fit in fits.items()})
    decision = decide(first_base, list(scores.values()),
                      lambda first, second: context.distinctness(fits[first].replay, fits[second].replay),
                      {cause: fit.parameter_count for cause, fit in fits.items()})
    recalibrated_sum = sum(as_given_context.chi_square(recalibrated.recalibration.replay, search.held_out_mask))
    return FirstRound(
        search=dataclasses.replace(search, noise_rms_K=noise), base_line=replayed.base_line,
        base_replay=replayed.base_replay, recalibration=recalibrated.recalibration,
        recalibrated_replay=recalibrated.recalibrated_replay, context=context, as_given=as_given,
        recalibrated=base_discrepancy(dataclasses.replace(context, base_replay=recalibrated.recalibrated_replay)),
        recalibration_gain=gain_between(as_given.sum_of_squares, recalibrated_sum, as_given.terms),
        fits=fits, scores=scores, decision=decision, bands=bands)


__all__ = ["FirstRound", "RecalibratedRecord", "ReplayedRecord", "judging_noise", "measured_noise",
           "rank_candidates", "recalibrate_base", "replay_record"]
