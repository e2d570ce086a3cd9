"""Hostile configurations against the real ``cryod run``, and reloads in every state (slow suite).

Run: ``.venv/bin/python -m pytest -m slow tests/test_adversarial_config.py -s`` (the figures are
printed at the end; benchmarks/results/adversarial_config.md, "Adversarial configuration run", quotes them).

Configurations are generated per category from the example configuration, its instruments on a
simulated bench served over TCP on 127.0.0.1 (pyvisa-py, as the lab's LAN gateways): numbers in
forms YAML versions read differently, VISA resources and GPIB addresses, Prologix controllers,
the control socket (path length, owner, group, folder), the VISA library, files that are not
files, limits and ramps. Each goes through ``cryod run --check``; one it refuses must name the
file, the line and the key, and ``cryod run`` must refuse it alike, before starting anything. One
it passes is started as a process, ``cryod run --duration 2``: it must run, or wait for
instruments it cannot reach (an outage, which it rides out), and never fail on its configuration
(exit 1 or 2, a traceback, a message without its key).

Then sequences of setpoints, ramps, heater-off, manual power, sensor faults and reloads with
other limits drive the daemon in process on virtual time through all its states: a refused reload
names file, line and key and keeps the running configuration; an accepted one leaves the setpoint
aimed at within its limits; the setpoint in use never reaches the over-temperature limit in force.
"""

from __future__ import annotations

import collections
import contextlib
import io
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cryod.cli import main
from cryod.config import SOCKET_PATH_MAX_BYTES
from cryod.control.regulator import RegulatorMode
from tests.conftest import CONFIG, REPOSITORY
from tests.service_bench import BenchOverTcp
from tests.example_config import EXAMPLE
from tests.reload_drills import ReloadDrill

pytestmark = pytest.mark.slow

#: What happened to each configuration, per category: printed at the end of the module.
OUTCOMES: collections.Counter = collections.Counter()


@pytest.fixture(scope="module", autouse=True)
def figures():
    """The figures of this module's run, printed (with -s) once its tests are done, whichever of them ran."""
    yield
    categories = collections.defaultdict(collections.Counter)
    for (category, outcome), count in OUTCOMES.items():
        categories[category][outcome] += count
    lines = []
    for category, counts in categories.items():
        total = sum(counts.values())
        lines.append(f"{category}: {total}: " + "; ".join(f"{outcome} {count}" for outcome, count in counts.items()))
    print("\n" + "\n".join(lines))
#: Seconds a started daemon is given to run or to say it waits for its instruments.
WAIT_S = 30.0
RUNS = settings(max_examples=25, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@pytest.fixture(scope="module")
def bench():
    """The simulated instruments on 127.0.0.1 ports; the resource names of each."""
    with BenchOverTcp() as served:
        yield served.resources


class Cases:
    """A fresh folder for each configuration tried."""

    def __init__(self, root: Path):
        self.root = root
        self.count = 0

    def folder(self) -> Path:
        self.count += 1
        folder = self.root / f"c{self.count}"
        folder.mkdir()
        return folder


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    return Cases(tmp_path_factory.mktemp("hostile"))


def base_text(bench: dict, folder: Path) -> str:
    """The example on the simulated bench, its data and socket in ``folder``."""
    text = EXAMPLE.replace("calibration: calibration/", f"calibration: {CONFIG}/calibration/")
    for gpib, key in (("GPIB0::16::INSTR", "flange_dmm"), ("GPIB0::17::INSTR", "ptc_stage_dmm"),
                      ("GPIB0::12::INSTR", "heater_supply")):
        text = text.replace(gpib, bench[key])
    return (text.replace("trigger: gpib-group", "trigger: sequential")
            .replace("  timeout_s: 1.0 ", f"  lock_directory: {folder.parent / 'locks'}\n  timeout_s: 1.0 ")
            .replace("/var/lib/cryod", str(folder / "data"))
            .replace("/run/cryod/control.sock", str(folder / "run" / "control.sock")))


def located(error: str, path: Path, key: str | None) -> bool:
    """``error`` names ``path``, a line and ``key`` (or a key inside it); any key for ``key=""``; for
    ``key=None`` (a file that is not a configuration) the file alone."""
    match = re.search(re.escape(str(path)) + r":(\d+): ([\w.\[\]-]+): ", error)
    if match is None:
        return key is None and re.search(re.escape(str(path)) + r"(:\d+)?: ", error) is not None
    return not key or match.group(2) == key or match.group(2).startswith(key + ".")


def in_process(arguments: list[str]) -> tuple[int, str]:
    stderr, stdout = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(stdout):
        code = main(arguments)
    return code, stderr.getvalue()


def cryod_run(path: Path, folder: Path) -> tuple[str, int, str]:
    """``cryod run`` as a process for 2 s, or stopped with SIGTERM once it says it waits for its instruments."""
    process = subprocess.Popen([sys.executable, "-m", "cryod.cli", "run", "--config", str(path), "--duration", "2"],
                               cwd=folder, env=dict(os.environ, PYTHONPATH=str(REPOSITORY)),
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(process.stderr), daemon=True)
    reader.start()
    how, deadline = "ran", time.monotonic() + WAIT_S
    while process.poll() is None:
        if any("out of reach" in line for line in list(lines)) or time.monotonic() > deadline:
            how = "waited"
            process.send_signal(signal.SIGTERM)
            break
        time.sleep(0.05)
    process.wait(timeout=30)
    reader.join(10)
    return how, process.returncode, "".join(lines)


def try_config(category: str, path: Path, key: str | None) -> str:
    """Check ``path`` as cryod run would, then run it if the check passed; the outcome, counted."""
    started = time.monotonic()
    code, error = in_process(["run", "--config", str(path), "--check"])
    assert time.monotonic() - started < 20, f"--check took {time.monotonic() - started:.0f} s on {path}"
    if code != 0:
        assert code == 2 and "Traceback" not in error, error
        assert located(error, path, key), f"{category}: not at {path}:line: {key}: {error}"
        run_code, run_error = in_process(["run", "--config", str(path), "--duration", "1"])
        assert (run_code, run_error) == (code, error), "cryod run and --check disagree"
        outcome = "refused at --check, and by cryod run alike"
    else:
        how, run_code, run_error = cryod_run(path, path.parent)
        assert "Traceback" not in run_error, run_error[-3000:]
        assert run_code == 0, f"{category}: --check passed, cryod run exited {run_code}:\n{run_error[-3000:]}"
        outcome = "ran" if how == "ran" else "waited for instruments out of reach, stopped by SIGTERM"
        assert how == "ran" or "out of reach" in run_error, f"{category}: neither ran nor waited:\n{run_error[-3000:]}"
    OUTCOMES[(category, outcome)] += 1
    return outcome


def written_case(cases: Cases, bench: dict, replacements) -> Path:
    """A new folder with the example on the bench, ``replacements`` made (``{folder}`` is the folder; a
    callable gets the folder and gives the replacements)."""
    folder = cases.folder()
    text = base_text(bench, folder)
    for old, new in (replacements(folder) if callable(replacements) else replacements):
        old = old.replace("{folder}", str(folder))
        assert old in text, old
        text = text.replace(old, new.replace("{folder}", str(folder)), 1)
    path = folder / "cryod.yaml"
    path.write_text(text)
    return path


# ---------------------------------------------------------------------------
# numbers
# ---------------------------------------------------------------------------
NUMBER_LINES = [line for line in EXAMPLE.splitlines()
                if re.match(r"^ *[a-zA-Z_]+: *-?[0-9][0-9.e-]*( |$)", line) and "format" not in line]
YAML_1_1_FORMS = ["010", "0777", "-010", "09", "1_0", "1_000.5", "1:30", "0x1F", "0o17", "0b11", "+0_1"]


def number_key(line: str) -> str:
    """The dotted key of a number line of the example."""
    lines = EXAMPLE.splitlines()
    index = lines.index(line)
    depth = len(line) - len(line.lstrip())
    names = [line.strip().split(":")[0]]
    for previous in reversed(lines[:index]):
        indent = len(previous) - len(previous.lstrip())
        if previous.strip() and not previous.lstrip().startswith("#") and indent < depth:
            names.insert(0, previous.strip().split(":")[0])
            depth = indent
            if indent == 0:
                break
    return ".".join(names)


@RUNS
@given(line=st.sampled_from(NUMBER_LINES), form=st.sampled_from(YAML_1_1_FORMS))
def test_numbers_in_forms_yaml_versions_read_differently(bench, cases, line, form):
    key, _, rest = line.partition(":")
    comment = "  #" + rest.split("#", 1)[1] if "#" in rest else ""
    path = written_case(cases, bench, [(line, f"{key}: {form}{comment}")])
    assert try_config("numbers in YAML 1.1 forms", path, number_key(line)).startswith("refused")


# ---------------------------------------------------------------------------
# instruments
# ---------------------------------------------------------------------------
INTERFACES = st.sampled_from(["GPIB", "GPIB0", "GPIB1", "gpib", "TCPIP0", "TCPIP", "ASRL", "USB0", "VXI0",
                              "PRLGX-TCPIP0", "GPIB-1", "", "TCPIP0::127.0.0.1"])
PARTS = st.one_of(st.integers(-2, 70).map(str), st.sampled_from(["127.0.0.1", "localhost", "abc", "", "16:INSTR",
                                                                  "/dev/ttyS0", "0x1234", "inst0", "1234"]))
CLASSES = st.sampled_from(["INSTR", "SOCKET", "INTFC", "instr", "", "BACKPLANE", "RAW"])
SEPARATORS = st.sampled_from(["::", "::", "::", ":", ":::"])
RESOURCES = st.one_of(
    st.builds(lambda interface, parts, separator, cls: separator.join([interface, *parts, cls]).rstrip(":"),
              INTERFACES, st.lists(PARTS, min_size=0, max_size=3), SEPARATORS, CLASSES),
    st.text(max_size=30),
)
INSTRUMENTS = ["flange_dmm", "ptc_stage_dmm", "heater_supply"]


@RUNS
@given(instrument=st.sampled_from(INSTRUMENTS), resource=RESOURCES)
def test_resources(bench, cases, instrument, resource):
    path = written_case(cases, bench, [(f"resource: {bench[instrument]}", f"resource: {json.dumps(resource)}")])
    try_config("VISA resources", path, f"instruments.{instrument}")


@RUNS
@given(first=st.sampled_from(INSTRUMENTS), second=st.sampled_from(INSTRUMENTS),
       trigger=st.sampled_from(["sequential", "gpib-group", "prologix", "external"]))
def test_shared_addresses_and_triggers(bench, cases, first, second, trigger):
    replacements = [("trigger: sequential", f"trigger: {trigger}")]
    if first != second:
        replacements.append((f"resource: {bench[second]}", f"resource: {bench[first]}"))
    path = written_case(cases, bench, replacements)
    try_config("shared addresses and trigger modes", path, "instruments")


PROLOGIX_PORTS = st.sampled_from(["/dev/null", "/dev/ttyUSB-cryod-none", "{folder}", "{folder}/cryod.yaml",
                                  "/dev/zero", "COM3", "", " "])
PROLOGIX_HOSTS = st.sampled_from(["127.0.0.1", "256.1.1.1", "", "cryod-no-such-host.invalid", "::1"])


@RUNS
@given(instrument=st.sampled_from(INSTRUMENTS), by_port=st.booleans(), port=PROLOGIX_PORTS, host=PROLOGIX_HOSTS,
       address=st.integers(-1, 31))
def test_prologix_controllers(bench, cases, instrument, by_port, port, host, address):
    where = f'port: "{port}"' if by_port else f'host: "{host}"'
    path = written_case(cases, bench, [(f"resource: {bench[instrument]}",
                                        f"prologix: {{{where}, address: {address}}}")])
    try_config("Prologix controllers", path, f"instruments.{instrument}")


@RUNS
@given(library=st.one_of(st.sampled_from(["@py", "", "@ivi", "@sim", "garbage", "/cryod/none/libvisa.so",
                                          "@py@py", "@", "libc.so.6"]), st.text(max_size=12)))
def test_visa_libraries(bench, cases, library):
    path = written_case(cases, bench, [('visa_library: "@py"', f"visa_library: {json.dumps(library)}")])
    try_config("VISA libraries", path, "instruments.visa_library")


# ---------------------------------------------------------------------------
# the control socket
# ---------------------------------------------------------------------------
@RUNS
@given(extra=st.integers(-12, 12), owner=st.sampled_from([None, "root", "nobody", "cryod-no-such-user", "0"]),
       group=st.sampled_from([None, "root", "nogroup", "cryod-no-such-group", "daemon"]),
       place=st.sampled_from(["folder", "missing folder", "in a file", "/proc", "a file there", "a folder there"]))
def test_control_sockets(bench, cases, extra, owner, group, place):
    def replacements(folder):
        if place == "in a file":
            (folder / "f").write_text("a file")
        elif place == "a file there":
            (folder / "s").write_text("a file")
        elif place == "a folder there":
            (folder / "s").mkdir()
        if place in ("a file there", "a folder there"):
            socket_path = folder / "s"
        else:
            base = {"folder": folder / "run", "missing folder": folder / "new" / "deeper",
                    "in a file": folder / "f", "/proc": Path("/proc/cryod-adversarial")}[place]
            length = SOCKET_PATH_MAX_BYTES + extra - len(os.fsencode(str(base))) - 1
            socket_path = base / ("s" * max(1, length))
        changes = [("path: {folder}/run/control.sock", f"path: {socket_path}")]
        if owner is not None:
            changes.append(("# owner: cryod", f"owner: {owner}"))
        if group is not None:
            changes.append(("# group: cryod", f"group: {group}"))
        return changes
    path = written_case(cases, bench, replacements)
    try_config("control sockets", path, "control_socket")


# ---------------------------------------------------------------------------
# limits, ramps and files
# ---------------------------------------------------------------------------
LIMIT_LINES = ["  setpoint_K: 5.0", "  ramp_K_per_min: 0.0", "  setpoint_min_K: 3.0", "  setpoint_max_K: 20.0",
               "  max_ramp_K_per_min: 10.0", "  flange_max_K: 25.0", "  ptc_stage_max_K: 15.0"]
LIMIT_VALUES = st.one_of(st.sampled_from(["1e-320", "1e-7", "1e-6", "0", "-0", "1e308", "5e-324", "0.0001",
                                          "null", "4.2", "19.999999999999996", "25", "100.0000001"]),
                         st.floats(min_value=-1.0, max_value=400.0).map(repr))


@RUNS
@given(line=st.sampled_from(LIMIT_LINES), value=LIMIT_VALUES)
def test_limits_and_ramps(bench, cases, line, value):
    key = line.strip().split(":")[0]
    path = written_case(cases, bench, [(line, f"  {key}: {value}")])
    try_config("limits and ramps", path, "")


@pytest.mark.parametrize("kind", ["fifo", "device", "directory", "empty", "dangling link", "calibration fifo"])
def test_files_that_are_not_configurations(bench, cases, kind):
    folder = cases.folder()
    path = folder / "cryod.yaml"
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "device":
        path = Path("/dev/zero")
    elif kind == "directory":
        path = folder
    elif kind == "empty":
        path.write_text("")
    elif kind == "dangling link":
        path.symlink_to(folder / "nowhere.yaml")
    else:
        os.mkfifo(folder / "curve.340")
        path.write_text(base_text(bench, folder).replace(f"{CONFIG}/calibration/X186279.340",
                                                         str(folder / "curve.340")))
    key = "sensors.flange.calibration" if kind == "calibration fifo" else None
    try_config("files that are not configurations", path, key)


# ---------------------------------------------------------------------------
# setpoints, ramps and reloads in every state
# ---------------------------------------------------------------------------
@st.composite
def limit_sets(draw) -> dict:
    """Limits for a reload: mostly a valid file, every tenth one breaking its own rules."""
    setpoint_max = draw(st.sampled_from([3.9, 4.5, 6.0, 8.0, 12.0, 20.0]))
    flange_max = draw(st.sampled_from([limit for limit in (4.1, 6.5, 10.0, 25.0) if limit > setpoint_max]))
    setpoint_min = draw(st.sampled_from([limit for limit in (3.0, 3.5, 5.0) if limit < setpoint_max]))
    max_ramp = draw(st.sampled_from([0.05, 1.0, 10.0]))
    limits = {
        "setpoint_max_K": setpoint_max, "flange_max_K": flange_max, "setpoint_min_K": setpoint_min,
        "max_ramp_K_per_min": max_ramp,
        "ramp_K_per_min": draw(st.sampled_from([rate for rate in (0.0, 0.01, 2.0) if rate <= max_ramp])),
        "setpoint_K": draw(st.sampled_from(["null"] + [value for value in (3.5, 5.0, 7.0)
                                                       if setpoint_min <= value <= setpoint_max])),
    }
    if draw(st.integers(0, 9)) == 9:
        limits[draw(st.sampled_from(sorted(limits)))] = draw(st.sampled_from(["010", "1_0", "-1", "1e-320", "30"]))
    return limits


OPERATIONS = st.one_of(
    st.tuples(st.just("setpoint"), st.sampled_from([3.5, 4.0, 5.0, 7.0, 9.0, 12.0, 19.0])),
    st.tuples(st.just("ramp"), st.sampled_from([0.0, 0.02, 0.5, 5.0, 1e-320, 1e-7])),
    st.tuples(st.just("heater-off"), st.none()),
    st.tuples(st.just("manual"), st.sampled_from([0.0, 0.005, 0.01])),
    st.tuples(st.just("reload"), limit_sets()),
    st.tuples(st.just("reload"), limit_sets()),
    st.tuples(st.just("reload while recovering"), limit_sets()),
    st.tuples(st.just("ramp, then a slower ramp limit"), limit_sets()),
    st.tuples(st.just("a limit below the flange"), st.none()),
)
#: Limits below the flange's temperature with the heater off (about 4.26 K).
COLD_LIMITS = {"setpoint_max_K": 3.9, "flange_max_K": 4.1, "setpoint_min_K": 3.0, "setpoint_K": "null",
               "ramp_K_per_min": 0.0, "max_ramp_K_per_min": 1.0}
RELOAD_RUNS = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                       suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def limits_text(limits: dict) -> list[tuple[str, str]]:
    return [(line, f"  {line.strip().split(':')[0]}: {limits[line.strip().split(':')[0]]}")
            for line in LIMIT_LINES if line.strip().split(":")[0] in limits]


@RELOAD_RUNS
@given(first=limit_sets(), first_row=st.integers(1, 3),
       steps=st.lists(st.tuples(st.integers(4, 40), OPERATIONS), min_size=3, max_size=10))
def test_setpoints_ramps_and_reloads_in_every_state(tmp_path_factory, first, first_row, steps):
    """A reload while the loop still holds the heater off at start, then operator commands, reloads and sensor
    faults (each ``reload while recovering`` injects one and reloads two rows later; ``ramp, then a slower ramp
    limit`` and ``a limit below the flange`` aim at the limits on the ramp in use and the temperature now)."""
    tmp_path = tmp_path_factory.mktemp("sequence")
    schedule, row = {first_row: ("reload", first)}, first_row
    for gap, (name, value) in steps:
        row += gap
        if name == "reload while recovering":
            schedule[row] = ("fault", None)
            schedule[row + 2] = ("reload", value)
            row += 2
        elif name == "ramp, then a slower ramp limit":
            schedule[row] = ("ramp", 0.5)
            schedule[row + 2] = ("reload", {**value, "max_ramp_K_per_min": 0.05, "ramp_K_per_min": 0.0})
            row += 2
        elif name == "a limit below the flange":
            schedule[row] = ("reload", COLD_LIMITS)
        else:
            schedule[row] = (name, value)
    violations = []
    states_at_reload = {}

    def act(drill, label, operation):
        name, value = operation
        if name == "fault":
            drill.opener.bench.ptc_stage_dmm.inject_overflow(3)
        elif name == "reload":
            states_at_reload[label] = str(drill.loop.state)
            try:
                drill.reload(label, limits_text(value))
            except Exception as error:      # refused as the file was read: FileFormatError at its key
                assert located(str(error), drill.path, ""), error
                OUTCOMES[("reloads", "refused as the file was read, at its key")] += 1
                OUTCOMES[("reload states", states_at_reload.pop(label))] += 1
        else:
            drill.command(label, name, value)

    def watch(drill):
        loop, row_ = drill.loop, drill.rows[-1]
        control, safety, regulator = loop.config.control, loop.config.safety, loop.regulator
        if str(row_.state).startswith("closed") and not row_.setpoint_K < safety.flange_max_K:
            violations.append(f"setpoint in use {row_.setpoint_K} at or above flange_max_K {safety.flange_max_K}")
        if regulator.mode is RegulatorMode.CLOSED:
            target = regulator.ramp.target_K
            if not control.setpoint_min_K <= target <= control.setpoint_max_K:
                violations.append(f"target {target} outside {control.setpoint_min_K}..{control.setpoint_max_K}")

    actions = {}
    for number in range(1, row + 40):
        def action(drill, operation=schedule.get(number), number=number):
            watch(drill)
            if operation is not None:
                act(drill, str(number), operation)
        actions[number] = action
    drill = ReloadDrill(tmp_path, actions)
    assert drill.run((row + 30) * 0.08).exit_code == 0
    assert not violations, violations[:3]
    for label, command in drill.sent.items():
        assert command.done.is_set(), label
        if command.name != "reload":
            continue
        OUTCOMES[("reload states", states_at_reload[label])] += 1
        if command.ok:
            OUTCOMES[("reloads", "accepted")] += 1
            continue
        assert re.match(r"kept the running configuration: " + re.escape(str(drill.path)) + r":\d+: [\w.]+: ",
                        command.message), command.message
        OUTCOMES[("reloads", f"refused at {command.message.split(': ')[2]}")] += 1


