"""The reference tables the code holds, as markdown: the docs site puts each one where a page asks for it.

A page asks with a marker line, ``<!-- cryod-table NAME -->``; :func:`expand` replaces every marker with
:data:`TABLES`'s table of that name (an unknown name is an error, so the build fails). The tables come from
the code's own declarations, so they cannot fall behind it:

==================  ====================================================================================
name                from
==================  ====================================================================================
commands            ``cryod.service.commands.COMMANDS`` (what ``cryod ctl --help`` lists)
status-keys         ``cryod.service.daemon_status.status_json`` of a full status, the control terms'
                    columns (``cryod.control.terms``)
summary-keys        ``cryod.service.simulation.simulate``: a 30 s dry run's ``--json`` summary
record-columns      ``cryod.records.columns`` and each control term's ``columns``
causes              ``cryod.analysis.summary.CAUSES``, each effect's class in ``cryod.model.parameters``
fault-causes        ``cryod.service.faults.FaultCause``
exit-codes          ``cryod.service.faults.ExitCode``
pvs                 ``cryod.ioc.pv_table``
metrics             ``cryod.interfaces.metrics.CryodCollector``, scraped once on a made-up view
lakeshore336        ``cryod.service.lakeshore336.SUPPORTED`` (the names; the docs page says what each does)
cli-help            ``cryod.cli.build_parser`` and each model tool's ``configure_parser``
example-config      ``config/cryod.yaml``, as shipped
==================  ====================================================================================

The words around a marker are the page's own: what a table cannot say (what to do about a fault, how a
key is read) is written there.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import inspect
import math
import os
import re
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parent.parent
MARKER = re.compile(r"^<!-- cryod-table ([\w-]+) -->$", re.M)


def _cell(text: object) -> str:
    """Text for one table cell: one line, pipes escaped."""
    return " ".join(str(text).split()).replace("|", "\\|")


def _table(header: tuple[str, ...], rows) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_cell(cell) for cell in row) + " |" for row in rows]
    return "\n".join(lines)


def _first_paragraph(thing) -> str:
    """The first paragraph of a docstring, on one line."""
    doc = inspect.getdoc(thing) or ""
    return " ".join(doc.split("\n\n")[0].split()).replace("``", "`")


# -- the control socket's commands ------------------------------------------------------------------
def commands() -> str:
    from cryod.service.commands import COMMANDS

    return _table(("command", "what it does"), ((f"`{spec.usage}`", spec.help)
                                                for spec in COMMANDS.values() if spec.from_socket))


# -- the status ---------------------------------------------------------------------------------------
#: What each key of the status means; a key the code gives that has no line here fails the build.
STATUS_MEANINGS = {
    "time_s": "the daemon's clock at the tick's readings (s; a monotonic clock, not a date: `cryod ctl status` "
              "shows it as `daemon_clock_s`)",
    "state": "the loop's state: `holding` (heater off until readings are valid), `closed`, `closed-limited` "
             "(regulating with the heater held at a bound), `manual`, `off`, `recovering`, `stopped`; `waiting` "
             "before the loop runs (then `message` says what it waits for)",
    "T2_K": "flange temperature, the control thermometer (K)",
    "T5_K": "the cooler's second stage (K)",
    "heater_W": "the heater power the supply was told (W); null: unknown (the supply could not be switched off)",
    "setpoint_K": "the setpoint in use, where a ramp has got to (K); null while the loop is open",
    "target_K": "the setpoint asked for (K)",
    "ramp_K_per_min": "the setpoint ramp rate (0: steps)",
    "last_target_K": "the last target given, kept while the loop is open: what regulating again heads for",
    "last_fault": "the last fault, `cause: message` (null: none since the start)",
    "zone": "the zone of `control.zones` in use, counted from 1 (only with zones)",
    "zone_upper_K": "that zone's upper temperature (K; only with zones)",
    "ticks": "loop ticks since the start",
    "overruns": "ticks that ended after the next one's deadline",
    "missed_deadlines": "deadlines skipped by overruns",
    "late_cycles_waiting_for_instruments": "cycles that ended late while the heater was off waiting for valid "
                                           "readings (not overruns)",
    "lateness_ms_p50": "median lateness of a tick's start after its deadline (ms)",
    "lateness_ms_p99": "99th percentile of the lateness (ms)",
    "lateness_ms_max": "largest lateness (ms)",
    "gc_ms_max": "longest garbage collection (ms)",
    "record_path": "absolute path of the record being written",
    "setpoint_warning": "why the heater cannot hold the setpoint asked for, with the numbers (null: it can)",
    "alarms": "the alarms raised or latched, each `{name, state, acknowledged, since_s, value, message, "
              "raised_message}`",
    "alarm_states": "1.0 for each alarm raised or latched, 0.0 for the others that are on",
    "interfaces": "the interfaces process (web page, 336, metrics, alarm hook): running, where it serves, its "
                  "problems; null when none is configured",
    "T2_average_K": "T2 averaged over the last 10 s (17 cooler periods)",
    "line_amplitude_K": "the cooler line on T2: harmonics 1 to 6 of the cooler's frequency together (K)",
    "heater_mean_W": "the heater's level: its power over the last whole cooler cycles (W)",
    "message": "while `waiting`: what the daemon waits for",
}


def _term_columns():
    from cryod.control.terms import TERM_TYPES, term_type

    return tuple(column for name in TERM_TYPES for column in term_type(name).columns)


def status_keys() -> str:
    from cryod.service.daemon_status import DaemonStatus, LoopStatus, RecentFigures, status_json

    control = {column.name: 0.0 for column in _term_columns()}
    full = DaemonStatus(loop=LoopStatus(time_s=1.0, state="closed", flange_K=5.0, ptc_stage_K=3.4, heater_w=0.1,
                                        setpoint_K=5.0, target_K=5.0, control=control, zone=1, zone_upper_K=8.0),
                        record_path="/x.csv", interfaces={}, recent=RecentFigures(5.0, 1e-4, 0.1))
    keys = list(status_json(full)) + ["message"]
    described = {column.name: f"{column.description} ({column.unit})" if column.unit else column.description
                 for column in _term_columns()}
    missing = [key for key in keys if key not in STATUS_MEANINGS and key not in described]
    if missing:
        raise KeyError(f"status keys without a meaning in docs_tools/reference_tables.py: {missing}")
    return _table(("key", "meaning"), ((f"`{key}`", STATUS_MEANINGS.get(key) or
                                        f"control term's column: {described[key]}") for key in keys))


# -- the dry run's summary --------------------------------------------------------------------------
#: What each key of ``cryod --simulate --json`` means; a key the code gives that has no line here fails the build.
SUMMARY_MEANINGS = {
    "duration_s": "simulated time run: ticks times the loop period (s)",
    "ticks": "loop ticks",
    "overruns": "ticks that ended after the next one's deadline",
    "missed_deadlines": "deadlines skipped by overruns (real time only): the record spans that many periods more",
    "lateness_ms_p50": "median lateness of a tick's start after its deadline (ms)",
    "lateness_ms_p99": "99th percentile of the lateness (ms)",
    "lateness_ms_max": "largest lateness (ms)",
    "gc_ms_max": "longest garbage collection (ms)",
    "wall_s": "real time the run took (s)",
    "cpu_s": "CPU time the run took (s)",
    "cpu_percent_of_one_core": "CPU time over real time, in % of one core",
    "window_s": "the metrics window at the end of the run (`--window`, s)",
    "ptc_line_amplitude_K": "the cooler's fundamental alone on T2, over the window (K)",
    "ptc_line_rad_s": "the cooler's angular frequency tracked on T5 (rad/s)",
    "ptc_periodic_amplitude_K": "the cooler line on T2: harmonics 1 to 6 together, √2 × the rms of T2's periodic "
                                "part, over the window (K)",
    "ptc_harmonic_amplitudes_K": "each harmonic's amplitude on T2, 1 to 6 (K)",
    "rms_K": "rms of T2 minus the setpoint over the window (K)",
    "mean_error_K": "mean of T2 minus the setpoint over the window (K)",
    "lowfreq_rms_K": "rms of T2's error below the cooler's frequency, the line removed (K)",
    "setpoint_K": "the setpoint at the end (K)",
    "state": "the loop's state at the end",
    "zone": "the zone in use at the end (null without `control.zones`)",
    "last_fault": "the last fault, `cause: message` (null: none)",
    "setpoint_warning": "why the heater cannot hold the setpoint (null: it can)",
    "exit_code": "the daemon's [exit code](exit-codes.md)",
    "log_path": "the first record written",
    "record_path": "the last record written",
    "log_paths": "every record written, in order",
    "achieved_speed": "simulated seconds per real second over the run",
    "ptc_periodic_limit_K": "the physical limit: the least line any heater waveform can leave at this setpoint, for "
                            "the simulated cryostat, the heater and the loop's timing (K)",
    "feedforward_authority": "the largest fundamental the heater can give over the one the line needs",
    "feedforward_limited_by": "what limits the limit, in words",
    "feedforward_limit_bound": "what binds the best waveform: `floor`, `top`, `floor and top` or `none`",
    "feedforward_limit_explained": "the same in words, with the figures",
    "feedforward_limit_changes": "the limit if the setpoint moved 0.5 K either way or R·I_max² doubled: a list of "
                                 "`change`, `ptc_periodic_limit_K`, `limited_by`, `problem`",
    "feedforward_plant": "the plant the feedforward learned, per harmonic: `learned`, `gain_ratio` and `phase_deg` "
                         "against the model with their spreads, the plant and the model's in K/W",
    "feedforward_plant_differences": "how the learned plant differs from the model, in words",
    "feedforward_reported_limit_K": "the limit the feedforward reported at the end (K)",
    "feedforward_reported_authority": "its authority",
    "feedforward_limit_from": "what that limit was computed from: `model` or `learned`",
    "feedforward_probe_K": "T2's answer to the probe at the end (K; null: off)",
    "feedforward_divergences": "divergences the feedforward detected and undid",
    "feedforward_setting_delay_s": "the delay from a reading to the heater setting it caused, as learned (s)",
    "trigger": "how the two DMMs were triggered",
}


def summary_keys() -> str:
    import io
    import tempfile

    from cryod.service.simulation import simulate

    with tempfile.TemporaryDirectory() as folder:
        run = simulate(30.0, data_dir=Path(folder), socket=Path(folder) / "s.sock", window_s=10.0,
                       log_stream=io.StringIO())
    keys = list(run.summary)
    missing = [key for key in keys if key not in SUMMARY_MEANINGS]
    if missing:
        raise KeyError(f"dry-run summary keys without a meaning in docs_tools/reference_tables.py: {missing}")
    return _table(("key", "meaning"), ((f"`{key}`", SUMMARY_MEANINGS[key]) for key in keys))


# -- the record's columns -----------------------------------------------------------------------------
def record_columns() -> str:
    from cryod.records.columns import LOOP_END, LOOP_MEASUREMENT, REQUIRED

    rows = []
    for group, columns in (("contract: every record", REQUIRED), ("the loop", LOOP_MEASUREMENT),
                           ("control terms", _term_columns()), ("the loop", LOOP_END)):
        rows += [(f"`{column.name}`", column.unit, column.description, group) for column in columns]
    return _table(("column", "unit", "meaning", "written by"), rows)


# -- cryod analyze's causes ---------------------------------------------------------------------------
#: The verdicts that are no effect of the model.
VERDICTS = {
    "none": "the base model, recalibrated within its tolerance, agrees with the record within the noise",
    "unexplained": "no cause of the catalogue explains the discrepancy; the report describes what is left, and "
                   "the extended model carries a generic, data-driven extension",
    "base_model_off": "the record asks the base model's own parameters to move beyond the recalibration's "
                      "tolerance: identify the cryostat (`cryod identify`) and analyse again with that model",
}


def causes() -> str:
    from cryod.analysis.summary import CAUSES
    from cryod.model.parameters import Effects

    hints = {field.name: field.type for field in dataclasses.fields(Effects)}
    module = importlib.import_module("cryod.model.parameters")
    rows = []
    for cause in CAUSES:
        if cause in VERDICTS:
            rows.append((f"`{cause}`", "verdict", VERDICTS[cause]))
            continue
        if cause == "ptc_harmonics":
            rows.append((f"`{cause}`", "cause", _first_paragraph(module.CoolerHarmonic) +
                         " Named when T5's oscillation has harmonics the model lacks."))
            continue
        class_name = str(hints[cause]).split("|")[0].strip()
        rows.append((f"`{cause}`", "cause", _first_paragraph(getattr(module, class_name))))
    return _table(("name", "kind", "meaning"), rows)


# -- faults and exit codes ----------------------------------------------------------------------------
def fault_causes() -> str:
    from cryod.service.faults import FaultCause

    return _table(("cause", "recovers", "reconnects", "exit code when it ends the run"),
                  ((f"`{cause}`", "yes" if cause.recoverable else "no", "yes" if cause.reconnect else "no",
                    "128 + the signal's number" if cause is FaultCause.SIGNAL else int(cause.exit_code))
                   for cause in FaultCause))


EXIT_MEANINGS = {
    "OK": "done; a requested stop (SIGTERM, SIGINT)",
    "EXCEPTION": "an exception nobody caught (a bug): the traceback is in the journal",
    "CONFIG": "unusable input: a configuration this computer cannot run, a bad command line, a wrong instrument "
              "at an address (`identity_mismatch`), a second daemon on the same instruments. Not restarted",
    "OVER_TEMPERATURE": "T2 or T5 above its limit (`safety.flange_max_K`, `safety.ptc_stage_max_K`)",
    "INSTRUMENTS_LOST": "a transient fault not cleared within `safety.recovery_timeout_s`, or instruments out of "
                        "reach beyond `safety.instruments_wait_s`",
    "READINGS_TOO_OLD": "readings too old to set the heater from, again and again (`safety.max_reading_age_s`)",
    "HEATER_FAULT": "the heater supply refused, hit its compliance, or its output went off",
    "DATA_LOG_FAILED": "the record could not be written (disk full, below `data.min_free_MB`, directory gone). "
                       "Not restarted",
}


def exit_codes() -> str:
    from cryod.service.faults import ExitCode, FaultCause

    rows = []
    for code in ExitCode:
        causes = ", ".join(f"`{cause}`" for cause in FaultCause if cause.exit_code is code
                           and cause is not FaultCause.SIGNAL)
        rows.append((int(code), EXIT_MEANINGS[code.name], causes))
    rows.append(("128 + N", "ended by signal N (134: SIGABRT, systemd's watchdog)", "`signal`"))
    return _table(("exit", "meaning", "fault causes"), rows)


# -- EPICS ----------------------------------------------------------------------------------------------
def pvs() -> str:
    from cryod.ioc.pv_table import READINGS, SETTINGS

    rows = []
    for pv in READINGS + SETTINGS:
        meaning = ("**writable**: " if pv.writable else "") + pv.meaning
        if pv.choices:
            meaning += " (" + ", ".join(f"{index} {label}" if pv.record in ("bi", "bo") else label
                                        for index, label in enumerate(pv.choices)) + ")"
        if pv.per_row:
            meaning += "; every row, stamped with its sample instant"
        rows.append((f"`{pv.name}`", pv.record, pv.unit, meaning))
    return _table(("PV", "record", "unit", "meaning"), rows)


# -- Prometheus -----------------------------------------------------------------------------------------
class _View:
    """A live view with every figure, for one scrape."""

    def snapshot(self):
        return dict(T2_K=5.0, T5_K=3.4, setpoint_K=5.0, error_K=0.0, heater_W=0.1, heater_mean_W=0.1,
                    line_amplitude_K=1e-4, line_limit_K=1e-4, pi_W=0.1, ff_W=0.0, lateness_ms=0.1, ticks=1,
                    overruns=0, faults={}, state="closed")


def metrics() -> str:
    from cryod.interfaces.metrics import CryodCollector

    rows = []
    for family in CryodCollector(_View(), "A", alarms=lambda: {"deviation": 0.0}).collect():
        name = family.name + ("_total" if family.type == "counter" else "")
        labels = sorted({key for sample in family.samples for key in sample.labels})
        rows.append((f"`{name}`" + (f"{{{','.join(labels)}}}" if labels else ""), family.type, family.documentation))
    return _table(("metric", "type", "meaning"), rows)


# -- the Lake Shore 336 command set --------------------------------------------------------------------
def lakeshore336() -> str:
    from cryod.service.lakeshore336 import SUPPORTED

    return ", ".join(f"`{name}`" for name in SUPPORTED)


# -- the command line ------------------------------------------------------------------------------------
def _help(parser: argparse.ArgumentParser) -> str:
    return parser.format_help().rstrip()


def cli_help() -> str:
    from cryod.cli import MODEL_TOOLS, build_parser

    os.environ["COLUMNS"] = "110"                     # argparse wraps at the terminal's width
    parser = build_parser()
    parts = [("cryod", _help(parser))]
    subparsers = next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction))
    for name in ("run", "ctl", "ioc", "init"):
        parts.append((f"cryod {name}", _help(subparsers.choices[name])))
    for name, module_name, _ in MODEL_TOOLS:
        module = importlib.import_module(module_name)
        parts.append((f"cryod {name}", _help(module.configure_parser(argparse.ArgumentParser(prog=f"cryod {name}")))))
    return "\n\n".join(f"### `{title}`\n\n```text\n{text}\n```" for title, text in parts)


def example_config() -> str:
    return "```yaml\n" + (REPOSITORY / "config" / "cryod.yaml").read_text(encoding="utf-8").rstrip() + "\n```"


TABLES = {
    "commands": commands,
    "status-keys": status_keys,
    "summary-keys": summary_keys,
    "record-columns": record_columns,
    "causes": causes,
    "fault-causes": fault_causes,
    "exit-codes": exit_codes,
    "pvs": pvs,
    "metrics": metrics,
    "lakeshore336": lakeshore336,
    "cli-help": cli_help,
    "example-config": example_config,
}


def expand(markdown: str) -> str:
    """The page with every marker replaced by its table."""
    def table(match: re.Match) -> str:
        name = match.group(1)
        if name not in TABLES:
            raise KeyError(f"no reference table {name!r}: one of {', '.join(TABLES)}")
        return TABLES[name]()
    return MARKER.sub(table, markdown)


__all__ = ["TABLES", "expand", "math"]
