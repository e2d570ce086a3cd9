"""Leave out a cause made unnecessary by a later one.

Once a further cause is named and all are refitted together, each earlier one
is tried without (:func:`tried_without`: the newest cause and the others
refitted with the recalibration on the model without it) and judged as a
further cause on top of the others would be
(:func:`cryod.analysis.cause_search.rules.still_needed`: what it adds in the
joint fit, everywhere and at its own signature); one that is not still needed
is left out (:func:`left_out`), and the path continues on the model without
it. Each earlier cause is taken from the path as it is when its turn comes
(by its name): once one is left out the others carry the numbers the joint fit
without it gave them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from cryod.analysis.cause_search.joint_refit import joint_fit, settled
from cryod.analysis.cause_search.record_search import RecordSearch
from cryod.analysis.cause_search.results import CausePath, JointFit, NamedCause
from cryod.analysis.cause_search.rules import signature_discrepancy, still_needed
from cryod.analysis.cause_signature import BandLayout, band_of, share_at_signature
from cryod.analysis.decision import significance


@dataclass(frozen=True, kw_only=True)
class WithoutCause:
    """The causes of a path refitted without one of them (:func:`tried_without`).

    Attributes
    ----------
    joint : JointFit
        The newest cause refitted with the recalibration and the other causes, on the model without the one left
        out.
    added : float
        How much lower the path's model leaves the held-out sum of squares than the model without the cause.
    significance : float
        ``added`` in standard deviations of the difference between the two predictions.
    without_excess : float
        The excess the model without the cause leaves.
    """

    joint: JointFit
    added: float
    significance: float
    without_excess: float


def without_unneeded(search: RecordSearch, path: CausePath, bands: BandLayout) -> CausePath:
    """``path`` without the earlier causes its newest one made unnecessary (see the module doc), each tried in the
    order they were named, as the path holds it when its turn comes; the path continues on the model without each
    one left out. ``bands``: where each cause's signature is measured."""
    for cause in [named.cause for named in path.causes[:-1]]:
        named = next(item for item in path.causes if item.cause == cause)
        if named.fit.effect is None or len(path.named_effects) < 2:
            continue
        newest = path.causes[-1]
        trial = tried_without(search, path, named, newest)
        if still_needed(trial.added, trial.significance, trial.without_excess, path.remaining.present,
                        signature_share(cause, bands, trial, path)):
            continue
        path = left_out(search, path, named, newest, trial)
    return path


def signature_share(cause: str, bands: BandLayout, trial: WithoutCause, path: CausePath) -> float:
    """``cause``'s share of what the model without it (``trial``) leaves at its own signature, 0 when that is no
    discrepancy (:func:`~cryod.analysis.cause_search.rules.signature_discrepancy`)."""
    without = bands.bands(trial.joint.fit.replay)
    if not signature_discrepancy(without[band_of(cause)]):
        return 0.0
    return share_at_signature(cause, without, bands.bands(path.context.base_replay))


def tried_without(search: RecordSearch, path: CausePath, named: NamedCause, newest: NamedCause) -> WithoutCause:
    """The path's causes but ``named`` refitted with the recalibration (``newest``'s effect carrying the joint
    fit), and what ``named`` adds to them on the held-out blocks."""
    context = path.context
    kept = [item for item in path.named_effects if item.cause != named.cause]
    own = next((item.effect for item in kept if item.cause == newest.cause), newest.fit.effect)
    without = dataclasses.replace(newest.fit, extended_model=context.base_model.with_effects(**{named.cause: None}),
                                  replay=context.base_replay, effect=own)
    others = tuple(item for item in kept if item.cause != newest.cause)
    joint = joint_fit(search, path.recalibration, without, others)
    added = sum(context.chi_square(joint.fit.replay, context.held_out_mask)) - path.remaining.sum_of_squares
    return WithoutCause(joint=joint, added=added,
                        significance=significance(added, context.distinctness(joint.fit.replay, context.base_replay)),
                        without_excess=path.remaining.excess + added)


def left_out(search: RecordSearch, path: CausePath, named: NamedCause, newest: NamedCause,
             trial: WithoutCause) -> CausePath:
    """``path`` without ``named``: ``newest`` and the other causes with the numbers ``trial``'s joint fit gave
    them, the path on the model that fit extends, and the reason."""
    fit = trial.joint.fit
    reason = (f"{named.cause} left out: with {newest.cause} it adds only {trial.added:.4g} "
              f"({trial.significance:.1f} sigma, {100.0 * trial.added / max(trial.without_excess, 1e-300):.1f} % of "
              "what is left without it)")
    others = [item for item in path.causes
              if item.cause not in (named.cause, newest.cause) and item.fit.effect is not None]
    refitted = dict(zip([id(item) for item in others], trial.joint.named_effects))
    causes = []
    for item in path.causes:
        if item.cause == named.cause:
            continue
        if item.cause == newest.cause:
            parameters = fit.parameters if fit.effect is not None else item.fit.parameters
            item = dataclasses.replace(item, fit=dataclasses.replace(
                item.fit, effect=fit.effect, parameters=parameters, extended_model=fit.extended_model,
                replay=fit.replay))
        elif id(item) in refitted:
            item = dataclasses.replace(item, fit=dataclasses.replace(
                item.fit, effect=refitted[id(item)].effect,
                parameters=refitted[id(item)].effect.describe(fit.extended_model)))
        causes.append(item)
    return settled(search, dataclasses.replace(path, causes=tuple(causes), reasons=path.reasons + (reason,)),
                   newest.cause, trial.joint)


__all__ = ["WithoutCause", "left_out", "signature_share", "tried_without", "without_unneeded"]
