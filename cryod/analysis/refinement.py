"""A cause refitted together with the recalibration: Gauss-Newton on both at once.

A candidate is found (:mod:`cryod.analysis.candidates`) with the recalibration
linearised about the recalibrated model: good enough to rank the causes, not to
give their parameters to a percent when the cause moves the recalibration far
(a 1.5 s dead time is, at low frequency, close to 1.5 s more of G2's 26 s time
constant, which the recalibration took first). Refining a cause refits the
structure's log factors and the effect's own numbers together, nonlinearly:
at each step the change of T2 and T5 per unit of each (forward differences of
the simulator with the cause in the model) is one
:class:`~cryod.analysis.replay.LinearBasis`, solved with the nuisance
parameters; the numbers move by the result and the columns are taken again,
until nothing moves by more than a thousandth of its step.

The recalibration keeps its tolerances and penalty; the effect's numbers are
held within the effect's own range and have no penalty.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from cryod.analysis.candidates import CandidateFit, EffectForm
from cryod.analysis.recalibration import RecalibratedBase, linear_basis
from cryod.analysis.replay import LinearBasis, Replay, Replayer, flange_mode_columns, stage_release_response
from cryod.cooler.line import PtcLine
from cryod.model import CryostatModel

#: Gauss-Newton steps at most, and the relative change (of each number's step) that counts as converged.
MOST_STEPS = 4
CONVERGED_FRACTION = 1e-3
#: Width of the effect's numbers in the penalty: none, in practice.
NO_PENALTY = 1e30


def _state_added(replayer: Replayer, aligned: CryostatModel, flange, stage, state: Replay | None):
    if state is None:
        return flange, stage
    data = replayer.data
    modes = flange_mode_columns(aligned, data.elapsed_s, data.sample_interval_s)
    if modes.shape[1] == state.initial_mode_amplitudes_K.size:
        flange = flange + modes @ state.initial_mode_amplitudes_K
    return flange, stage + stage_release_response(aligned, data.elapsed_s) * state.initial_power_offset_w


def joint_basis(replayer: Replayer, base: RecalibratedBase, line: PtcLine, effect: EffectForm,
                state: Replay | None, excluded=()) -> LinearBasis | None:
    """The recalibration's columns and the effect's, at ``base``'s log factors and ``effect``'s values (None when
    ``excluded`` leaves none)."""
    values = np.asarray(effect.values, dtype=float)

    def apply(model):
        return effect.apply(model, tuple(values))

    recalibration = linear_basis(replayer, base, line, state, apply)
    model = apply(base.model())
    cycle = line.cycle if line is not None else None
    aligned = line.applied_to(model) if line is not None else model
    simulated = replayer.simulate(aligned, cycle=cycle)
    flange, stage = _state_added(replayer, aligned, simulated.flange_K, simulated.ptc_stage_K, state)
    flange_columns, stage_columns = [], []
    for index, step in enumerate(effect.steps):
        moved = values.copy()
        moved[index] += step
        changed = effect.apply(base.model(), tuple(moved))
        aligned = line.applied_to(changed) if line is not None else changed
        result = replayer.simulate(aligned, cycle=cycle)
        moved_flange, moved_stage = _state_added(replayer, aligned, result.flange_K, result.ptc_stage_K, state)
        flange_columns.append((moved_flange - flange) / step)
        stage_columns.append((moved_stage - stage) / step)
    names = tuple(f"effect {index}" for index in range(len(effect.steps)))
    joint = LinearBasis(
        recalibration.names + names,
        np.column_stack([recalibration.flange_columns] + flange_columns),
        np.column_stack([recalibration.stage_columns] + stage_columns),
        np.concatenate([recalibration.values, values]),
        np.concatenate([recalibration.lower, effect.lower]),
        np.concatenate([recalibration.upper, effect.upper]),
        np.concatenate([recalibration.widths, np.full(len(names), NO_PENALTY)]))
    return joint.without(excluded) if excluded else joint


@dataclass(frozen=True)
class NamedEffect:
    """A cause already named, as the refinement refits it: its effect form and the recalibration it replaces."""

    cause: str
    effect: EffectForm
    excluded: tuple = ()


def combined_effect(effects) -> EffectForm | None:
    """Several effect forms as one (their values one after the other); None if there are none."""
    effects = [effect for effect in effects if effect is not None]
    if not effects:
        return None
    sizes = [len(effect.values) for effect in effects]
    bounds = np.cumsum([0] + sizes)

    def apply(model, values):
        for effect, start, stop in zip(effects, bounds[:-1], bounds[1:]):
            model = effect.apply(model, tuple(values[start:stop]))
        return model

    def describe(model) -> dict:
        raise TypeError("a combined effect is described by its parts (each form of _split)")

    return EffectForm(tuple(v for effect in effects for v in effect.values),
                      tuple(v for effect in effects for v in effect.lower),
                      tuple(v for effect in effects for v in effect.upper),
                      tuple(v for effect in effects for v in effect.steps), apply, describe)


def _split(effects, values):
    """The values of a combined form back into each form."""
    found, start = [], 0
    for effect in effects:
        stop = start + len(effect.values)
        found.append(dataclasses.replace(effect, values=tuple(float(v) for v in values[start:stop])))
        start = stop
    return found


def refine(replayer: Replayer, base: RecalibratedBase, fit: CandidateFit, others=()
           ) -> tuple[CandidateFit, RecalibratedBase, list]:
    """Refit ``fit``'s effect and the recalibration together (and the causes named before it).

    Parameters
    ----------
    replayer : Replayer
    base : RecalibratedBase
        The recalibration the candidate was fitted on (its log factors are the start).
    fit : CandidateFit
        A candidate; its model's other effects and PTC source (the causes named
        before it, harmonics) are kept as they are, except ``others``. Without an
        :attr:`~cryod.analysis.candidates.CandidateFit.effect` (a measured line),
        only the recalibration (and ``others``) is refitted.
    others : sequence of NamedEffect
        Causes named before, refitted alongside: a cause that took part of what
        this one explains gives it back.

    Returns
    -------
    fit : CandidateFit
        The refined candidate.
    base : RecalibratedBase
        The recalibration refitted with it.
    others : list of NamedEffect
        ``others`` with their refitted values.
    """
    others = list(others)
    excluded = tuple(sorted(set(fit.excluded).union(*[set(other.excluded) for other in others])))
    names = [parameter.name for parameter in base.parameters]
    kept = [index for index, name in enumerate(names) if name not in excluded]
    x = base.log_factors.copy()
    for index in range(len(names)):
        if names[index] in excluded:
            x[index] = 0.0
    if fit.replay.basis is not None:
        for name, change in zip(fit.replay.basis.names, fit.replay.basis_change):
            if name in names and name not in excluded:
                x[names.index(name)] += change
    tolerances = np.array([parameter.tolerance for parameter in base.parameters])
    x = np.clip(x, -tolerances, tolerances)
    source = fit.extended_model
    own_link = fit.effect is None and "line gain on T2" in excluded

    def carried(model):
        model = dataclasses.replace(model, effects=source.effects, ptc=source.ptc,
                                    operating_point=source.operating_point)
        return dataclasses.replace(model, ptc_to_flange=source.ptc_to_flange) if own_link else model

    own = fit.effect or EffectForm((), (), (), (), lambda model, values: model, lambda model: fit.parameters)
    forms = [other.effect for other in others] + [own]
    effect = combined_effect(forms)
    assert effect is not None               # own is among the forms
    wrapped = dataclasses.replace(effect, apply=lambda model, v: effect.apply(carried(model), v))
    values = np.asarray(effect.values, dtype=float)
    lower, upper = np.asarray(effect.lower, dtype=float), np.asarray(effect.upper, dtype=float)
    steps = np.asarray(effect.steps, dtype=float)
    line = fit.line
    state = fit.replay
    for _ in range(MOST_STEPS):
        current = dataclasses.replace(base, log_factors=x)
        basis = joint_basis(replayer, current, line, dataclasses.replace(wrapped, values=tuple(values)), state,
                            excluded)
        model = wrapped.apply(current.model(), tuple(values))
        replay = replayer.replay(model, line, basis=basis)
        change = replay.basis_change
        x[kept] = np.clip(x[kept] + change[:len(kept)], -tolerances[kept], tolerances[kept])
        values = np.clip(values + change[len(kept):], lower, upper)
        state = replayer.replay(wrapped.apply(dataclasses.replace(base, log_factors=x).model(), tuple(values)), line,
                                basis=None)
        if np.all(np.abs(change[len(kept):]) <= 10.0 * CONVERGED_FRACTION * steps) \
                and np.all(np.abs(change[:len(kept)]) <= 1e-4):
            break
    refined_base = dataclasses.replace(base, log_factors=x)
    model = wrapped.apply(refined_base.model(), tuple(values))
    basis = linear_basis(replayer, refined_base, line, state, lambda m: wrapped.apply(m, tuple(values)))
    basis = basis.without(excluded) if excluded else basis
    replay = replayer.replay(model, line, basis=basis)
    split = _split(forms, values)
    refined = dataclasses.replace(fit, parameters=split[-1].describe(model) if fit.effect else fit.parameters,
                                  extended_model=model, replay=replay, effect=split[-1] if fit.effect else None)
    return refined, refined_base, [dataclasses.replace(other, effect=form) for other, form in zip(others, split)]


__all__ = ["NamedEffect", "combined_effect", "joint_basis", "refine"]
