"""How much of a record's discrepancy the base model's own uncertainty accounts for.

A model identified by ``cryod identify`` states how well it knows its
parameters (:class:`cryod.model.uncertainty.ModelUncertainty`). Replaying a
record through models drawn from that distribution shows how far the model's
prediction could move without anything being wrong with its form:

* the prediction's spread (rms over the held-out samples of the standard
  deviation across the drawn models, T2 and T5);
* the excess it alone would add to the held-out sum of squares, in noise
  units: ``U = sum (spread / noise)^2`` (the base model's excess ``E`` is
  the sum of squares less the number of terms, :mod:`cryod.analysis.decision`);
* the verdict: the discrepancy is *within the model's uncertainty* when
  ``E <= U + 3 sqrt(2 n)`` (3 standard deviations of the noise's own
  sum of squares): then the model's parameters, within their stated
  uncertainty, explain the record, and a cause found is worth a second record
  before the model is extended.

The cause the analysis names is not changed by this; ``cryod analyze`` reports
it beside the cause (``model_uncertainty`` in the JSON, present only for a model
that states its uncertainty; a section in the report).
"""

from __future__ import annotations

import math

import numpy as np

from cryod.analysis.decision import base_discrepancy

#: Models drawn from the stated uncertainty.
DEFAULT_DRAWS = 20


def model_uncertainty_check(analysis, draws: int = DEFAULT_DRAWS, seed: int | None = 0) -> dict | None:
    """The base model's prediction spread over its stated uncertainty, against the record's discrepancy.

    Parameters
    ----------
    analysis : cryod.analysis.cause_search.results.Analysis
    draws : int
    seed : int, optional

    Returns
    -------
    dict or None
        None when the base model states no uncertainty.
    """
    model = analysis.base_model
    if model.uncertainty is None:
        return None
    context = analysis.context
    mask = context.held_out_mask
    # the model as given, before the analysis recalibrated it: its discrepancy is what its uncertainty must cover
    base = analysis.base_discrepancy if analysis.base_discrepancy is not None else base_discrepancy(context)
    flange, stage = [], []
    for drawn in model.uncertainty.sampled_models(model, draws, seed):
        replay = context.replayer.replay(drawn, analysis.base_line)
        flange.append(replay.flange_K[mask])
        stage.append(replay.ptc_stage_K[mask])
    if len(flange) < 2:
        return None
    flange_spread = np.std(np.array(flange), axis=0, ddof=1)
    stage_spread = np.std(np.array(stage), axis=0, ddof=1)
    noise = context.noise_rms_K
    expected = float(np.sum((flange_spread / noise[0]) ** 2) + np.sum((stage_spread / noise[1]) ** 2))
    allowance = 3.0 * math.sqrt(2.0 * base.terms)
    within = base.excess <= expected + allowance
    return {
        "draws": len(flange),
        "prediction_spread_rms_K": [float(np.sqrt(np.mean(flange_spread ** 2))),
                                    float(np.sqrt(np.mean(stage_spread ** 2)))],
        "base_excess": float(base.excess),
        "excess_from_model_uncertainty": expected,
        "noise_allowance": allowance,
        "within_model_uncertainty": bool(within),
        "verdict": (f"the record's discrepancy (excess {base.excess:.0f}) is within what the model's stated "
                    f"uncertainty allows ({expected:.0f} + {allowance:.0f} for the noise)" if within else
                    f"the record's discrepancy (excess {base.excess:.0f}) is beyond what the model's stated "
                    f"uncertainty allows ({expected:.0f} + {allowance:.0f} for the noise): not a matter of the "
                    "parameters' precision"),
    }


def report_section(check: dict | None) -> str:
    """Markdown for the analysis report."""
    if check is None:
        return ""
    spread = check["prediction_spread_rms_K"]
    return "\n".join([
        "", "## The base model's own uncertainty", "",
        f"Replayed through {check['draws']} models drawn from the uncertainty the model file states, the "
        f"prediction moves by {spread[0] * 1e6:.2f} µK (T2) and {spread[1] * 1e6:.1f} µK (T5) rms; {check['verdict']}.",
        "",
    ])


__all__ = ["model_uncertainty_check", "report_section", "DEFAULT_DRAWS"]
