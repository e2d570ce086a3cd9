"""The short Markdown report of an analysis (``report.md`` in ``--out``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cryod.analysis.decision import (
    CANDIDATE_MINIMUM_IMPROVEMENT, CANDIDATE_SIGMA, DISCREPANCY_FRACTION_OF_NOISE, DISCREPANCY_SIGMA,
    EXPLAINED_FRACTION,
)
from cryod.analysis.cause_search.base_model_off import ADVICE
from cryod.analysis.cause_search.bounds import stays_text
from cryod.analysis.discrepancies import Discrepancy
from cryod.analysis.equivalence import equivalents, sentence
from cryod.analysis.cause_search.results import Analysis
from cryod.analysis.record_data import block_length_s, saturation_fraction
from cryod.analysis.summary import format_parameters

#: Discrepancies listed: those above this many standard errors, at most this many.
LISTED_SIGNIFICANCE = 3.0
LISTED_MOST = 25
#: The report's file name.
REPORT_NAME = "report.md"


def _number(value: float) -> str:
    if value is None or not math.isfinite(value):
        return "-"
    return f"{value:.4g}"


def _discrepancy_table(rows: list[Discrepancy]) -> list[str]:
    lines = ["| quantity | model | measured | significance (sigma) |", "|---|---|---|---|"]
    for row in rows:
        lines.append(f"| {row.quantity} | {_number(row.model)} | {_number(row.measured)} | {_number(row.significance)} |")
    return lines


def _named(analysis: Analysis) -> list:
    return analysis.causes if analysis.cause not in ("none", "unexplained") else []


def _extension_text(analysis: Analysis) -> str:
    parts = (["recalibrated"] if analysis.recalibrated else []) + \
        [f"{named.cause}: {format_parameters(named.fit.parameters)}" for named in _named(analysis)]
    if not parts:
        return ", unchanged: no effect is added)."
    return " " + "; ".join(parts) + ")."


def _recalibration_section(analysis: Analysis) -> list[str]:
    from cryod.analysis.recalibration import LINE_PHASE_TOLERANCE_RAD, TOLERANCE
    from cryod.analysis.summary import recalibration_rows

    rows = recalibration_rows(analysis)
    if not rows:
        return []
    gain = analysis.recalibration_gain
    state = ("applied: every cause below is fitted on top of it" if analysis.recalibrated else
             "not applied: the base model as given shows no discrepancy")
    lines = ["", "## Recalibration", "",
             f"The base model's own parameters refitted on the fit blocks, within {100 * TOLERANCE:g} % "
             f"(gains, time constants) and {LINE_PHASE_TOLERANCE_RAD:g} rad (the line's phase on T2); "
             f"{state}. Held-out residual {_number(gain.base)} -> {_number(gain.extended)} times the noise "
             f"(gain {_number(gain.ratio)}).", "",
             "| parameter | shipped | fitted | uncertainty | significance (sigma) |", "|---|---|---|---|---|"]
    for row in rows:
        mark = " (at its tolerance)" if row["at_tolerance"] else ""
        unit = f" {row['unit']}" if row["unit"] else ""
        lines.append(f"| {row['parameter']}{unit} | {_number(row['shipped'])} | {_number(row['fitted'])}{mark} | "
                     f"{_number(row['uncertainty'])} | {_number(row['significance'])} |")
    return lines


def _still_left(analysis: Analysis) -> str:
    """The first line's words on what is left: a discrepancy the causes named leave, and the generic extension."""
    left = analysis.remaining
    if left is None or not left.present or analysis.cause == "none":
        return ""
    text = "" if analysis.cause == "unexplained" else (
        f", and a discrepancy is still left ({left.significance:.1f} sigma, "
        f"{100.0 * left.excess / left.terms:.2f} % of the noise power)")
    generic = analysis.generic
    if generic is not None:
        verb = "extended by" if generic.added else "not extended: it does not count,"
        text += (f"; {'no physical cause is named, ' if analysis.cause == 'unexplained' else ''}the model is {verb} "
                 f"the generic extension ({' + '.join(generic.used)}), which removes "
                 f"{100.0 * generic.score.explained_fraction:.1f} % of what is left (held-out gain "
                 f"{generic.score.gain.ratio:.3g})")
    return text + ": see \"What is left\""


def _base_model_off_section(analysis: Analysis) -> list[str]:
    beyond = analysis.beyond_recalibration
    if beyond is None:
        return []
    lines = ["", "## The base model is further off than the recalibration allows", "",
             f"Advice: {ADVICE}. Within the usual tolerance the analysis would have said "
             f"`{beyond.within_tolerance.cause}` ({', '.join(beyond.within_tolerance.cause_names) or 'no cause'}); "
             f"parameters it left at the tolerance: {', '.join(beyond.at_tolerance) or 'none'}.", "",
             "| parameter | shipped | asked by the record | uncertainty | change |", "|---|---|---|---|---|"]
    for row in beyond.parameters:
        lines.append(f"| {row.parameter} {row.unit} | {_number(row.shipped)} | {_number(row.fitted)} | "
                     f"{_number(row.uncertainty)} | {100.0 * (row.fitted / row.shipped - 1.0):+.1f} % |")
    for reading in beyond.equivalent_to:
        lines += ["", f"The same record reads as {reading['reading']}. What would tell them apart: "
                      f"{reading['told_apart_by']}."]
    return lines


def _left_section(analysis: Analysis) -> list[str]:
    signature = analysis.residual_signature
    lines = ["", "## What is left", ""]
    left = analysis.remaining
    if left is not None:
        lines.append(f"The extended model's held-out excess: {left.excess:.4g} ({left.significance:.1f} sigma, "
                     f"{100.0 * left.excess / left.terms:.2f} % of the noise power): "
                     + ("a discrepancy." if left.present else "within the noise."))
    if signature is not None:
        sentences = signature.sentences()
        lines += [""] + ([f"- {text}" for text in sentences] if sentences else
                         ["- no spectral peak, drift or correlation above its band"])
        if signature.worst_blocks:
            lines.append("- largest in " + ", ".join(f"{block['from_s']:.0f}-{block['to_s']:.0f} s "
                                                    f"({block['chi_square_per_term']:.3g} per term)"
                                                    for block in signature.worst_blocks))
    if analysis.attribution is not None:
        lines += ["", "What would explain it (each candidate judged on top of the causes named, at its own "
                      "signature: docs/explanation/analysis-method.md, section 4b):", ""]
        lines += [f"- {text}" for text in analysis.attribution.sentences()]
    for item in analysis.at_bound:
        lines += ["", f"- {item.text()}"]
    generic = analysis.generic
    if generic is not None:
        gain = generic.score.gain
        state = ("added to the extended model (marked generic: effects "
                 f"{', '.join(_generic_effects(generic))}, no cause)" if generic.added
                 else "not added: it does not count on the held-out blocks")
        lines += ["", f"**Generic extension** (data-driven, not a physical cause; fitted on the fit blocks, judged on "
                      f"the held-out ones): {' + '.join(generic.used)} removes "
                      f"{100.0 * generic.score.explained_fraction:.1f} % of what is left "
                      f"({generic.score.significance:.1f} sigma), held-out gain {gain.ratio:.4g} "
                      f"({_number(gain.base)} -> {_number(gain.extended)} times the noise); {state}. "
                      "Each family alone:", ""]
        lines += [f"- {text}" for text in generic.sentences()]
    return lines


def _generic_effects(generic) -> list[str]:
    """The model file's effects the generic extension adds."""
    return [f"`{name}`" for name, used in (("heater_path_correction", "heater_path_correction" in generic.used),
                                           ("disturbance", set(generic.used) - {"heater_path_correction"})) if used]


def _causes_section(analysis: Analysis) -> list[str]:
    named = _named(analysis)
    if not named:
        return []
    lines = ["", "## Causes named", "",
             "Each one refitted with the recalibration, in the order it was added (the strongest first).", "",
             "| cause | fitted parameters | explained | gain | significance (sigma) |", "|---|---|---|---|---|"]
    for cause in named:
        lines.append(f"| {cause.cause} | {format_parameters(cause.fit.parameters)} | "
                     f"{100 * cause.explained_fraction:.1f} % | {cause.gain.ratio:.4g} | "
                     f"{cause.score.significance:.3g} |")
    for cause in named:
        text = sentence(cause, equivalents(analysis, cause))
        if text:
            lines += ["", text]
    return lines


@dataclass(frozen=True)
class ReportFiles:
    """Where the report goes and the files it names: its folder, the extended model's file, the figures made."""

    directory: Path
    model_path: Path
    figures: dict[str, Path] = field(default_factory=dict)


def write_report(analysis: Analysis, discrepancies: list[Discrepancy], extended_discrepancies: list[Discrepancy],
                 segments, files: ReportFiles) -> Path:
    """Write ``report.md`` into ``files.directory``; figure links are relative to it."""
    figures, model_path, directory = files.figures, files.model_path, files.directory
    data, decision = analysis.data, analysis.decision
    line = analysis.base_line
    point = analysis.extended_replay.operating_point
    at_zero, at_limit = saturation_fraction(data.heater_w, data.heater_limit_w)
    intervals = np.diff(data.time_s)
    lines = [
        f"# Analysis of `{Path(data.source).name}`",
        "",
        f"**Cause: `{analysis.cause}`{stays_text(analysis.at_bound)}{_still_left(analysis)}.** "
        f"{decision.reason[0].upper() + decision.reason[1:]}.",
        "",
        f"**Gain: {decision.gain.ratio:.4g}** ({decision.gain.metric}: base model {decision.gain.base:.4g}, "
        f"extended model {decision.gain.extended:.4g}). Fit and held-out data: alternate blocks of "
        f"{block_length_s(data.duration_s):.0f} s; every parameter is fitted on the first, third, ... block and "
        "judged on the others.",
        "",
        f"**Extended model:** `{model_path.name}` (base model `{analysis.base_model.name or analysis.base_model.source}`"
        + _extension_text(analysis),
        "",
        "## The record",
        "",
        "| | |",
        "|---|---|",
        f"| duration | {data.duration_s:.1f} s, {data.time_s.size} samples |",
        f"| sample interval | median {1e3 * data.sample_interval_s:.2f} ms, rms jitter {1e3 * np.std(intervals):.3f} ms |",
        f"| operating point (estimated with the extended model) | T2_0 = {point.flange_temperature_K:.5f} K, "
        f"T5_0 = {point.ptc_stage_temperature_K:.5f} K |",
        f"| PTC line in T5 | {line.angular_frequency_rad_s:.5f} +- {line.frequency_uncertainty_rad_s:.1e} rad/s, "
        f"{1e3 * line.fundamental.amplitude_K:.3f} mK, "
        f"phase {line.fundamental.phase_rad:.3f} rad at the first sample |",
        f"| measured noise | T2 {1e6 * analysis.noise_rms_K[0]:.2f} µK rms, T5 {1e6 * analysis.noise_rms_K[1]:.1f} µK rms |",
        f"| heater | limit {_number(data.heater_limit_w)} W; at 0 W {100 * at_zero:.1f} % of samples, "
        f"at the limit {100 * at_limit:.1f} % |",
    ]
    for note in data.notes:
        lines.append(f"| note | {note} |")
    lines += ["", "Segments:", "", "| kind | from (s) | to (s) | mean heater (mW) | setpoint (K) |", "|---|---|---|---|---|"]
    for segment in segments:
        setpoint = f"{segment.setpoint_K:.4f}" if math.isfinite(segment.setpoint_K) else "-"
        lines.append(f"| {segment.kind} | {segment.start_s:.1f} | {segment.stop_s:.1f} | "
                     f"{1e3 * segment.mean_heater_w:.3f} | {setpoint} |")
    lines += _base_model_off_section(analysis)
    lines += _recalibration_section(analysis)
    lines += _causes_section(analysis)
    lines += _left_section(analysis)
    listed = [d for d in discrepancies if d.significance >= LISTED_SIGNIFICANCE][:LISTED_MOST]
    lines += ["", "## What the base model gets wrong", "",
              f"Quantities whose model and measured values differ by {LISTED_SIGNIFICANCE:g} standard errors or more "
              f"({len(listed)} of {len(discrepancies)} computed; all are in the JSON output), most significant first:",
              ""]
    lines += _discrepancy_table(listed) if listed else ["None: the base model agrees with the record within the noise."]
    lines += ["", "## Candidates", "",
              f"Each cause fitted on the fit blocks (with the recalibration refitted alongside) and judged on the "
              f"held-out ones against the recalibrated model. A candidate counts from "
              f"{CANDIDATE_SIGMA:g} sigma and an improvement of {CANDIDATE_MINIMUM_IMPROVEMENT:g}; the record shows a "
              f"discrepancy when the base model's held-out excess is above {DISCREPANCY_SIGMA:g} sigma and "
              f"{100 * DISCREPANCY_FRACTION_OF_NOISE:g} % of the noise power; a cause is named when it removes "
              f"{100 * EXPLAINED_FRACTION:g} % of that excess or leaves none. Base model's held-out excess: "
              f"{decision.base.excess:.4g} over {decision.base.terms} terms ({decision.base.significance:.1f} sigma).",
              "",
              "| cause | fitted parameters | held-out improvement | significance (sigma) | explained | gain | note |",
              "|---|---|---|---|---|---|---|"]
    for cause, score in sorted(analysis.scores.items(), key=lambda item: -item[1].improvement):
        fit = analysis.fits[cause]
        mark = f"**{cause}**" if cause == analysis.cause else cause
        lines.append(f"| {mark} | {format_parameters(fit.parameters)} | {score.improvement:.4g} | "
                     f"{score.significance:.3g} | {100 * score.explained_fraction:.1f} % | {score.gain.ratio:.4g} | "
                     f"{fit.note} |")
    if analysis.extended:
        remaining = [d for d in extended_discrepancies if d.significance >= LISTED_SIGNIFICANCE][:10]
        lines += ["", "## What the extended model still gets wrong", ""]
        lines += _discrepancy_table(remaining) if remaining else ["Nothing above 3 standard errors."]
    lines += ["", "## Figures", ""]
    captions = {
        "overview": "T2 measured and replayed, residuals and heater (line averaged out; segments shaded)",
        "residual_spectrum": "spectra of the residuals, with the measured noise floor",
        "ptc_line": "the PTC line where the base model misses it most",
        "candidates": "held-out improvement of each candidate",
        "steps": "T2 after each heater step",
        "correlation": "T2 residual: autocorrelation and cross-correlation with the heater",
        "resid": "the extended model's T2 residual as MATLAB's resid shows it: autocorrelation and cross-correlation "
                 "with the heater (means over two line periods), 99 % bands",
    }
    for name, path in figures.items():
        lines += [f"![{captions[name]}]({path.name})", "", f"*{captions[name]}.*", ""]
    lines += ["## Timing", "", "| step | wall time (s) |", "|---|---|"]
    for step, seconds in analysis.timings_s.items():
        lines.append(f"| {step} | {seconds:.2f} |")
    path = Path(directory) / REPORT_NAME
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
