"""Every candidate cause and the function that fits it to a record (:data:`FITTERS`)."""

from __future__ import annotations

from cryod.analysis.candidates import CANDIDATE_CAUSES, CORE_FITTERS
from cryod.analysis.cooler_causes import fit_ptc_amplitude_modulation, fit_ptc_stage_drift

#: Per cause of :data:`cryod.analysis.candidates.CANDIDATE_CAUSES`: ``fit(context) -> CandidateFit``.
FITTERS = {**CORE_FITTERS, "ptc_amplitude_modulation": fit_ptc_amplitude_modulation,
           "ptc_stage_drift": fit_ptc_stage_drift}

if set(FITTERS) != set(CANDIDATE_CAUSES):
    raise ImportError(f"causes without a fitter: {sorted(set(CANDIDATE_CAUSES) - set(FITTERS))}")

__all__ = ["FITTERS"]
