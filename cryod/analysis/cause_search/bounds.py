"""A named cause's parameter at an edge of its range is evidence: re-examine it, and say so if it stays.

Each cause's numbers are fitted within a range (:class:`cryod.analysis.candidates.EffectForm`: a thermometer's
lag up to 30 s, a dead time up to a tenth of the record, a heat capacity's exponent within +-6, a heater
nonlinearity within -1..10 /W: the model file's ranges). A fit that ends on an edge did not find the record's
value: the cause is not of the record's form, or it takes up another cause's part. So
(:func:`examine_bounds`: when a path names its first cause, before a partner can take up what the edge leaves,
and again on the causes named in the end), for each cause of the path whose number sits at an edge (within its
step, :func:`at_edge`):

1. the edge is widened where physics and the model file allow (:data:`WIDER`: a thermometer's lag or a link's
   time constant to 120 s, a dead time to a third of the record and at most 600 s; a heat capacity's exponent and
   a heater nonlinearity's coefficient are held at the model file's range, which is already beyond copper's
   law and a heater's);
2. a widened number is searched again over its new range, the others held (:func:`scanned`: a grid then Brent,
   as the candidate was first fitted; a Gauss-Newton step from the edge stays in the nearest ripple of the cost:
   a 45 s dead time fitted at a 40 s edge did not move), then every cause of the path is refitted jointly with
   the recalibration on the widened ranges (:func:`cryod.analysis.cause_search.joint_refit.joint_fit`), and the
   path continues on that fit when it leaves the held-out sum of squares lower;
3. a number still at an edge is reported (:class:`~cryod.analysis.cause_search.results.BoundEvidence`): in the
   report's first line and in the JSON's ``at_bound``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from cryod.analysis.candidates import EffectForm, scalar_search
from cryod.analysis.cause_search.first_round import FirstRound
from cryod.analysis.cause_search.joint_refit import joint_fit, refitted_causes, settled
from cryod.analysis.cause_search.results import BoundEvidence, CausePath, NamedCause
from cryod.analysis.decision import base_discrepancy

#: Per cause, per number of its effect form: the widest upper edge physics and the model file allow, as a
#: function of the record's duration (s); None: not widened. Lower edges at zero (no effect) are not evidence.
WIDER = {
    "sensor_lag": (lambda duration: 120.0, lambda duration: 120.0),
    "link_dynamics": (lambda duration: 120.0, None),
    "dead_time": (lambda duration: min(600.0, duration / 3.0),),
}
#: Edges that are the effect vanishing, not a range: a lag, a delay or a link's time constant at zero.
ZERO_EDGES = {"sensor_lag": (0, 1), "link_dynamics": (0,), "dead_time": (0,)}


def parameter_names(named: NamedCause) -> list[str]:
    """The names of ``named``'s effect's numbers, in their order (its parameters' first names)."""
    names = [name for name, value in named.fit.parameters.items() if isinstance(value, (int, float))]
    return names[:len(named.fit.effect.values)]


def at_edge(cause: str, effect: EffectForm) -> list[tuple[int, float]]:
    """(index, edge) of each number of ``effect`` at an edge of its range (within its forward-difference step);
    a lower edge that is the effect vanishing (:data:`ZERO_EDGES`) is left out."""
    found = []
    for index, (value, lower, upper, step) in enumerate(zip(effect.values, effect.lower, effect.upper, effect.steps)):
        if value >= upper - step:
            found.append((index, float(upper)))
        elif value <= lower + step and index not in ZERO_EDGES.get(cause, ()):
            found.append((index, float(lower)))
    return found


def widened(cause: str, effect: EffectForm, edges: list[tuple[int, float]], duration_s: float) -> EffectForm:
    """``effect`` with each upper edge in ``edges`` widened as :data:`WIDER` allows."""
    upper = list(effect.upper)
    rules = WIDER.get(cause, ())
    for index, edge in edges:
        rule = rules[index] if index < len(rules) else None
        if rule is not None and edge == upper[index]:
            upper[index] = max(upper[index], rule(duration_s))
    return dataclasses.replace(effect, upper=tuple(upper))


def examine_bounds(first: FirstRound, path: CausePath) -> tuple[CausePath, tuple[BoundEvidence, ...]]:
    """``path`` refitted on widened ranges where a cause's number sat at an edge (see the module doc), and what
    stays at an edge."""
    edges = {named.cause: at_edge(named.cause, named.fit.effect) for named in path.causes
             if named.fit.effect is not None}
    if not any(edges.values()):
        return path, ()
    duration = first.search.data.duration_s
    forms = {}
    for named in path.causes:
        if named.fit.effect is not None:
            form = widened(named.cause, named.fit.effect, edges.get(named.cause, []), duration)
            moved = [index for index, (old, new) in enumerate(zip(named.fit.effect.upper, form.upper)) if new > old]
            forms[named.cause] = scanned(path, form, moved)
    refitted = _refitted(first, path, forms)
    better = refitted is not None and refitted.remaining.sum_of_squares < path.remaining.sum_of_squares
    if better:
        path = refitted
    evidence = []
    for named in path.causes:
        for index, edge in edges.get(named.cause, []):
            evidence.append(_evidence(named, index, edge, forms[named.cause], better))
    return path, tuple(evidence)


def scanned(path: CausePath, form: EffectForm, indexes: list[int]) -> EffectForm:
    """``form`` (a cause's on ``path``) with each number of ``indexes`` (those whose upper edge was widened)
    searched again between its old value and the new edge on the fit blocks, the other numbers and causes held (a
    log grid of 12 points then bounded Brent)."""
    context = path.context
    values = list(form.values)
    for index in indexes:
        value, upper = form.values[index], form.upper[index]

        def cost(trial, index=index):
            moved = list(values)
            moved[index] = float(trial)
            return context.fit_chi_square(context.replay(form.apply(context.base_model, tuple(moved)),
                                                         context.base_line))

        grid = np.geomspace(max(value, form.steps[index]), upper, 12)
        values[index] = scalar_search(cost, grid, (float(grid[0]), float(upper)), form.steps[index])
    return dataclasses.replace(form, values=tuple(values))


def _evidence(named: NamedCause, index: int, edge: float, form: EffectForm, refitted: bool) -> BoundEvidence:
    """What became of ``named``'s number ``index``, found at ``edge``: widened to ``form``'s range and
    ``refitted`` (the joint fit on the widened ranges did better), or left as it was."""
    names = parameter_names(named)
    name = names[index] if index < len(names) else f"number {index}"
    value = float(named.fit.effect.values[index])
    if not refitted:
        return BoundEvidence(cause=named.cause, parameter=name, value=value, bound=edge, widened_from=None, stays=True)
    wider = float(form.upper[index])
    was_widened = edge != form.lower[index] and wider > edge
    return BoundEvidence(cause=named.cause, parameter=name, value=value, bound=wider if was_widened else edge,
                         widened_from=edge if was_widened else None,
                         stays=index in dict(at_edge(named.cause, named.fit.effect)))


def _refitted(first: FirstRound, path: CausePath, forms: dict[str, EffectForm]) -> CausePath | None:
    """Every cause of ``path`` refitted jointly with the recalibration, each on its form in ``forms`` (None when
    the last cause has no effect form)."""
    newest = path.causes[-1]
    if newest.fit.effect is None:
        return None
    others = tuple(dataclasses.replace(item, effect=dataclasses.replace(item.effect, upper=forms[item.cause].upper,
                                                                        values=forms[item.cause].values))
                   for item in path.named_effects if item.cause != newest.cause)
    fit = dataclasses.replace(newest.fit, effect=forms[newest.cause])
    joint = joint_fit(first.search, path.recalibration, fit, others)
    causes = refitted_causes(path.causes[:-1], joint.named_effects, joint.fit.extended_model)
    newest = dataclasses.replace(newest, fit=joint.fit)
    kept = dataclasses.replace(path, causes=causes + (newest,),
                               named_effects=tuple(item for item in path.named_effects if item.cause != newest.cause))
    refitted = settled(first.search, kept, newest.cause, joint)
    return dataclasses.replace(refitted, remaining=base_discrepancy(refitted.context))


def merged_evidence(earlier: tuple[BoundEvidence, ...], final: tuple[BoundEvidence, ...]
                    ) -> tuple[BoundEvidence, ...]:
    """The evidence of the first cause's examination (``earlier``) and of the final one, one item per cause and
    number: the final one's where both have it; of the earlier, only a number that left its edge once widened (one
    still at its edge then is judged again on the causes named in the end, where a partner may have freed it)."""
    seen = {(item.cause, item.parameter) for item in final}
    return tuple(item for item in earlier
                 if (item.cause, item.parameter) not in seen and not item.stays) + tuple(final)


def stays_text(evidence: tuple[BoundEvidence, ...]) -> str:
    """The first line's words on the numbers that stay at an edge ('' when none does)."""
    staying = [item for item in evidence if item.stays]
    if not staying:
        return ""
    return "; at the edge of its range: " + ", ".join(
        f"{item.cause}'s {item.parameter} {item.value:.4g} (edge {item.bound:.4g})" for item in staying)


__all__ = ["WIDER", "ZERO_EDGES", "at_edge", "examine_bounds", "merged_evidence", "parameter_names", "scanned",
           "stays_text", "widened"]
