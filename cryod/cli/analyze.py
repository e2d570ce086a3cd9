"""``cryod analyze RECORD [--model MODEL] [--out DIR] [--json]``.

Writes into DIR (default ``<record name>-analysis`` beside the record;
an existing analysis there is kept unless ``--force``, and a file cryod did not
write there is never replaced: :mod:`cryod.output_files`): ``report.md``, the figures, ``extended-model.yaml`` (always
loadable by :func:`cryod.model.load_model`: the base model plus the fitted
effect, or the base model unchanged when the cause is ``none`` or
``unexplained``) and ``analysis.json`` (the same object ``--json`` prints).

Exit status: 0 done; 2 the record or the model cannot be used (the message
names the file, the line and what is wrong, or what the record is missing for
an analysis: :mod:`cryod.analysis.usability`); 1 the analysis itself failed.
The record is only read, never changed (nor the model), even with ``--force``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

from cryod.analysis.discrepancies import find_discrepancies
from cryod.analysis.model_uncertainty import model_uncertainty_check, report_section
from cryod.analysis.pipeline import analyze
from cryod.analysis.record_data import analysed_stretch, read_record_data
from cryod.analysis.record_window import ANALYSIS_WINDOW_S
from cryod.analysis.report import REPORT_NAME, ReportFiles, write_report
from cryod.analysis.segments import find_segments
from cryod.analysis.slow_series import in_file_form
from cryod.analysis.summary import json_summary, model_header
from cryod.analysis.usability import check_usable
from cryod.argument_types import not_negative
from cryod.cli.output_files import listed_when_written
from cryod.model import DEFAULT_MODEL_PATH, load_model, save_model
from cryod.output_files import OutputFiles
from cryod.records.record import RecordFormatError
from cryod.yaml_source import FileFormatError

PROGRAM = "cryod analyze"
EXTENDED_MODEL_NAME = "extended-model.yaml"
SUMMARY_NAME = "analysis.json"


def analysis_files(figures: bool = True) -> list[str]:
    """The files an analysis writes into its directory (with the figures' when ``figures``)."""
    names = [SUMMARY_NAME, REPORT_NAME, EXTENDED_MODEL_NAME]
    if figures:
        from cryod.analysis.figures import FIGURE_FILES  # matplotlib only when figures are wanted

        names += FIGURE_FILES.values()
    return names


def configure_parser(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Arguments of ``cryod analyze``."""
    parser.description = ("Replay a measured record (cryod-log v1) through the model, show what the simulation "
                          "gets wrong, name the cause, write the extended model and measure its gain on held-out "
                          "data.")
    parser.add_argument("record", help="the record to analyse (cryod-log v1 CSV)")
    parser.add_argument("--model", default=str(DEFAULT_MODEL_PATH),
                        help="base model file (default: the shipped model)")
    parser.add_argument("--out", default=None,
                        help="directory for the report, figures and extended model (default: <record>-analysis "
                             "beside the record)")
    parser.add_argument("--force", action="store_true", help="replace an earlier analysis in that directory")
    parser.add_argument("--json", action="store_true", help="print the result as one JSON object on stdout")
    parser.add_argument("--no-figures", action="store_true", help="skip the figures (faster)")
    parser.add_argument("--max-duration", type=not_negative, default=ANALYSIS_WINDOW_S, metavar="S",
                        help=f"a longer record is analysed on the stretch of S seconds where the heater moves most "
                             f"(default {ANALYSIS_WINDOW_S:.0f}); 0: the whole record")
    return parser


def run(args: argparse.Namespace) -> int:
    """Run the analysis; returns the exit status."""
    started = time.perf_counter()
    record_path = Path(args.record)
    try:
        whole = read_record_data(record_path)
        model = load_model(args.model)
        check_usable(whole)
    except (RecordFormatError, FileFormatError) as error:
        print(f"cryod analyze: {error}", file=sys.stderr)
        return 2
    name = record_path.name.removesuffix(".gz").removesuffix(".csv")
    out = Path(args.out) if args.out else record_path.with_name(f"{name}-analysis")
    outputs = OutputFiles(PROGRAM, out, analysis_files(figures=not args.no_figures),
                          inputs=[record_path, Path(args.model)], what="analysis")
    refusal = outputs.refusal(force=getattr(args, "force", False))
    if refusal is not None:
        print(f"{PROGRAM}: {refusal} (--out: another directory)", file=sys.stderr)
        return 2
    data = analysed_stretch(whole, getattr(args, "max_duration", ANALYSIS_WINDOW_S))
    if data is not whole:
        print(f"cryod analyze: {record_path}: {data.notes[-1]} (--max-duration 0: the whole record)",
              file=sys.stderr)
    del whole
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        print(f"cryod analyze: cannot create the output directory {out}: {error}", file=sys.stderr)
        return 2
    try:
        with listed_when_written(outputs):
            summary = analyse_and_write(data, model, record_path, Path(args.model), out,
                                        figures=not args.no_figures, started=started)
    except (ValueError, ArithmeticError, OSError) as error:
        print(f"cryod analyze: the analysis of {record_path} failed: {error}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(summary))
    else:
        gain = summary["gain"]
        print(f"cause: {summary['cause']}")
        print(f"gain: {gain['ratio']:.4g} ({gain['metric']})")
        print(f"extended model: {summary['extended_model']}")
        print(f"report: {out / 'report.md'}")
    return 0


def analyse_and_write(data, model, record_path: Path, model_path: Path, out: Path, *, figures: bool = True,
                      started: float | None = None) -> dict:
    """Analyse and write everything into ``out``; returns the JSON summary."""
    started = time.perf_counter() if started is None else started
    analysis = analyze(data, model)
    moment = time.perf_counter()
    segments = find_segments(data.time_s, data.heater_w, data.setpoint_K)
    frequency = analysis.base_line.angular_frequency_rad_s
    discrepancies = find_discrepancies(data, model, analysis.base_replay, analysis.noise_rms_K, frequency, segments)
    extended = []
    if analysis.extended:
        extended = find_discrepancies(data, analysis.extended_model, analysis.extended_replay, analysis.noise_rms_K,
                                      frequency, segments)
    analysis.timings_s["discrepancies"] = time.perf_counter() - moment
    model_path_out = out / EXTENDED_MODEL_NAME
    extended_model = in_file_form(analysis.extended_model)
    if analysis.extended:
        base_name = model.name or "model"
        added = [named.cause for named in analysis.causes] if analysis.cause not in ("none", "unexplained") else []
        added += ([f"generic {' + '.join(analysis.generic.used)}"]
                  if analysis.generic is not None and analysis.generic.added else [])
        what = " + ".join((["recalibrated"] if analysis.recalibrated else []) + added)
        extended_model = dataclasses.replace(
            extended_model, name=f"{base_name} + {what}",
            description=f"{model.description} Extended by cryod analyze ({what}) fitted to "
                        f"{record_path.name}.".strip())
    save_model(extended_model, model_path_out, header=model_header(analysis, record_path, model_path))
    made = {}
    if figures:
        moment = time.perf_counter()
        from cryod.analysis.figures import make_figures  # matplotlib only when figures are wanted
        made = make_figures(analysis, segments, out)
        analysis.timings_s["figures"] = time.perf_counter() - moment
    analysis.timings_s["total"] = time.perf_counter() - started
    report_path = write_report(analysis, discrepancies, extended, segments, ReportFiles(out, model_path_out, made))
    summary = json_summary(analysis, discrepancies, model_path_out)
    check = model_uncertainty_check(analysis)      # only for a model that states its uncertainty
    if check is not None:
        summary["model_uncertainty"] = check
        with Path(report_path).open("a", encoding="utf-8") as report:
            report.write(report_section(check))
    (out / SUMMARY_NAME).write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    return summary
