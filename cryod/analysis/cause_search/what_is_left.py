"""Describe what is left: the extended model's residual described, and the generic extension where it is needed.

The residual's signature (:mod:`cryod.analysis.residual_signature`) says what
the extended model leaves; where that is still a discrepancy, the generic
extension (:mod:`cryod.analysis.generic_extension`) is fitted on top of the
extended model (or the one the causes were weighed against is kept) and, when
it counts, added to it: the gain is then the base model's against the model
extended by both.
"""

from __future__ import annotations

import dataclasses

from cryod.analysis.candidates import FitContext
from cryod.analysis.cause_search.results import Analysis
from cryod.analysis.decision import gain_between
from cryod.analysis.generic_extension import fit_generic_extension
from cryod.analysis.residual_signature import describe_residual


def describe_what_is_left(analysis: Analysis) -> Analysis:
    """Step 8: ``analysis`` with its residual's signature and, where its extended model leaves a discrepancy, the
    generic extension (the one fitted when the causes were weighed against it, if on the same model)."""
    signature = describe_residual(analysis)
    if analysis.remaining is None or not analysis.remaining.present:
        return dataclasses.replace(analysis, residual_signature=signature, generic=None)
    generic = analysis.generic
    if generic is None or generic.on_model is not analysis.extended_model:
        context = analysis.context
        on_extended = FitContext(analysis.data, context.replayer, analysis.extended_model, analysis.base_line,
                                 analysis.extended_replay, analysis.noise_rms_K, context.fit_mask,
                                 context.held_out_mask)
        generic = fit_generic_extension(on_extended, analysis.remaining)
    if not generic.added:
        return dataclasses.replace(analysis, residual_signature=signature, generic=generic)
    shipped, score = analysis.base_discrepancy, generic.score
    return dataclasses.replace(
        analysis, residual_signature=signature, generic=generic, final_model=generic.fit.extended_model,
        final_replay=generic.fit.replay, decision=dataclasses.replace(analysis.decision, gain=gain_between(
            shipped.sum_of_squares, score.held_out_flange + score.held_out_stage, shipped.terms)))


__all__ = ["describe_what_is_left"]
