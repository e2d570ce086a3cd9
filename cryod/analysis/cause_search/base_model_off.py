"""A base model further off than the recalibration allows: ``base_model_off``.

The recalibration (:mod:`cryod.analysis.recalibration`) may move each of the
base model's gains and time constants by 10 % (the line's phase by 0.1 rad):
the spread expected of a cryostat of the kind the model was made for. A record
of another cryostat (another flange, another heater, a wrong heater
resistance in the configuration) asks for more, and a catalogue cause then
takes up what the recalibration cannot: a heater 15 % stronger than the model
says looks like a heater nonlinearity with the gains at their tolerance.

The rule (:func:`judged_beyond_recalibration`), after the causes are searched
within the tolerance:

1. It is asked only when the search needs it: a parameter of the
   recalibration (refitted with the causes named) is at its tolerance, a
   cause named stands for a base parameter, or the extended model still shows
   a discrepancy by the rule that calls for a cause. A cause stands for a base
   parameter when all it changes in what the record shows is that parameter
   (:func:`cryod.analysis.equivalence.line_gain_stood_for`: a link whose lag
   moves the line's phase by no more than the recalibration may is, at the one
   frequency of the line, the line's gain on T2); such a parameter counts as
   at its tolerance (the cause was named because the recalibration could not
   reach it), and the cause is the parameter's equivalent reading.
2. The base model alone is then recalibrated with :data:`WIDE` tolerances
   (50 % on gains and time constants, 0.4 rad on the line's phase). A
   parameter is *beyond* the recalibration when its widened value is past its
   usual tolerance by at least :data:`BEYOND_SIGMA` standard errors.
3. With a parameter beyond, the causes are searched again on the widened
   model (its own recalibration of 10 % around it; the causes tried are those
   that improved the held-out residual within the tolerance,
   :func:`cryod.analysis.cause_search.rules.improving_causes`; one cause at
   most). The verdict is ``base_model_off`` (with what that search names on
   top of it) when that search explains the record to the noise (no
   discrepancy left by the rule that calls for a cause: a record with
   something outside the catalogue is not put down to the base model, nor is
   a widened model patched by causes) and its extended model is preferred to
   the first one's (:func:`cryod.analysis.cause_search.rules.widened_model_preferred`:
   significantly better on the held-out blocks, or, when a parameter was at
   its tolerance, not significantly worse); and, when that search names a
   cause, significantly better than the model within the tolerance with that
   same cause (:func:`cryod.analysis.cause_search.rules.asks_beyond_its_causes`).
   Otherwise the first verdict stands: a catalogue cause that explains the
   record better than any change of the base model's parameters is named, and
   a parameter at its tolerance is reported with it.

When the recalibration alone leaves a parameter at its tolerance and the
widened recalibration alone leaves no discrepancy (:func:`explained_by_widening`),
the search within the tolerance looks for the first cause only (what a
catalogue cause alone would say), not for a path of several: the record is
explained without any.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

from cryod.analysis.candidates import FitContext
from cryod.analysis.cause_search.results import Analysis
from cryod.analysis.cause_search.rules import asks_beyond_its_causes, widened_model_preferred
from cryod.analysis.decision import Decision, base_discrepancy, gain_between, significance
from cryod.analysis.equivalence import LINE_GAIN, as_link, line_gain_stood_for
from cryod.analysis.recalibration import (
    RecalibratedParameter, Recalibration, Tolerances, recalibrate, structure_parameters,
)
from cryod.analysis.refinement import refine
from cryod.analysis.replay import Replay, Replayer
from cryod.cooler.line import PtcLine
from cryod.model import CryostatModel

#: Tolerances of the widened recalibration.
WIDE = Tolerances(relative=0.5, line_phase_rad=0.4)
#: A widened parameter is beyond its usual tolerance when past it by at least this many standard errors.
BEYOND_SIGMA = 3.0
#: What the report advises for ``base_model_off``.
ADVICE = ("identify the cryostat (`cryod identify`, docs/how-to/commission.md) and analyse the record again with "
          "that model (`cryod analyze RECORD --model MODEL`)")
#: Where the wider recalibration's wall time goes in the timing log.
WIDER_RECALIBRATION = "wider recalibration"


@dataclass(frozen=True, kw_only=True)
class BeyondRecalibration:
    """What makes a verdict ``base_model_off``.

    Attributes
    ----------
    parameters : list of RecalibratedParameter
        The parameters the record asks beyond their usual tolerance: shipped value, the value the record asks
        for (the widened recalibration's), its standard error.
    at_tolerance : list of str
        The parameters the search within the tolerance left at it.
    widened : Recalibration
        The base model alone recalibrated with :data:`WIDE` tolerances.
    within_tolerance : Analysis
        The analysis within the usual tolerance: what a catalogue cause alone would have said.
    on_widened : str
        The verdict of the search on the widened model (``none``, a cause, ``unexplained``).
    improvement : float
        Held-out sum of squares (noise units) of the first extended model less the widened one's.
    equivalent_to : list of dict
        Causes named within the tolerance that stood for a parameter beyond it (a link without a lag for the
        line's gain on T2): the same readings as a cause's ``equivalent_to``.
    """

    parameters: list[RecalibratedParameter]
    at_tolerance: list[str]
    widened: Recalibration
    within_tolerance: Analysis
    on_widened: str
    improvement: float
    equivalent_to: list[dict] = dataclasses.field(default_factory=list)

    def as_dict(self) -> dict:
        return {"parameters": [row.as_dict() | {"relative_change": row.fitted / row.shipped - 1.0}
                               for row in self.parameters],
                "at_tolerance": list(self.at_tolerance), "within_tolerance_cause": self.within_tolerance.cause,
                "within_tolerance_causes": self.within_tolerance.cause_names, "on_widened_model": self.on_widened,
                "held_out_improvement": self.improvement, "equivalent_to": list(self.equivalent_to),
                "advice": ADVICE}


@dataclass(frozen=True, kw_only=True)
class WidenedSearch:
    """The causes searched again on the widened base model, against the first verdict.

    Attributes
    ----------
    widened : Recalibration
    beyond : list of RecalibratedParameter
        The parameters past their usual tolerance (:func:`beyond_parameters`).
    analysis : Analysis
        The search on the widened model.
    improvement : float
        Held-out sum of squares of the first extended model less that of the widened search's.
    significance : float
        ``improvement`` in standard deviations of the difference between the two predictions.
    """

    widened: Recalibration
    beyond: list[RecalibratedParameter]
    analysis: Analysis
    improvement: float
    significance: float


def _held_out(analysis: Analysis, replay: Replay) -> float:
    return sum(analysis.context.chi_square(replay, analysis.context.held_out_mask))


def beyond_parameters(widened: Recalibration, base_model: CryostatModel) -> list[RecalibratedParameter]:
    """The widened recalibration's parameters past their usual tolerance by :data:`BEYOND_SIGMA` standard errors."""
    usual = {parameter.name: parameter.tolerance for parameter in structure_parameters(base_model)}
    found = []
    for row, parameter, x, error in zip(widened.table(), widened.parameters, widened.log_factors,
                                        widened.uncertainties):
        tolerance = usual.get(parameter.name, parameter.tolerance)
        past = abs(float(x)) - tolerance
        if past > 0.0 and (not math.isfinite(error) or past >= BEYOND_SIGMA * float(error)):
            found.append(row)
    return found


def widened_recalibration(replayer: Replayer, base_model: CryostatModel, base_line: PtcLine) -> Recalibration:
    """The base model alone recalibrated with :data:`WIDE` tolerances."""
    return recalibrate(replayer, base_model, base_line, WIDE)


def explained_by_widening(widened: Recalibration, base_model: CryostatModel, context: FitContext) -> bool:
    """Whether the widened recalibration alone moves a parameter beyond its usual tolerance and leaves no
    discrepancy on ``context``'s held-out blocks (the rule that calls for a cause)."""
    if not beyond_parameters(widened, base_model):
        return False
    return not base_discrepancy(dataclasses.replace(context, base_replay=widened.replay)).present


def stood_for(analysis: Analysis) -> list[tuple]:
    """(parameter, factor, named cause) for each cause named that stands for a base parameter
    (:func:`cryod.analysis.equivalence.line_gain_stood_for`)."""
    omega = analysis.base_line.angular_frequency_rad_s
    found = []
    for named in analysis.causes:
        factor = line_gain_stood_for(named, omega)
        if factor is not None:
            found.append((LINE_GAIN, factor, named))
    return found


def _within_tolerance_with_its_cause(analysis: Analysis, on_widened: Analysis) -> bool:
    """Whether the widened model with the cause its search names does significantly better than the model within
    the tolerance with that same cause, refitted with its recalibration
    (:func:`cryod.analysis.cause_search.rules.asks_beyond_its_causes`). True when the widened model names no cause
    (or one the first round did not fit)."""
    if not on_widened.causes:
        return True
    fits = [analysis.fits.get(named.cause) for named in on_widened.causes]
    if any(fit is None for fit in fits) or len(fits) > 1:
        return True
    context = analysis.context
    fit = refine(context.replayer, context.recalibrated, fits[0], [])[0]
    improvement = _held_out(analysis, fit.replay) - _held_out(analysis, on_widened.extended_replay)
    return asks_beyond_its_causes(improvement, significance(improvement, context.distinctness(
        fit.replay, on_widened.extended_replay)))


def judged_beyond_recalibration(analysis: Analysis, search_on: Callable[[CryostatModel], Analysis]) -> Analysis:
    """``analysis`` (of the search within the tolerance), or the ``base_model_off`` verdict when the rule of this
    module says so; ``search_on(model)`` searches the causes on another base model."""
    if not analysis.recalibrated:
        return analysis
    narrow = analysis.final_recalibration or analysis.recalibration
    at_tolerance = [row.parameter for row in narrow.table() if row.at_tolerance]
    standing = stood_for(analysis)
    at_tolerance += [parameter for parameter, _, _ in standing if parameter not in at_tolerance]
    if not at_tolerance and not (analysis.remaining is not None and analysis.remaining.present):
        return analysis
    if analysis.widened is None:
        started = time.perf_counter()
        widened = widened_recalibration(analysis.context.replayer, analysis.base_model, analysis.base_line)
        analysis.timings_s[WIDER_RECALIBRATION] = time.perf_counter() - started
        analysis = dataclasses.replace(analysis, widened=widened)
    beyond = beyond_parameters(analysis.widened, analysis.base_model)
    if not beyond:
        return analysis
    inner = search_on(analysis.widened.model)
    analysis.timings_s.update({f"{step} (widened model)": seconds for step, seconds in inner.timings_s.items()})
    if inner.remaining is not None and inner.remaining.present:
        return analysis
    improvement = _held_out(analysis, analysis.extended_replay) - _held_out(analysis, inner.extended_replay)
    spread = significance(improvement, analysis.context.distinctness(analysis.extended_replay, inner.extended_replay))
    if inner.cause == "unexplained" or not widened_model_preferred(improvement, spread, bool(at_tolerance)):
        return analysis
    if not _within_tolerance_with_its_cause(analysis, inner):
        return analysis
    on_widened = WidenedSearch(widened=analysis.widened, beyond=beyond, analysis=inner, improvement=improvement,
                               significance=spread)
    return base_model_off(analysis, on_widened, at_tolerance, standing)


def base_model_off(analysis: Analysis, on_widened: WidenedSearch, at_tolerance: list[str], standing: list[tuple]
                   ) -> Analysis:
    """The ``base_model_off`` verdict: the widened search's analysis, on the record as the first one replayed and
    judged it (base model, line, noise, timing log), with the widened recalibration and what makes the verdict."""
    inner, widened = on_widened.analysis, on_widened.widened
    shipped = analysis.base_discrepancy
    inner_sum = _held_out(analysis, inner.extended_replay)
    decision = Decision(cause="base_model_off", reason=_reason(on_widened.beyond, inner), best=inner.decision.best,
                        base=shipped, gain=gain_between(shipped.sum_of_squares, inner_sum, shipped.terms))
    return dataclasses.replace(
        inner, base_model=analysis.base_model, base_line=analysis.base_line, base_replay=analysis.base_replay,
        base_discrepancy=shipped, decision=decision, noise_rms_K=analysis.noise_rms_K, recalibrated=True,
        recalibration=widened, final_recalibration=_combined_recalibration(widened, inner),
        recalibration_gain=gain_between(shipped.sum_of_squares, _held_out(analysis, widened.replay), shipped.terms),
        causes=inner.causes if inner.cause not in ("none", "unexplained") else (),
        final_model=inner.extended_model, final_replay=inner.extended_replay, timings_s=analysis.timings_s,
        beyond_recalibration=BeyondRecalibration(
            parameters=on_widened.beyond, at_tolerance=at_tolerance, widened=widened, within_tolerance=analysis,
            on_widened=inner.cause, improvement=float(on_widened.improvement),
            equivalent_to=[as_link(factor, named) for _, factor, named in standing]))


def _combined_recalibration(widened: Recalibration, inner: Analysis) -> Recalibration:
    """The widened factors plus those the search on the widened model refitted (same structure)."""
    own = inner.final_recalibration or (inner.recalibration if inner.recalibrated else None)
    if own is None:
        return widened
    return Recalibration(parameters=widened.parameters, log_factors=widened.log_factors + own.log_factors,
                         uncertainties=own.uncertainties, model=own.model, replay=inner.extended_replay,
                         steps=own.steps, shipped=widened.shipped)


def _reason(beyond: list[RecalibratedParameter], inner: Analysis) -> str:
    asked = ", ".join(f"{row.parameter} {row.shipped:.4g} -> {row.fitted:.4g} {row.unit} "
                      f"({100.0 * (row.fitted / row.shipped - 1.0):+.0f} %)".replace("  ", " ") for row in beyond)
    if inner.cause == "none":
        then = "with those values the model leaves no discrepancy beyond the noise"
    else:
        then = f"with those values, {inner.decision.reason}"
    return (f"the base model is further off than the recalibration allows: the record asks {asked}; {ADVICE}; "
            f"{then}")


__all__ = ["ADVICE", "BEYOND_SIGMA", "WIDE", "WIDER_RECALIBRATION", "BeyondRecalibration", "WidenedSearch",
           "base_model_off", "beyond_parameters", "explained_by_widening", "judged_beyond_recalibration",
           "stood_for", "widened_recalibration"]
