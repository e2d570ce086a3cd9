"""The loop's CPU per tick and its overruns with and without 5 open web pages and 5 Lake Shore 336 clients.

Run: PYTHONPATH=. python3 benchmarks/network_load.py [--duration 60] [--repeat 2]

Each measurement is a fresh ``cryod simulate`` process in real time (``--speed 1``, the drivers
talking to the simulated instruments over TCP) with the web page and the 336 command set on, the
CPU time of the thread that runs ``ControlLoop.run`` taken from its start to its end
(``time.thread_time``) and divided by its ticks, and the overruns of the run. With clients, this
process opens 5 pages (each reading the event stream) and 5 TCP clients of the 336 interface: two
poll ``KRDG? A;HTR? 1;SETP? 1`` as fast as they are answered, one sends random bytes, one sends
lines far beyond the limit, one connects, sends half a command and goes away, over and over.
Runs alternate (none, clients, none, clients, ...); the best of each is compared.

Results: ``benchmarks/results/network_load.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parent.parent

PROBE = r"""
import json, os, sys, time
from cryod.service import loop as loop_module
measured = {}
run = loop_module.ControlLoop.run
def timed(self, *args, **kwargs):
    start = time.thread_time()
    try:
        return run(self, *args, **kwargs)
    finally:
        measured["cpu_s"] = time.thread_time() - start
        summary = self.timing.summary()
        measured["ticks"], measured["overruns"] = summary["ticks"], summary["overruns"]
loop_module.ControlLoop.run = timed
from cryod.cli import main
try:
    main(sys.argv[1:])
finally:
    with open(os.environ["CRYOD_BENCHMARK_RESULT"], "w") as result:
        result.write(json.dumps(measured))
"""

ADDRESS = re.compile(r"(Lake Shore 336 command set|web page) \((?:writable|read-only)\) on 127\.0\.0\.1:(\d+)")


def configuration(folder: Path) -> Path:
    text = (REPOSITORY / "config" / "cryod.yaml").read_text().replace(
        "calibration: calibration/", f"calibration: {REPOSITORY}/config/calibration/")
    text = re.sub(r"(?m)^web: null.*$", 'web: {address: "127.0.0.1:0"}', text)
    text = re.sub(r"(?m)^lakeshore336: null.*$", 'lakeshore336: {address: "127.0.0.1:0"}', text)
    path = folder / "cryod.yaml"
    path.write_text(text)
    return path


class ClientLoad:
    """5 open pages and 5 TCP clients of the 336 interface, in threads of this process, until stopped."""

    def __init__(self, web_port: int, lakeshore_port: int):
        self.web_port, self.lakeshore_port = web_port, lakeshore_port
        self.stopping = threading.Event()
        self.counts = {"frames": 0, "replies": 0, "garbage": 0, "long": 0, "half": 0}
        workers = [self._page] * 5 + [self._poll, self._poll, self._garbage, self._long_lines, self._half_commands]
        self.threads = [threading.Thread(target=self._guarded, args=(worker,), daemon=True) for worker in workers]

    def __enter__(self) -> "ClientLoad":
        for thread in self.threads:
            thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stopping.set()
        for thread in self.threads:
            thread.join(10)

    def _guarded(self, worker) -> None:
        while not self.stopping.is_set():
            try:
                worker()
            except OSError:
                time.sleep(0.05)                # closed by the server (a limit): come back, as a client would

    def _connect(self, port: int) -> socket.socket:
        connection = socket.create_connection(("127.0.0.1", port), timeout=5)
        return connection

    def _page(self) -> None:
        with self._connect(self.web_port) as page:
            page.sendall(b"GET /api/events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            stream = page.makefile("rb")
            while not self.stopping.is_set():
                line = stream.readline()
                if not line:
                    return
                self.counts["frames"] += line.startswith(b"data: ")

    def _poll(self) -> None:
        with self._connect(self.lakeshore_port) as client:
            stream = client.makefile("rb")
            while not self.stopping.is_set():
                client.sendall(b"KRDG? A;HTR? 1;SETP? 1\r\n")
                if not stream.readline():
                    return
                self.counts["replies"] += 1

    def _garbage(self) -> None:
        with self._connect(self.lakeshore_port) as client:
            while not self.stopping.is_set():
                client.sendall(random.randbytes(4096))
                self.counts["garbage"] += 1
                time.sleep(0.01)

    def _long_lines(self) -> None:
        with self._connect(self.lakeshore_port) as client:
            while not self.stopping.is_set():
                client.sendall(b"SETP 1," + b"9" * 60_000 + b"\r\n")
                self.counts["long"] += 1
                time.sleep(0.01)

    def _half_commands(self) -> None:
        with self._connect(self.lakeshore_port) as client:
            client.sendall(b"SETP 1,1")
        self.counts["half"] += 1
        time.sleep(0.02)


def measure(duration_s: float, with_clients: bool) -> dict:
    """One real-time run: loop-thread CPU per tick (s), overruns, and what the clients did."""
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        stderr = folder / "stderr.txt"
        result = folder / "result"
        with open(stderr, "w") as errors:
            process = subprocess.Popen(
                [sys.executable, "-c", PROBE, "simulate", "--config", str(configuration(folder)), "--speed", "1",
                 "--duration", str(duration_s), "--data-dir", str(folder / "data"), "--socket",
                 str(folder / "c.sock")],
                env=dict(os.environ, PYTHONPATH=str(REPOSITORY), CRYOD_BENCHMARK_RESULT=str(result)),
                stdout=subprocess.DEVNULL, stderr=errors)
            ports = {}
            while len(ports) < 2 and process.poll() is None:
                ports = dict(ADDRESS.findall(stderr.read_text()))
                time.sleep(0.05)
            counts = {}
            if with_clients:
                with ClientLoad(int(ports["web page"]), int(ports["Lake Shore 336 command set"])) as load:
                    process.wait()
                counts = load.counts
            process.wait()
        measured = json.loads(result.read_text())
    return {"cpu_per_tick_s": measured["cpu_s"] / measured["ticks"], "overruns": measured["overruns"],
            "ticks": measured["ticks"], **counts}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of each real-time run")
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()
    runs = {"none": [], "clients": []}
    for _ in range(args.repeat):
        for mode in runs:
            runs[mode].append(measure(args.duration, mode == "clients"))
            print(mode, runs[mode][-1], flush=True)
    best = {mode: min(run["cpu_per_tick_s"] for run in values) for mode, values in runs.items()}
    print(f"loop thread CPU per tick, {args.duration:g} s real-time runs, best of {args.repeat}:")
    print("| clients | best (µs) | all runs (µs) | overruns | best / best without |")
    print("|---|---|---|---|---|")
    for mode, values in runs.items():
        name = "5 pages + 5 TCP clients" if mode == "clients" else "none"
        each = ", ".join(f"{1e6 * run['cpu_per_tick_s']:.1f}" for run in values)
        overruns = ", ".join(str(run["overruns"]) for run in values)
        print(f"| {name} | {1e6 * best[mode]:.1f} | {each} | {overruns} | {best[mode] / best['none']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
