"""Many control-socket clients at once against the running daemon: what they get back, and what the loop feels.

Run: PYTHONPATH=. python3 benchmarks/control_socket_clients.py [--clients 100] [--phase-s 20] [--phases 3]

Starts ``cryod --simulate`` in real time (drivers to the simulated instruments through pyvisa-py
over TCP on 127.0.0.1), waits until it regulates, then alternates quiet phases and phases in which
rounds of ``--clients`` clients connect at the same instant (one round after the other; half the
rounds ask ``status``, half send ``ramp 0``, which goes through the loop and changes nothing).
For each phase: the clients' outcomes (a reply, a busy reply, or an error and its type), the loop's
overruns and missed deadlines (from its status), the ``lateness_ms`` and ``cycle_ms`` columns of
the rows recorded in the phase, and the daemon process's CPU time per second of the phase and per
reply (beyond the quiet phases' rate). The machine's load from other work shows in the quiet
phases; CPU time does not depend on it as much as lateness does.

Results: ``benchmarks/results/control_socket.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from cryod.records.record import read_record

REPOSITORY = Path(__file__).resolve().parent.parent


def one_round(path: Path, clients: int, line: str) -> collections.Counter:
    """``clients`` connections made at the same instant, each sending ``line``: outcome counts."""
    outcomes: collections.Counter = collections.Counter()
    lock = threading.Lock()
    barrier = threading.Barrier(clients)

    def client() -> None:
        connection = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        connection.settimeout(20.0)
        barrier.wait()
        try:
            connection.connect(str(path))
            connection.sendall(line.encode() + b"\n")
            reply = json.loads(connection.makefile("rb").readline())
            outcome = "reply" if reply["ok"] or "busy" not in reply["message"] else "busy"
        except Exception as error:                      # what a client of the daemon would see
            outcome = type(error).__name__
        finally:
            connection.close()
        with lock:
            outcomes[outcome] += 1

    threads = [threading.Thread(target=client) for _ in range(clients)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return outcomes


def process_cpu_s(pid: int) -> float:
    """User + system CPU time of process ``pid`` so far, s."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def status(path: Path) -> dict:
    connection = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    connection.settimeout(20.0)
    with connection:
        connection.connect(str(path))
        connection.sendall(b"status\n")
        return json.loads(connection.makefile("rb").readline())["status"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clients", type=int, default=100)
    parser.add_argument("--phase-s", type=float, default=20.0, help="length of each phase, s")
    parser.add_argument("--phases", type=int, default=3, help="pairs of (quiet, clients) phases")
    parser.add_argument("--speed", default="1", help="the daemon's --speed (below 1 gives its loop more room on a "
                                                     "loaded machine)")
    parser.add_argument("--nice", type=int, default=0,
                        help="niceness of the daemon (negative, as root: less disturbed by other work on the machine)")
    arguments = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "c.sock"
        daemon = subprocess.Popen(
            [sys.executable, "-m", "cryod.cli", "--simulate", "--speed", arguments.speed, "--data-dir", f"{folder}/data",
             "--socket", str(path)],
            cwd=folder, env=dict(os.environ, PYTHONPATH=str(REPOSITORY)), stdout=subprocess.DEVNULL,
            stderr=open(Path(folder) / "stderr.txt", "w"), preexec_fn=lambda: os.nice(arguments.nice))
        try:
            end = time.monotonic() + 60.0
            while time.monotonic() < end:
                try:
                    if status(path)["state"].startswith("closed"):
                        break
                except (OSError, ValueError, KeyError):
                    pass
                time.sleep(0.5)
            else:
                raise SystemExit("the daemon did not start regulating within 60 s")
            time.sleep(5.0)                 # past the start
            phases = []
            for index in range(2 * arguments.phases):
                busy = index % 2 == 1
                before = status(path)
                cpu_before, wall_before = process_cpu_s(daemon.pid), time.monotonic()
                outcomes: collections.Counter = collections.Counter()
                rounds = 0
                phase_end = time.monotonic() + arguments.phase_s
                while time.monotonic() < phase_end:
                    if busy:
                        outcomes += one_round(path, arguments.clients, "status" if rounds % 2 == 0 else "ramp 0")
                        rounds += 1
                    else:
                        time.sleep(0.2)
                cpu_s, wall_s = process_cpu_s(daemon.pid) - cpu_before, time.monotonic() - wall_before
                after = status(path)
                if "ticks" not in after:
                    raise SystemExit(f"the daemon is not regulating: {after}")
                phases.append({"clients": busy, "rounds": rounds, "outcomes": dict(outcomes),
                               "ticks": (before["ticks"], after["ticks"]), "cpu_s": cpu_s, "wall_s": wall_s,
                               "overruns": after["overruns"] - before["overruns"],
                               "missed_deadlines": after["missed_deadlines"] - before["missed_deadlines"]})
        except (OSError, SystemExit):
            daemon.wait(30)
            raise SystemExit(f"the daemon stopped (exit {daemon.returncode}): "
                             f"{Path(folder, 'stderr.txt').read_text()[-1500:]}") from None
        finally:
            if daemon.poll() is None:
                daemon.terminate()
                daemon.wait(30)
        records = [read_record(file) for file in sorted(Path(folder, "data").glob("cryod-*.csv"))]
    record = records[0]
    lateness, cycle = record.columns["lateness_ms"], record.columns["cycle_ms"]
    quiet_rate = np.mean([phase["cpu_s"] / phase["wall_s"] for phase in phases if not phase["clients"]])
    print(f"{'phase':<8} {'rounds':>6} {'outcomes':<44} {'overruns':>8} {'missed':>6} "
          f"{'late p99/max ms':>16} {'cycle p99/max ms':>17} {'CPU s/s':>7} {'CPU ms/reply':>12}")
    for phase in phases:
        first, last = phase["ticks"]
        rows = slice(max(first - 1, 0), last - 1)        # row k is tick k + 1 (holding rows included)
        late, took = lateness[rows], cycle[rows]
        late, took = late[np.isfinite(late)], took[np.isfinite(took)]
        replies = sum(count for outcome, count in phase["outcomes"].items() if outcome in ("reply", "busy"))
        per_reply = (phase["cpu_s"] - quiet_rate * phase["wall_s"]) / replies * 1e3 if replies else float("nan")
        print(f"{'clients' if phase['clients'] else 'quiet':<8} {phase['rounds']:>6} "
              f"{json.dumps(phase['outcomes']):<44} {phase['overruns']:>8} {phase['missed_deadlines']:>6} "
              f"{np.percentile(late, 99):>7.2f}/{late.max():<8.2f} {np.percentile(took, 99):>7.1f}/{took.max():<8.1f} "
              f"{phase['cpu_s'] / phase['wall_s']:>7.3f} {per_reply:>12.3f}")
    print(f"load average at the end: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
