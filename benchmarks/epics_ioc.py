"""What cryod's EPICS IOC costs the daemon, and how soon a reading reaches a Channel Access monitor.

Run: PYTHONPATH=. python3 benchmarks/epics_ioc.py [--seconds 60] [--monitors 100] [--puts 20] [--repeat 2]

Each round runs the example configuration's dry run in real time (``cryod simulate --speed 1``, a
process of its own, on loopback EPICS ports of its own) twice, in turn:

* ``quiet``: the daemon alone;
* ``commands``: the same commands as ``ioc``'s puts, ``--puts`` a second, sent straight to the control
  socket (as ``cryod ctl`` would): the same run without the IOC, whose cost per tick is the loop's own
  work of applying a command, whoever sends it;
* ``monitors``: ``cryod ioc`` beside the daemon and a Channel Access client process (pyepics) holding
  ``--monitors`` monitors on the per-row readings (T2, T5, HEATER, ... : each changes at every row, so every
  monitor gets the loop's rate), no puts;
* ``ioc``: the same, and the client puts ``--puts`` times a second (SETPOINT 5.0 and RAMP 0 in turn: each
  put is a command the daemon answers, and leaves the regulation as it was).

Over the same ``--seconds`` window of each run (after the loop has regulated for 20 s, the client connected) it takes the CPU
time of the loop's own thread (its POSIX thread CPU clock, read inside the daemon's process at the
window's two ends) per tick, and the overruns; in ``ioc`` runs also each T2 update's lateness at the
monitor: the wall time it arrived less its timestamp, which the IOC takes from the daemon's sample
instant (the row's ``time_s`` plus the stream's ``clock_offset_s``). It prints one JSON line per run
and a summary: the best tick CPU of each mode (this machine's speed drifts between runs) and their
ratio, the overruns, the lateness p50/p99/max.

Results: ``benchmarks/results/epics_ioc.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPOSITORY))

from tests.ioc_bench import EPICS_ENVIRONMENT, IocProcess, ioc_lab_config  # noqa: E402

PREFIX = "BENCH:"
MODES = ("quiet", "commands", "monitors", "ioc")
#: The loop regulates this long before the window opens (s).
SETTLE_S = 20.0

DAEMON = r"""
import json, os, sys, threading, time
from pathlib import Path
from cryod.service import loop as loop_module
marks_folder = Path(sys.argv[1])
found = {}
run = loop_module.ControlLoop.run
def watched(self, *args, **kwargs):
    found["loop"], found["clock"] = self, time.pthread_getcpuclockid(threading.get_ident())
    return run(self, *args, **kwargs)
loop_module.ControlLoop.run = watched
def marks():
    taken = {}
    while True:
        time.sleep(0.02)
        for path in marks_folder.glob("mark-*"):
            name = path.name[5:]
            if name in taken or "loop" not in found:
                continue
            loop = found["loop"]
            summary = loop.timing.summary()
            taken[name] = {"cpu_s": time.clock_gettime(found["clock"]), "ticks": summary["ticks"], "wall": time.time(),
                           "overruns": summary["overruns"]}
            (marks_folder / "marks.json").write_text(json.dumps(taken))
threading.Thread(target=marks, daemon=True).start()
from cryod.cli import main
sys.exit(main(sys.argv[2:]))
"""

CLIENT = r"""
import json, sys, threading, time
import epics
prefix, seconds, monitors, puts = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
names = ["T2", "T5", "HEATER", "HEATER_PI", "HEATER_FF", "SETPOINT_IN_USE", "LATENESS"]
late, counts, lock = [], [0], threading.Lock()
def t2(value=None, timestamp=None, **kw):
    arrived = time.time()
    with lock:
        late.append(arrived - timestamp)
def other(**kw):
    with lock:
        counts[0] += 1
pvs = []
for index in range(monitors):
    name = names[index % len(names)]
    pv = epics.PV(prefix + name, form="time", callback=t2 if index == 0 else other, auto_monitor=True)
    pvs.append(pv)
for pv in pvs:
    pv.wait_for_connection(10)
setpoint, ramp = epics.PV(prefix + "SETPOINT"), epics.PV(prefix + "RAMP")
setpoint.wait_for_connection(10); ramp.wait_for_connection(10)
print("ready", flush=True)
sys.stdin.readline()
with lock:
    late.clear(); counts[0] = 0
start = time.monotonic(); sent = 0
while time.monotonic() - start < seconds:
    if puts > 1e-6:
        (setpoint if sent % 2 == 0 else ramp).put(5.0 if sent % 2 == 0 else 0.0, wait=False)
        sent += 1
        time.sleep(max(0.0, start + sent / puts - time.monotonic()))
    else:
        time.sleep(0.1)
with lock:
    result = {"t2_updates": len(late), "other_updates": counts[0], "late_s": list(late), "puts": sent,
              "seconds": time.monotonic() - start}
print(json.dumps(result), flush=True)
"""


COMMANDS = r"""
import sys, threading, time
from cryod.service.control_socket import send_command
socket_path, seconds, rate = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
print("ready", flush=True)
sys.stdin.readline()
start = time.monotonic(); sent = 0
while time.monotonic() - start < seconds:
    line = "setpoint 5.0" if sent % 2 == 0 else "ramp 0.0"
    threading.Thread(target=send_command, args=(socket_path, line), daemon=True).start()   # each waits its tick
    sent += 1
    time.sleep(max(0.0, start + sent / rate - time.monotonic()))
print('{"puts": %d, "seconds": %f, "late_s": [], "t2_updates": 0, "other_updates": 0}' % (sent, time.monotonic() - start),
      flush=True)
"""


def percentile(values: list[float], fraction: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(fraction * len(ordered)))] if ordered else float("nan")


def status(socket_path: Path) -> dict:
    from cryod.service.control_socket import send_command

    return send_command(socket_path, "status")["status"]


def one_run(mode: str, seconds: float, monitors: int, puts: float) -> dict:
    with tempfile.TemporaryDirectory(prefix="cryod-epics-bench-") as name:
        folder = Path(os.environ.get("KEEP_BENCH_FOLDER") or name)
        folder.mkdir(parents=True, exist_ok=True)
        config = ioc_lab_config(folder, prefix=PREFIX)
        socket_path = folder / "control.sock"
        env = dict(os.environ, PYTHONPATH=str(REPOSITORY), **EPICS_ENVIRONMENT)
        duration = SETTLE_S + seconds + 40.0
        with open(folder / "daemon.txt", "w") as journal:
            daemon = subprocess.Popen([sys.executable, "-c", DAEMON, str(folder), "simulate", "--config", str(config),
                                       "--socket", str(socket_path), "--data-dir", str(folder / "data"),
                                       "--speed", "1", "--duration", str(duration), "--json"],
                                      env=env, cwd=folder, stdout=subprocess.PIPE, stderr=journal, text=True)
        ioc = client = None
        try:
            deadline = time.monotonic() + 60
            while not socket_path.exists() or not status(socket_path).get("state", "").startswith("closed"):
                assert time.monotonic() < deadline and daemon.poll() is None, (folder / "daemon.txt").read_text()
                time.sleep(0.2)
            if mode in ("monitors", "ioc"):
                ioc = IocProcess(folder, socket_path, PREFIX)
                client = subprocess.Popen([sys.executable, "-c", CLIENT, PREFIX, str(seconds), str(monitors),
                                           str(puts if mode == "ioc" else 1e-9)], env=env, stdin=subprocess.PIPE,
                                          stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            elif mode == "commands":
                client = subprocess.Popen([sys.executable, "-c", COMMANDS, str(socket_path), str(seconds), str(puts)],
                                          env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
            if client is not None:
                assert client.stdout.readline().strip() == "ready"
            time.sleep(SETTLE_S)
            if client is not None:
                client.stdin.write("go\n")
                client.stdin.flush()
            (folder / "mark-start").touch()
            if client is not None:
                result = json.loads(client.stdout.readline())
                client.wait(timeout=30)
            else:
                time.sleep(seconds)
                result = {}
            (folder / "mark-end").touch()
            time.sleep(0.5)
            marks = json.loads((folder / "marks.json").read_text())
        finally:
            for process in (client,):
                if process is not None and process.poll() is None:
                    process.kill()
            if ioc is not None:
                ioc.stop()
            daemon.terminate()
            daemon.wait(timeout=60)
        start, end = marks["start"], marks["end"]
        ticks = end["ticks"] - start["ticks"]
        run = {"mode": mode, "ticks": ticks, "tick_cpu_us": 1e6 * (end["cpu_s"] - start["cpu_s"]) / ticks,
               "overruns": end["overruns"] - start["overruns"], "overruns_since_start": end["overruns"],
               "load_average": os.getloadavg()[0]}
        if result:
            run.update(puts=result["puts"])
        if result.get("late_s"):
            late_ms = [1e3 * value for value in result["late_s"]]
            run.update(t2_updates=result["t2_updates"], monitor_updates=result["t2_updates"] + result["other_updates"],
                       puts=result["puts"], late_ms_p50=percentile(late_ms, 0.5), late_ms_p99=percentile(late_ms, 0.99),
                       late_ms_max=max(late_ms) if late_ms else float("nan"), window_s=result["seconds"])
        return run


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--monitors", type=int, default=100)
    parser.add_argument("--puts", type=float, default=20.0)
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()
    runs = []
    for _ in range(args.repeat):
        for mode in MODES:
            run = one_run(mode, args.seconds, args.monitors, args.puts)
            print(json.dumps(run), flush=True)
            runs.append(run)
    best = {mode: min(run["tick_cpu_us"] for run in runs if run["mode"] == mode) for mode in MODES}
    loaded = [run for run in runs if run["mode"] in ("monitors", "ioc")]
    print(json.dumps({"tick_cpu_us": best, "ioc_over_commands": best["ioc"] / best["commands"],
                      "monitors_over_quiet": best["monitors"] / best["quiet"],
                      "overruns": [run["overruns"] for run in runs],
                      "late_ms_p99": [run["late_ms_p99"] for run in loaded],
                      "late_ms_max": [run["late_ms_max"] for run in loaded]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
