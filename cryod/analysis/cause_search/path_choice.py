"""Follow paths from the leading candidates, and read the causes named the other way round.

:func:`follow_paths` refits the first round's leading candidates jointly with
the recalibration, follows the path of causes from the best, and, when that
path leaves a discrepancy, the paths from the other leading candidates
(:func:`cryod.analysis.cause_search.rules.alternatives_followed`); a path of
several causes that leaves much less is kept instead
(:func:`cryod.analysis.cause_search.rules.kept_instead`).

:func:`read_the_other_way_round` follows the other reading of the causes kept
(:func:`cryod.analysis.equivalence.other_way_round`) as a path of its own; it
is named instead when it does better by what a cause must add
(:func:`cryod.analysis.cause_search.rules.other_reading_named_instead`), and
is otherwise the causes' equivalent reading
(:func:`cryod.analysis.equivalence.path_reading`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from cryod.analysis.cause_search.first_round import FirstRound
from cryod.analysis.cause_search.joint_refit import JointChoice, joint_fit, refit_jointly, starting_path
from cryod.analysis.cause_search.path import follow_path
from cryod.analysis.cause_search.results import CausePath, JointFit
from cryod.analysis.cause_search.rules import alternatives_followed, kept_instead, other_reading_named_instead
from cryod.analysis.decision import CandidateScore, score_candidate, significance
from cryod.analysis.equivalence import other_way_round, path_reading


@dataclass(frozen=True, kw_only=True)
class PathsFollowed:
    """The path of causes kept (:func:`follow_paths`).

    Attributes
    ----------
    path : CausePath
    first_choices : dict of str to JointFit
        The first round's leading candidates refitted jointly with the recalibration.
    """

    path: CausePath
    first_choices: dict[str, JointFit]


@dataclass(frozen=True, kw_only=True)
class ReadPath:
    """The path of causes named after the other reading was weighed (:func:`read_the_other_way_round`).

    Attributes
    ----------
    path : CausePath
    other_paths : tuple of dict
        The other reading, when the record cannot tell it from the causes named
        (:func:`cryod.analysis.equivalence.path_reading`).
    """

    path: CausePath
    other_paths: tuple[dict, ...] = ()


def follow_paths(first: FirstRound, most: int) -> PathsFollowed | None:
    """Step 4: the first round's leading candidates refitted jointly, the path of causes from the best of them,
    and (``most`` above 1, a discrepancy left) the paths from the others; the path kept. None when no candidate
    counts once refitted."""
    best = first.decision.best
    if best is None or best.cause not in first.fits:
        return None
    choice = refit_jointly(first.search, starting_path(first), first.fits, first.scores, first.bands)
    if choice.decision.best is None:
        return None
    path = first_path = follow_path(first, choice.decision.best, choice.refined, most)
    if most > 1:
        for alternative in alternatives_followed(_other_first_choices(first, choice), first_path.remaining,
                                                 first.recalibrated):
            other = follow_path(first, alternative, choice.refined, most)
            if kept_instead(other, first_path, path):
                path = other
    return PathsFollowed(path=path, first_choices=choice.refined)


def _other_first_choices(first: FirstRound, choice: JointChoice) -> list[CandidateScore]:
    """The leading candidates but the one chosen, refitted jointly, that count against the recalibrated model,
    the largest improvement first."""
    chosen = choice.decision.best
    assert chosen is not None               # a choice that names one (follow_paths)
    scores = sorted((score_candidate(first.context, joint.fit, first.recalibrated)
                     for cause, joint in choice.refined.items() if cause != chosen.cause),
                    key=lambda score: -score.improvement)
    return [score for score in scores if score.counts]


@dataclass(frozen=True, kw_only=True)
class OtherReading:
    """The other way round of a path's causes, followed as a path of its own (:func:`other_reading`).

    Attributes
    ----------
    path : CausePath
    better : float
        How much lower it leaves the held-out sum of squares than the causes named.
    significance : float
        ``better`` in standard deviations of the difference between the two predictions.
    """

    path: CausePath
    better: float
    significance: float


def other_reading(first: FirstRound, followed: PathsFollowed) -> OtherReading | None:
    """The causes of the path kept, leaving no discrepancy, read the other way round
    (:func:`cryod.analysis.equivalence.other_way_round`: a flange thermometer's lag alone as a dead time with a
    link; a link with a dead time as the lag with a dead time) and followed as any path is, its first cause
    first. None when no such reading applies, its first cause does not count, or it does not name its causes
    or leaves a discrepancy.

    The lag delays T2 on every path: on the heater's like a dead time (as far as the heater's content is slow
    against the lag), on the line's like a link that lags. The reading's first cause reuses its joint fit of the
    first round when it was a leading candidate.
    """
    path = followed.path
    causes = other_way_round(path.causes)
    if causes is None or path.remaining.present or causes[0] not in first.fits:
        return None
    cause, context = causes[0], first.context
    joint = followed.first_choices.get(cause) or joint_fit(first.search, context.recalibration, first.fits[cause], ())
    score = score_candidate(context, joint.fit, first.recalibrated)
    if not score.counts:
        return None
    other = follow_path(first, score, {cause: joint}, len(causes), causes=causes)
    if other.cause_names() != causes or other.remaining.present:
        return None
    better = path.remaining.sum_of_squares - other.remaining.sum_of_squares
    return OtherReading(path=other, better=better, significance=significance(
        better, context.distinctness(path.context.base_replay, other.context.base_replay)))


def read_the_other_way_round(first: FirstRound, followed: PathsFollowed) -> ReadPath:
    """Step 5: the other reading of the causes kept (:func:`other_reading`) named instead when it does better by
    what a cause must add, otherwise kept beside them as their equivalent reading."""
    reading = other_reading(first, followed)
    path = followed.path
    if reading is None:
        return ReadPath(path=path)
    if not other_reading_named_instead(reading.better, reading.significance):
        return ReadPath(path=path, other_paths=(path_reading(reading.path.causes, reading.better,
                                                             reading.significance),))
    return ReadPath(path=dataclasses.replace(reading.path, reasons=reading.path.reasons + (
        f"these leave {reading.better:.4g} less than {' + '.join(path.cause_names())} "
        f"({reading.significance:.1f} sigma), which they stand for",)))


__all__ = ["OtherReading", "PathsFollowed", "ReadPath", "follow_paths", "other_reading",
           "read_the_other_way_round"]
