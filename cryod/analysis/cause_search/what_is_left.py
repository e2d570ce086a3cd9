"""Describe what is left: the extended model's residual described, and the generic extension where it is needed.

The residual's signature (:mod:`cryod.analysis.residual_signature`) says what
the extended model leaves; where that is still a discrepancy, what is left is
attributed (:func:`attribute`): band by band (the cooler's line and harmonics;
the slow stretches where the temperatures follow the heater,
:mod:`cryod.analysis.cause_signature`), its excess and the candidates judged on
top of the causes named that would explain it, with their share of it, what
they add and why a rule refused them. Then the generic extension
(:mod:`cryod.analysis.generic_extension`) is fitted on top of the extended
model (or the one the causes were weighed against is kept) and, when it counts,
added to it: the gain is then the base model's against the model extended by
both.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from cryod.analysis.candidates import FitContext
from cryod.analysis.cause_search.results import Analysis, FurtherCandidate
from cryod.analysis.cause_search.rules import SIGNATURE_SHARE, signature_discrepancy
from cryod.analysis.cause_signature import BANDS, BandExcess, BandLayout
from cryod.analysis.decision import CANDIDATE_MINIMUM_IMPROVEMENT, CANDIDATE_SIGMA, EXPLAINED_FRACTION, gain_between
from cryod.analysis.generic_extension import fit_generic_extension
from cryod.analysis.residual_signature import describe_residual

#: What each band is, in the report's words.
BAND_WORDS = {"line": "at the cooler's line and its harmonics (T2 and T5)",
              "slow": "in the slow stretches, where T2 and T5 follow the heater (steps, modulation, warm-ups)"}


@dataclass(frozen=True, kw_only=True)
class Attribution:
    """What is left, band by band, and the candidates that would explain it (:func:`attribute`).

    Attributes
    ----------
    bands : dict of str to BandExcess
        What the extended model (the causes named, before any generic extension) leaves in each band.
    candidates : tuple of FurtherCandidate
        The candidates judged on top of the causes named (on the recalibrated model for ``unexplained``).
    largest_blocks : tuple of dict
        Where in the record the residual is largest (``from_s``, ``to_s``).
    """

    bands: dict[str, BandExcess]
    candidates: tuple[FurtherCandidate, ...]
    largest_blocks: tuple[dict, ...] = ()

    def in_band(self, band: str) -> list[FurtherCandidate]:
        """The candidates whose signature is ``band`` and that would remove some of it, the largest share first."""
        return sorted((item for item in self.candidates if item.band == band and item.share > 0.0),
                      key=lambda item: -item.share)

    def as_dict(self) -> dict:
        return {band: {**self.bands[band].as_dict(), "discrepancy": signature_discrepancy(self.bands[band]),
                       "candidates": [item.as_dict() | {"why_not_named": why_not_named(item)}
                                      for item in self.in_band(band)]} for band in BANDS}

    def sentences(self) -> list[str]:
        """What is left, band by band, in words."""
        found = []
        for band in BANDS:
            left, items = self.bands[band], self.in_band(band)
            if not signature_discrepancy(left) and not items:
                continue
            where = BAND_WORDS[band]
            if band == "slow" and self.largest_blocks:
                where += "; largest in " + ", ".join(f"{block['from_s']:.0f}-{block['to_s']:.0f} s"
                                                    for block in self.largest_blocks[:2])
            text = f"{where}: excess {left.excess:.4g} ({left.significance:.1f} sigma)"
            parts = [f"{item.cause} would remove {100.0 * item.share:.1f} % of it "
                     f"({'refitted jointly with the causes named' if item.joint else 'fitted on top'}: adds "
                     f"{item.improvement:.4g}, {item.significance:.1f} sigma, {100.0 * item.explained_fraction:.1f} % "
                     f"of everything left; {why_not_named(item)})" for item in items[:3]]
            found.append(text + ("; " + "; ".join(parts) if parts else "; no candidate would remove any of it"))
        return found


def why_not_named(item: FurtherCandidate) -> str:
    """Why a candidate judged on top of the causes named is not among them, in words."""
    if item.admitted:
        return "admitted, but it adds too little to the generic extension"
    if item.off_signature:
        return "refused: it removes what it removes mostly outside its signature, standing for another cause"
    if item.reshapes and item.joint:
        return (f"refused: {100.0 * item.explained_fraction:.1f} % of everything left, beside a cause named on the "
                "line's path to T2 whose form it reshapes (10 % of the excess needed)")
    if item.significance < CANDIDATE_SIGMA or item.improvement < CANDIDATE_MINIMUM_IMPROVEMENT:
        return "refused: it does not add what a cause must (25 and 5 sigma)"
    if not item.joint:
        return "not refitted jointly: its first fit does not lead"
    if not signature_discrepancy(item.before):
        return (f"refused: it takes {100.0 * item.explained_fraction:.1f} % of everything left (70 % needed) and its "
                "signature shows no discrepancy")
    return (f"refused: {100.0 * item.explained_fraction:.1f} % of everything left and {100.0 * item.share:.1f} % "
            f"at its signature ({100 * EXPLAINED_FRACTION:g} % and {100 * SIGNATURE_SHARE:g} % needed)")


def attribute(analysis: Analysis) -> Attribution:
    """What the extended model leaves, band by band, and the candidates judged on top of its causes."""
    context = analysis.context
    layout = BandLayout.of(analysis.data, context.held_out_mask, analysis.base_line, analysis.noise_rms_K)
    blocks = tuple(analysis.residual_signature.worst_blocks) if analysis.residual_signature is not None else ()
    return Attribution(bands=layout.bands(analysis.extended_replay), candidates=analysis.further,
                       largest_blocks=blocks)


def describe_what_is_left(analysis: Analysis) -> Analysis:
    """Step 8: ``analysis`` with its residual's signature and, where its extended model leaves a discrepancy, what
    is left attributed to the candidates (:func:`attribute`) and the generic extension (the one fitted when the
    causes were weighed against it, if on the same model)."""
    signature = describe_residual(analysis)
    if analysis.remaining is None or not analysis.remaining.present:
        return dataclasses.replace(analysis, residual_signature=signature, generic=None)
    analysis = dataclasses.replace(analysis, residual_signature=signature)
    analysis = dataclasses.replace(analysis, attribution=attribute(analysis))
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


__all__ = ["Attribution", "attribute", "describe_what_is_left", "why_not_named"]
