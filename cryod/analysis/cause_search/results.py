"""What the cause search's steps hand on: each a frozen dataclass, built by keyword.

* :class:`NamedCause`: a cause added to the model, with what it brought.
* :class:`JointFit`: a candidate refitted jointly with the recalibration and the causes named before it.
* :class:`ReplayedModel`: a model, its replay of the record and what it leaves on the held-out blocks.
* :class:`FurtherCandidate`: a candidate judged on top of the causes named, on its own signature and jointly.
* :class:`BoundEvidence`: a named cause's parameter at an edge of its range, re-examined.
* :class:`CausePath`: causes named one after another from a first choice, and where they leave the model.
* :class:`Verdict`: what the search concludes (the decision, the causes, the extended model).
* :class:`Analysis`: everything one analysis found, what the report, the figures and the JSON are made of.

Two of the analysis's parts are made by later steps, and declared here by what the report and the JSON read of
them: :class:`BeyondTolerance` (:class:`~cryod.analysis.cause_search.base_model_off.BeyondRecalibration`) and
:class:`WhatIsLeft` (:class:`~cryod.analysis.cause_search.what_is_left.Attribution`).

A step that changes one of these makes a new one (:func:`dataclasses.replace`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

from cryod.analysis.candidates import CandidateFit, FitContext
from cryod.analysis.cause_signature import BandExcess
from cryod.analysis.decision import BaseDiscrepancy, CandidateScore, Decision, Gain
from cryod.analysis.generic_extension import GenericExtension
from cryod.analysis.recalibration import RecalibratedBase, RecalibratedParameter, Recalibration
from cryod.analysis.record_data import RecordData
from cryod.analysis.refinement import NamedEffect
from cryod.analysis.replay import Replay
from cryod.analysis.residual_signature import ResidualSignature
from cryod.cooler.line import PtcLine
from cryod.model import CryostatModel


@dataclass(frozen=True, kw_only=True)
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


@dataclass(frozen=True, kw_only=True)
class JointFit:
    """A candidate refitted jointly with the recalibration (:func:`cryod.analysis.refinement.refine`).

    Attributes
    ----------
    fit : CandidateFit
        The candidate, refitted.
    recalibration : RecalibratedBase
        The recalibration refitted with it.
    named_effects : tuple of NamedEffect
        The causes named before it, their numbers refitted alongside.
    """

    fit: CandidateFit
    recalibration: RecalibratedBase
    named_effects: tuple[NamedEffect, ...]


@dataclass(frozen=True, kw_only=True)
class ReplayedModel:
    """A model, the record replayed with it, and what that replay leaves on the held-out blocks."""

    model: CryostatModel
    replay: Replay
    remaining: BaseDiscrepancy


@dataclass(frozen=True, kw_only=True)
class FurtherCandidate:
    """A candidate fitted on top of the causes named, judged on what it adds and at its own signature.

    Attributes
    ----------
    cause : str
    joint : bool
        Whether it was refitted jointly with the causes named (all their numbers and the recalibration free);
        otherwise its first fit on top of them (their numbers and the recalibration linearised).
    improvement, significance : float
        What it adds on the held-out blocks (noise units) and that in standard deviations.
    explained_fraction : float
        Its share of everything the causes named leave.
    band : str
        Its signature's band (:func:`cryod.analysis.cause_signature.band_of`).
    before : BandExcess
        What the causes named leave in that band.
    share : float
        Its share of ``before``'s excess.
    admitted : bool
        Whether the rule names it (:func:`cryod.analysis.cause_search.rules.admits_further_cause`).
    off_signature : bool
        Its fit removes what it removes mostly outside its signature
        (:func:`cryod.analysis.cause_search.rules.shows_at_its_signature`).
    reshapes : bool
        It only reshapes a cause named on its path (:func:`cryod.analysis.cause_search.rules.reshapes_a_named_cause`).
    """

    cause: str
    joint: bool
    improvement: float
    significance: float
    explained_fraction: float
    band: str
    before: BandExcess
    share: float
    admitted: bool
    off_signature: bool = False
    reshapes: bool = False

    def as_dict(self) -> dict:
        return {"cause": self.cause, "joint_fit": self.joint, "improvement": self.improvement,
                "significance": self.significance, "share_of_what_is_left": self.explained_fraction,
                "signature": self.band, "signature_excess": self.before.excess,
                "signature_significance": self.before.significance, "share_at_signature": self.share,
                "admitted": self.admitted, "off_signature": self.off_signature, "reshapes": self.reshapes}


@dataclass(frozen=True, kw_only=True)
class BoundEvidence:
    """A named cause's parameter at an edge of its range, re-examined (:mod:`~cryod.analysis.cause_search.bounds`).

    Attributes
    ----------
    cause, parameter : str
    value : float
        Where the joint fit left it.
    bound : float
        The edge it sits at (the widened one when the range was widened).
    widened_from : float or None
        The edge before it was widened (None: physics or the model file does not let it be widened).
    stays : bool
        Whether it is still at the edge once re-examined.
    """

    cause: str
    parameter: str
    value: float
    bound: float
    widened_from: float | None
    stays: bool

    def text(self) -> str:
        where = (f"at the edge of its range ({self.bound:.4g}, widened from {self.widened_from:.4g})"
                 if self.widened_from is not None else f"at the edge of its range ({self.bound:.4g}, not widened)")
        return (f"{self.cause}'s {self.parameter} {self.value:.4g} is {where}: the cause is not the record's form, "
                "or it stands in for another" if self.stays else
                f"{self.cause}'s {self.parameter} left the edge {self.widened_from:.4g} once widened: {self.value:.4g}")

    def as_dict(self) -> dict:
        return {"cause": self.cause, "parameter": self.parameter, "value": self.value, "bound": self.bound,
                "widened_from": self.widened_from, "stays_at_bound": self.stays, "text": self.text()}


@dataclass(frozen=True, kw_only=True)
class CausePath:
    """Causes named one after another from a first choice, and where they leave the model.

    Attributes
    ----------
    causes : tuple of NamedCause
        In the order they were named.
    context : FitContext
        On the model with these causes: where a further cause is fitted and judged.
    remaining : BaseDiscrepancy
        What the model with these causes still shows on the held-out blocks.
    named_effects : tuple of NamedEffect
        The causes' own numbers, refitted with the recalibration when a further cause is.
    recalibration : RecalibratedBase
        The recalibration as refitted with these causes.
    reasons : tuple of str
        What happened on the way, in words (the decision's reason is made of them).
    further : tuple of FurtherCandidate
        The candidates last judged on top of these causes and not named (what would explain what is left).
    at_bound : tuple of BoundEvidence
        The first cause's numbers found at an edge of their range when it was named, re-examined.
    """

    causes: tuple[NamedCause, ...]
    context: FitContext
    remaining: BaseDiscrepancy
    named_effects: tuple[NamedEffect, ...]
    recalibration: RecalibratedBase
    reasons: tuple[str, ...]
    further: tuple[FurtherCandidate, ...] = ()
    at_bound: tuple["BoundEvidence", ...] = ()

    def replayed(self) -> ReplayedModel:
        """The model with these causes, its replay and what it leaves."""
        return ReplayedModel(model=self.context.base_model, replay=self.context.base_replay,
                             remaining=self.remaining)

    def cause_names(self) -> tuple[str, ...]:
        return tuple(named.cause for named in self.causes)


@dataclass(frozen=True, kw_only=True)
class Verdict:
    """What the search concludes on one record.

    Attributes
    ----------
    decision : Decision
        The cause named and why.
    recalibrated : bool
        Whether the recalibration is part of the extended model.
    causes : tuple of NamedCause
        Every cause named, strongest first; empty for ``none`` and ``unexplained``.
    final_model : CryostatModel
        The extended model: the base model as given, recalibrated, or recalibrated with the causes named.
    final_replay : Replay
    remaining : BaseDiscrepancy
        What the extended model still shows on the held-out blocks.
    final_recalibration : Recalibration or None
        The recalibration as refitted with the causes named.
    generic : GenericExtension or None
        The generic extension the causes were weighed against, when they were
        (:class:`cryod.analysis.generic_extension.GenericExtension`).
    other_paths : tuple of dict
        Readings of other causes that fit the record as well as those named (:mod:`cryod.analysis.equivalence`).
    further : tuple of FurtherCandidate
        Candidates judged on top of the causes named and not named.
    at_bound : tuple of BoundEvidence
        The causes' numbers found at an edge of their range, re-examined.
    """

    decision: Decision
    recalibrated: bool
    causes: tuple[NamedCause, ...] = ()
    final_model: CryostatModel
    final_replay: Replay
    remaining: BaseDiscrepancy
    final_recalibration: Recalibration | None = None
    generic: GenericExtension | None = None
    other_paths: tuple[dict, ...] = ()
    further: tuple[FurtherCandidate, ...] = ()
    at_bound: tuple[BoundEvidence, ...] = ()


class BeyondTolerance(Protocol):
    """For ``base_model_off``: what the record asks beyond the recalibration's tolerance, as the report reads it
    (:class:`cryod.analysis.cause_search.base_model_off.BeyondRecalibration`)."""

    @property
    def parameters(self) -> list[RecalibratedParameter]: ...
    @property
    def at_tolerance(self) -> list[str]: ...
    @property
    def within_tolerance(self) -> Analysis: ...
    @property
    def equivalent_to(self) -> list[dict]: ...
    def as_dict(self) -> dict: ...


class WhatIsLeft(Protocol):
    """What is left, band by band, as the report reads it
    (:class:`cryod.analysis.cause_search.what_is_left.Attribution`)."""

    def sentences(self) -> list[str]: ...
    def as_dict(self) -> dict: ...


@dataclass(frozen=True, kw_only=True)
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
        Wall time of each step, in the order they ran (the command adds its own).
    recalibration : Recalibration
        The recalibration of the base model alone.
    recalibrated : bool
        Whether the recalibration is part of the extended model (it is when the
        base model as given shows a discrepancy).
    recalibration_gain : Gain
        Held-out residual of the base model as given and recalibrated.
    causes : tuple of NamedCause
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
    beyond_recalibration : BeyondTolerance or None
        For ``base_model_off``: the parameters the record asks beyond the recalibration's tolerance
        (:class:`cryod.analysis.cause_search.base_model_off.BeyondRecalibration`).
    generic : GenericExtension or None
        The generic extension fitted on top of the extended model, when a discrepancy remains
        (:class:`cryod.analysis.generic_extension.GenericExtension`).
    residual_signature : ResidualSignature or None
        What the extended model leaves, described (:class:`cryod.analysis.residual_signature.ResidualSignature`).
    widened : Recalibration or None
        The base model alone recalibrated with the wider tolerances of
        :mod:`cryod.analysis.cause_search.base_model_off`, once a parameter reached its usual tolerance.
    other_paths : tuple of dict
        Readings of other causes that fit the record as well as the causes named
        (:mod:`cryod.analysis.equivalence`; each with ``reading``, ``causes`` and ``told_apart_by``).
    further : tuple of FurtherCandidate
        Candidates judged on top of the causes named and not named: what would explain what is left.
    at_bound : tuple of BoundEvidence
        Named causes' parameters found at an edge of their range, re-examined.
    attribution : WhatIsLeft or None
        What is left, band by band, and the candidates that would explain it
        (:class:`cryod.analysis.cause_search.what_is_left.Attribution`).
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
    recalibration: Recalibration
    recalibrated: bool = False
    recalibration_gain: Gain
    causes: tuple[NamedCause, ...] = ()
    final_model: CryostatModel | None = None
    final_replay: Replay | None = None
    base_discrepancy: BaseDiscrepancy
    final_recalibration: Recalibration | None = None
    remaining: BaseDiscrepancy | None = None
    beyond_recalibration: BeyondTolerance | None = None
    generic: GenericExtension | None = None
    residual_signature: ResidualSignature | None = None
    widened: Recalibration | None = None
    other_paths: tuple[dict, ...] = ()
    further: tuple[FurtherCandidate, ...] = ()
    at_bound: tuple[BoundEvidence, ...] = ()
    attribution: WhatIsLeft | None = None

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


__all__ = ["Analysis", "BeyondTolerance", "BoundEvidence", "CausePath", "FurtherCandidate", "JointFit", "NamedCause",
           "ReplayedModel", "Verdict", "WhatIsLeft"]
