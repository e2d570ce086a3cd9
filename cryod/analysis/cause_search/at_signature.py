"""Hold each candidate to its own signature: a fit that removes what it removes outside it does not count.

A candidate is scored on everything it removes from the held-out blocks; a line-path cause whose fit takes most of
that from the slow part of the record stands for a heater-path effect there
(:func:`cryod.analysis.cause_search.rules.shows_at_its_signature`). :func:`judged_at_signature` marks such a
score (:attr:`cryod.analysis.decision.CandidateScore.off_signature`), so that it does not count wherever
candidates are chosen among: the first round, the joint refit of the leading candidates, a further cause on top
of the causes named.
"""

from __future__ import annotations

import dataclasses

from cryod.analysis.cause_search.rules import shows_at_its_signature
from cryod.analysis.cause_signature import BandLayout
from cryod.analysis.decision import CandidateScore
from cryod.analysis.replay import Replay


def judged_at_signature(bands: BandLayout, base_replay: Replay, score: CandidateScore, replay: Replay
                        ) -> CandidateScore:
    """``score`` (of a fit replayed as ``replay``, against the model replayed as ``base_replay``) marked
    ``off_signature`` when its cause does not show at its signature in ``bands``."""
    if not score.counts or shows_at_its_signature(score.cause, bands.bands(base_replay), bands.bands(replay)):
        return score
    return dataclasses.replace(score, off_signature=True)


def scores_at_signature(bands: BandLayout, base_replay: Replay, scores: dict[str, CandidateScore],
                        replays: dict[str, Replay]) -> dict[str, CandidateScore]:
    """Each of ``scores`` judged at its signature (:func:`judged_at_signature`), its fit replayed as in
    ``replays``."""
    return {cause: judged_at_signature(bands, base_replay, score, replays[cause]) for cause, score in scores.items()}


__all__ = ["judged_at_signature", "scores_at_signature"]
