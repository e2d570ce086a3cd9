"""The analysis as plain data: the ``--json`` object and the extended model file's provenance header.

JSON keys (``cryod analyze --json``): ``cause`` (one of :data:`CAUSES`),
``discrepancies`` (list of {quantity, model, measured, significance}),
``extended_model`` (path of the model file written), ``gain`` ({metric, base,
extended, ratio}), ``candidates`` (list, one per cause tried: {cause, score,
parameters, significance, explained_fraction, gain_ratio}; ``score`` is the
held-out improvement over the base model in noise-variance units).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from cryod.analysis.candidates import CANDIDATE_CAUSES
from cryod.analysis.pipeline import Analysis

#: The cause vocabulary of ``cryod analyze`` (DESIGN.md 4.3).
CAUSES = ("none", *CANDIDATE_CAUSES, "unexplained")


def plain(value):
    """Numbers and containers as JSON-ready Python values (non-finite numbers as None)."""
    if isinstance(value, dict):
        return {str(key): plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(item) for item in value]
    if isinstance(value, (np.floating, float)):
        value = float(value)
        return value if math.isfinite(value) else None
    if isinstance(value, (np.integer,)):
        return int(value)
    return value


def candidates_summary(analysis: Analysis) -> list[dict]:
    rows = []
    for cause, fit in analysis.fits.items():
        score = analysis.scores[cause]
        rows.append({
            "cause": cause,
            "score": score.improvement,
            "parameters": fit.parameters,
            "significance": score.significance,
            "explained_fraction": score.explained_fraction,
            "gain_ratio": score.gain.ratio,
        })
    return plain(rows)


def json_summary(analysis: Analysis, discrepancies, extended_model_path: Path) -> dict:
    """The ``--json`` object."""
    return {
        "cause": analysis.cause,
        "discrepancies": [plain(d.as_dict()) for d in discrepancies],
        "extended_model": str(extended_model_path),
        "gain": plain(analysis.decision.gain.as_dict()),
        "candidates": candidates_summary(analysis),
    }


def format_parameters(parameters: dict) -> str:
    """``name = value`` pairs, numbers to 4 significant digits."""
    parts = []
    for name, value in parameters.items():
        if isinstance(value, (list, tuple)):
            text = "[" + ", ".join(f"{float(v):.4g}" for v in value) + "]"
        elif isinstance(value, (float, int, np.floating)):
            text = f"{float(value):.4g}"
        else:
            text = str(value)
        parts.append(f"{name} = {text}")
    return ", ".join(parts) if parts else "(none)"


def model_header(analysis: Analysis, record_path: Path, base_model_path: Path) -> str:
    """Provenance comment of the extended model file."""
    decision = analysis.decision
    lines = [
        f"Written by cryod analyze from the record {record_path}",
        f"Base model: {base_model_path}",
        f"Cause: {analysis.cause}: {decision.reason}",
    ]
    if analysis.cause in analysis.fits:
        lines.append(f"Fitted effect: {analysis.cause}: {format_parameters(analysis.fits[analysis.cause].parameters)}")
        lines.append(f"Gain on held-out data: {decision.gain.ratio:.4g} ({decision.gain.metric}: "
                     f"base {decision.gain.base:.4g}, extended {decision.gain.extended:.4g})")
    else:
        lines.append("No effect added: this file is the base model unchanged.")
    return "\n".join(lines)
