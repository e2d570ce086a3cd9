"""One analysis of one record: replay, noise, candidates, decision.

:func:`analyze` is what ``cryod analyze`` runs; the figures, the report and the
JSON are made from the :class:`Analysis` it returns.

Steps:

1. Split the record into fit and held-out blocks (:mod:`cryod.analysis.record_data`).
2. Measure the PTC line in T5 in the form the model has (its harmonic orders,
   its drift or none), replay the record with the base model, estimate the
   operating point and the initial state (:mod:`cryod.analysis.replay`).
3. Measure the noise of T2 and T5 in the base model's residuals
   (:mod:`cryod.analysis.noise`); it weights the two thermometers in the fits.
4. Fit every candidate cause (:mod:`cryod.analysis.candidates`). The noise
   used for judging is the lowest white floor of any replay's residuals (a
   large misfit leaks a little into the base model's floor).
5. Judge the candidates on the held-out blocks (:mod:`cryod.analysis.decision`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from cryod.analysis.candidates import CANDIDATE_CAUSES, FITTERS, CandidateFit, FitContext
from cryod.analysis.decision import CandidateScore, Decision, base_discrepancy, decide, score_candidate
from cryod.analysis.noise import white_noise_rms
from cryod.analysis.ptc_line import PtcLine
from cryod.analysis.record_data import RecordData, fit_block_mask
from cryod.analysis.replay import Replay, Replayer
from cryod.model import CryostatModel


@dataclass
class Analysis:
    """Everything one analysis found.

    Attributes
    ----------
    data : RecordData
    base_model : CryostatModel
    base_line : PtcLine
        The line measured in T5, in the base model's form.
    base_replay : Replay
    noise_rms_K : tuple of float
        Measured (T2, T5) noise.
    fits : dict of str to CandidateFit
    scores : dict of str to CandidateScore
    decision : Decision
    context : FitContext
    timings_s : dict of str to float
        Wall time of each step.
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

    @property
    def cause(self) -> str:
        return self.decision.cause

    @property
    def extended_model(self) -> CryostatModel:
        """The base model plus the named effect (the base model itself for none or unexplained)."""
        if self.cause in self.fits:
            return self.fits[self.cause].extended_model
        return self.base_model

    @property
    def extended_replay(self) -> Replay:
        if self.cause in self.fits:
            return self.fits[self.cause].replay
        return self.base_replay


def measured_noise(data: RecordData, replay: Replay, line: PtcLine) -> tuple[float, float]:
    """(T2, T5) white noise rms in a replay's residuals."""
    interval, frequency = data.sample_interval_s, line.angular_frequency_rad_s
    return (white_noise_rms(replay.flange_residual_K[data.valid], interval, frequency),
            white_noise_rms(replay.ptc_stage_residual_K[data.valid], interval, frequency))


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
    """
    timings = {}
    started = time.perf_counter()
    fit_mask = fit_block_mask(data.time_s) & data.valid
    held_out_mask = ~fit_block_mask(data.time_s) & data.valid
    replayer = Replayer(data, fit_mask)
    orders = (1,) + tuple(h.order for h in base_model.ptc.harmonics)
    base_line = replayer.stage_line(base_model, orders=orders, drift=base_model.effects.ptc_frequency_drift is not None)
    replayer.settle_from(replayer.replay(base_model, base_line))
    base_replay = replayer.replay(base_model, base_line)
    noise = measured_noise(data, base_replay, base_line)
    replayer.noise_rms_K = noise
    timings["base replay and noise"] = time.perf_counter() - started
    context = FitContext(data, replayer, base_model, base_line, base_replay, noise, fit_mask, held_out_mask)
    fits, scores = {}, {}
    for cause in causes:
        started = time.perf_counter()
        fits[cause] = FITTERS[cause](context)
        timings[cause] = time.perf_counter() - started
    # A large misfit leaks into the base model's noise floor; the best-fitting replay gives the truer noise.
    context.noise_rms_K = noise = tuple(
        min([noise[channel]] + [measured_noise(data, fit.replay, fit.line)[channel] for fit in fits.values()])
        for channel in (0, 1))
    base = base_discrepancy(context)
    for cause in causes:
        scores[cause] = score_candidate(context, fits[cause], base)
    mask = held_out_mask

    def distinctness(first: str, second: str) -> float:
        a, b = fits[first].replay, fits[second].replay
        flange = (a.flange_K - b.flange_K)[mask] / noise[0]
        stage = (a.ptc_stage_K - b.ptc_stage_K)[mask] / noise[1]
        return float(flange @ flange + stage @ stage)

    decision = decide(base, list(scores.values()), distinctness,
                      {cause: fit.parameter_count for cause, fit in fits.items()})
    return Analysis(data, base_model, base_line, base_replay, noise, fits, scores, decision, context, timings)


__all__ = ["Analysis", "analyze"]
