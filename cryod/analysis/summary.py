"""The analysis as plain data: the ``--json`` object and the extended model file's provenance header.

JSON keys (``cryod analyze --json``): ``cause`` (one of :data:`CAUSES`: the
strongest cause named), ``causes`` (list, strongest first, of every cause
named: {cause, parameters, explained_fraction, gain, significance, score};
empty for ``none`` and ``unexplained``), ``recalibrated`` ({applied,
parameters: list of {parameter, unit, shipped, fitted, uncertainty,
significance, at_tolerance}, gain, tolerance}), ``discrepancies`` (list of
{quantity, model, measured, significance}), ``extended_model`` (path of the
model file written), ``gain`` ({metric, base, extended, ratio}: the base model
as given against the extended one, generic extension included), ``candidates`` (list, one per cause tried
on the recalibrated model: {cause, score, parameters, significance,
explained_fraction, gain_ratio}; ``score`` is the held-out improvement in
noise-variance units); ``remaining`` (what the causes' model still shows:
{discrepancy, excess, significance, fraction_of_noise_power}); ``base_model_off``
(for that verdict: the parameters the record asks beyond the tolerance, with
the values asked for, the advice, what a catalogue cause alone would have
said); ``generic_extension`` (what is left modelled without physics: each
family alone, the families used, the heater-path terms and the disturbance's
statistics, its held-out gain and whether it is in the extended model: then
``gain`` counts it); ``residual_signature`` (spectral peaks,
drift, cross-correlations, segments, the resid-style correlations:
:mod:`cryod.analysis.residual_signature`); ``at_bound`` (list: a named cause's number found at an edge of its
range, re-examined: {cause, parameter, value, bound, widened_from, stays_at_bound, text};
:mod:`cryod.analysis.cause_search.bounds`); ``attribution`` (what the extended model leaves, band by band: the
line and its harmonics, the slow stretches; each with its excess and the candidates that would explain it:
:mod:`cryod.analysis.cause_search.what_is_left`). Each named cause also carries
``equivalent_to`` (other readings that fit alike: :mod:`cryod.analysis.equivalence`), and so does
``base_model_off`` when a cause named within the tolerance stood for the parameter it lists (a link
without a lag for the line's gain on T2).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from cryod.analysis.candidates import CANDIDATE_CAUSES
from cryod.analysis.equivalence import equivalents
from cryod.analysis.cause_search.results import Analysis

#: The cause vocabulary of ``cryod analyze`` (docs/reference/causes.md is generated from it).
CAUSES = ("none", *CANDIDATE_CAUSES, "unexplained", "base_model_off")


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


def causes_summary(analysis: Analysis) -> list[dict]:
    """Every cause named, strongest first, with what it brought when added."""
    if analysis.cause in ("none", "unexplained"):
        return []
    return plain([{
        "cause": named.cause,
        "parameters": named.fit.parameters,
        "explained_fraction": named.explained_fraction,
        "gain": named.gain.as_dict(),
        "significance": named.score.significance,
        "score": named.score.improvement,
        "equivalent_to": equivalents(analysis, named),
    } for named in analysis.causes])


def recalibration_rows(analysis: Analysis) -> list[dict]:
    """Each recalibrated quantity: the structure's parameters, the operating point and the noise."""
    recalibration = analysis.final_recalibration or analysis.recalibration
    if recalibration is None:
        return []
    rows = [row.as_dict() for row in recalibration.table()]
    replay = analysis.extended_replay if analysis.recalibrated else recalibration.replay
    shipped_point = analysis.base_model.operating_point
    point = replay.operating_point
    covariance = replay.normal_inverse
    modes = replay.initial_mode_amplitudes_K.size
    errors = (math.sqrt(covariance[0, 0]) if covariance is not None else math.nan,
              math.sqrt(covariance[1 + modes, 1 + modes]) if covariance is not None else math.nan)
    for name, shipped, fitted, error in (
            ("operating point T2_0", shipped_point.flange_temperature_K, point.flange_temperature_K, errors[0]),
            ("operating point T5_0", shipped_point.ptc_stage_temperature_K, point.ptc_stage_temperature_K,
             errors[1])):
        rows.append({"parameter": name, "unit": "K", "shipped": shipped, "fitted": fitted, "uncertainty": error,
                     "significance": abs(fitted - shipped) / error if error > 0 else math.inf,
                     "at_tolerance": False})
    count = int(np.count_nonzero(analysis.data.valid))
    noise = analysis.base_model.sensor_noise
    for name, shipped, fitted in (("T2 white noise rms", noise.flange_thermometer_rms_K, analysis.noise_rms_K[0]),
                                  ("T5 white noise rms", noise.ptc_stage_thermometer_rms_K, analysis.noise_rms_K[1])):
        error = fitted * 1.25 / math.sqrt(2.0 * max(count, 1))
        rows.append({"parameter": name, "unit": "K", "shipped": shipped, "fitted": fitted, "uncertainty": error,
                     "significance": abs(fitted - shipped) / error if error > 0 else math.inf,
                     "at_tolerance": False})
    return plain(rows)


def recalibration_summary(analysis: Analysis) -> dict:
    """The ``recalibrated`` object of the JSON."""
    from cryod.analysis.recalibration import LINE_PHASE_TOLERANCE_RAD, TOLERANCE

    gain = analysis.recalibration_gain
    return plain({
        "applied": analysis.recalibrated,
        "parameters": recalibration_rows(analysis),
        "gain": gain.as_dict() if gain is not None else None,
        "tolerance": {"relative": TOLERANCE, "line_phase_rad": LINE_PHASE_TOLERANCE_RAD},
    })


def json_summary(analysis: Analysis, discrepancies, extended_model_path: Path) -> dict:
    """The ``--json`` object."""
    return {
        "cause": analysis.cause,
        "causes": causes_summary(analysis),
        "recalibrated": recalibration_summary(analysis),
        "discrepancies": [plain(d.as_dict()) for d in discrepancies],
        "extended_model": str(extended_model_path),
        "gain": plain(analysis.decision.gain.as_dict()),
        "candidates": candidates_summary(analysis),
        "remaining": plain(_remaining(analysis)),
        "base_model_off": plain(analysis.beyond_recalibration.as_dict()) if analysis.beyond_recalibration else None,
        "generic_extension": plain(analysis.generic.as_dict()) if analysis.generic else None,
        "residual_signature": plain(analysis.residual_signature.as_dict()) if analysis.residual_signature else None,
        "at_bound": [plain(item.as_dict()) for item in analysis.at_bound],
        "attribution": plain(analysis.attribution.as_dict()) if analysis.attribution is not None else None,
    }


def _remaining(analysis: Analysis) -> dict | None:
    """What the causes' model still shows on the held-out blocks (before any generic extension)."""
    left = analysis.remaining
    if left is None:
        return None
    return {"discrepancy": left.present, "excess": left.excess, "significance": left.significance,
            "fraction_of_noise_power": left.excess / left.terms}


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
    if analysis.recalibrated:
        changed = ", ".join(f"{row.parameter} {row.shipped:.6g} -> {row.fitted:.6g} {row.unit}".rstrip()
                            for row in (analysis.final_recalibration or analysis.recalibration).table())
        lines.append(f"Recalibrated (base model's parameters refitted to the record): {changed}")
    for named in (analysis.causes if analysis.cause not in ("none", "unexplained") else []):
        lines.append(f"Fitted effect: {named.cause}: {format_parameters(named.fit.parameters)}")
    if analysis.generic is not None and analysis.generic.added:
        gain = analysis.generic.score.gain
        lines.append(f"Generic (data-driven, not a physical cause): {' + '.join(analysis.generic.used)}, held-out "
                     f"gain {gain.ratio:.4g} on top of the causes")
    if analysis.extended:
        lines.append(f"Gain on held-out data: {decision.gain.ratio:.4g} ({decision.gain.metric}: "
                     f"base {decision.gain.base:.4g}, extended {decision.gain.extended:.4g})")
    else:
        lines.append("No effect added: this file is the base model unchanged.")
    return "\n".join(lines)
