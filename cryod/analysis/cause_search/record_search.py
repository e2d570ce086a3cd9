"""What every step of one record's cause search shares: the record, its samples, the replayer, the noise.

:class:`RecordSearch` holds the record and its fit and held-out samples, the
replayer and the noise that weight every fit, the causes tried
(:class:`SearchScope`) and the log of the time each step took; it makes the
contexts candidates are fitted in (:meth:`RecordSearch.context_on`, at a
:class:`ModelPoint`) and fits candidates there. A step that measures the
noise again makes a new one (:func:`dataclasses.replace`); the timing log is
shared by all of them, in the order the steps ran.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from cryod.analysis.candidates import CANDIDATE_CAUSES, CandidateFit, FitContext
from cryod.analysis.cause_search.rules import MOST_CAUSES
from cryod.analysis.fitters import FITTERS
from cryod.analysis.recalibration import LINK_PARAMETERS, RecalibratedBase, linear_basis
from cryod.analysis.record_data import RecordData, fit_block_mask
from cryod.analysis.refinement import NamedEffect, combined_effect, joint_basis
from cryod.analysis.replay import Replay, Replayer
from cryod.cooler.line import PtcLine
from cryod.model import CryostatModel


@contextmanager
def timed(timings_s: dict[str, float], step: str) -> Iterator[None]:
    """Add the wall time of the ``with`` block to ``step``'s in the timing log ``timings_s``."""
    started = time.perf_counter()
    yield
    timings_s[step] = timings_s.get(step, 0.0) + time.perf_counter() - started


@dataclass(frozen=True, kw_only=True)
class SearchScope:
    """Which causes a search tries and how far it goes.

    Attributes
    ----------
    causes : tuple of str
        Candidate causes to try.
    screen_when_fitting : bool
        Fit the candidates (for the report's table) even when the base model as given shows no discrepancy.
    widen : bool
        When the recalibration leaves a parameter at its tolerance, recalibrate with the wider tolerances of
        :mod:`cryod.analysis.cause_search.base_model_off`; if that alone explains the record, only the first cause
        is looked for within the tolerance (what a catalogue cause alone would say), not a path of several.
    most_causes : int
        Causes named at most (with 1, no second path is followed either).
    """

    causes: tuple[str, ...] = tuple(CANDIDATE_CAUSES)
    screen_when_fitting: bool = True
    widen: bool = True
    most_causes: int = MOST_CAUSES


@dataclass(frozen=True, kw_only=True)
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
    named: tuple[NamedEffect, ...] = ()
    carries_effects: bool = False

    def carried(self):
        """``model -> model`` with this point's effects, PTC source and operating point (None: nothing carried)."""
        if not self.carries_effects:
            return None
        reference = self.model
        return lambda model: dataclasses.replace(model, effects=reference.effects, ptc=reference.ptc,
                                                 operating_point=reference.operating_point)


@dataclass(frozen=True, kw_only=True)
class RecordSearch:
    """One record's cause search: what its steps share (see the module doc).

    Attributes
    ----------
    data : RecordData
    base_model : CryostatModel
        The model as given.
    scope : SearchScope
    fit_mask, held_out_mask : numpy.ndarray of bool
        The valid samples of the fit and of the held-out blocks.
    replayer : Replayer
        Weighted by the noise once it is measured.
    noise_rms_K : tuple of float
        (T2, T5) noise that weights the fits and the judgements.
    timings_s : dict of str to float
        Wall time of each step, in the order they ran.
    """

    data: RecordData
    base_model: CryostatModel
    scope: SearchScope
    fit_mask: np.ndarray
    held_out_mask: np.ndarray
    replayer: Replayer
    noise_rms_K: tuple[float, float]
    timings_s: dict[str, float]

    @classmethod
    def on(cls, data: RecordData, base_model: CryostatModel, scope: SearchScope = SearchScope(),
           cycle_from: Replayer | None = None) -> "RecordSearch":
        """The search of ``data`` against ``base_model``; ``cycle_from``: a replayer of the same record whose
        cooler's phase, measured sample by sample in T5, is reused (the phase hardly depends on the model's heater
        part taken out of T5)."""
        fit_mask = fit_block_mask(data.time_s) & data.valid
        replayer = Replayer(data, fit_mask)
        if cycle_from is not None:
            replayer.share_measured_cycle(cycle_from)
        return cls(data=data, base_model=base_model, scope=scope, fit_mask=fit_mask,
                   held_out_mask=~fit_block_mask(data.time_s) & data.valid, replayer=replayer,
                   noise_rms_K=replayer.noise_rms_K, timings_s={})

    def timed(self, step: str):
        """Add the wall time of the ``with`` block to ``step``'s in the search's timing log."""
        return timed(self.timings_s, step)

    def context(self, model: CryostatModel, line: PtcLine, replay: Replay) -> FitContext:
        """A context on ``model`` replayed as ``replay``, without a linearised recalibration."""
        return FitContext(self.data, self.replayer, model, line, replay, self.noise_rms_K, self.fit_mask,
                          self.held_out_mask)

    def context_on(self, point: ModelPoint, line_model: CryostatModel | None = None) -> FitContext:
        """Candidates' context on ``point``: its recalibration (and its named causes' own numbers) linearised there
        and fitted in every replay; candidates are judged against the point's model replayed so.
        ``line_model``: the model whose heater part of T5 is taken out before the line is measured in it."""
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

        # the point's model replayed as the context replays (FitContext.replay), its basis fitted alongside
        base_replay = replayer.replay(point.model, point.line, basis=basis_for(point.line))
        return FitContext(self.data, replayer, point.model, point.line, base_replay, self.noise_rms_K, self.fit_mask,
                          self.held_out_mask, link_reference=base.model(without=LINK_PARAMETERS).ptc_to_flange,
                          recalibrated=base, line_model=line_model, basis_for=basis_for)

    def fit_candidates(self, context: FitContext, causes, label: str = "") -> dict[str, CandidateFit]:
        """Each cause fitted in ``context``, timed under ``cause + label``."""
        fits = {}
        for cause in causes:
            with self.timed(cause + label):
                fits[cause] = FITTERS[cause](context)
        return fits


__all__ = ["ModelPoint", "RecordSearch", "SearchScope", "timed"]
