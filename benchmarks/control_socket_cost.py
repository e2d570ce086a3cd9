"""What serving the control socket costs the daemon's process: CPU per reply, and the stretch of a tick.

Run: PYTHONPATH=. python3 benchmarks/control_socket_cost.py [--tree PATH] [--clients 100] [--rounds 10] [--repeat 3]

A server process runs ``ControlSocketServer`` from the cryod tree ``--tree`` (default this one; give
another checkout, e.g. main's, to compare) beside a stand-in for the control loop's thread: every
80 ms, 20 exchanges that each wait 0.5 ms with the interpreter released (a driver waiting for an
instrument) and then compute for 50 us; it records how long each tick took. The bench alternates
quiet stretches with rounds of ``--clients`` clients that ask ``status`` at the same instant
(``cryod ctl``'s client from this tree, which waits while the backlog is full), and reports:

* the server process's CPU time beyond the stand-in loop's, per reply (less sensitive to other
  work on the machine than timing is);
* the stand-in ticks' duration, quiet and with clients (p50, p99, max; 80 ms is the deadline).

Results: ``benchmarks/results/control_socket.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from cryod.service.control_socket import send_command

REPOSITORY = Path(__file__).resolve().parent.parent

SERVER = r"""
import json, sys, threading, time
sys.path.insert(0, sys.argv[1])
from cryod.service.control_socket import ControlSocketServer

STATUS = {f"column_{index:02d}": 1.0 + index for index in range(30)}
durations, lock = [], threading.Lock()

def stand_in_loop():
    deadline = time.monotonic()
    while True:
        deadline += 0.08
        time.sleep(max(0.0, deadline - time.monotonic()))
        started = time.monotonic()
        for _ in range(20):
            time.sleep(0.0005)
            until = time.thread_time() + 50e-6
            while time.thread_time() < until:
                pass
        with lock:
            durations.append(time.monotonic() - started)

def answer(command):
    command.answer(True, "done")
    return command

server = ControlSocketServer(sys.argv[2], 0o600, None, None, answer, lambda: dict(STATUS))
server.start()
loop_thread = threading.Thread(target=stand_in_loop, daemon=True)
loop_thread.start()
loop_clock = time.pthread_getcpuclockid(loop_thread.ident)
print("ready", flush=True)
for line in sys.stdin:
    with lock:
        taken, durations[:] = list(durations), []
    print(json.dumps({"process_cpu_s": time.process_time(), "loop_cpu_s": time.clock_gettime(loop_clock),
                      "tick_s": taken}), flush=True)
server.stop()
"""


def one_round(path: Path, clients: int) -> int:
    """``clients`` ``status`` requests at the same instant; the number answered."""
    answered = []
    barrier = threading.Barrier(clients)

    def client() -> None:
        barrier.wait()
        try:
            answered.append(send_command(path, "status", timeout_s=30.0)["ok"])
        except (ConnectionError, OSError):
            pass

    threads = [threading.Thread(target=client) for _ in range(clients)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return sum(answered)


def measure(tree: Path, clients: int, rounds: int) -> dict:
    path = Path(f"/tmp/cryod-socket-cost-{os.getpid()}.sock")
    server = subprocess.Popen([sys.executable, "-c", SERVER, str(tree), str(path)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert server.stdout.readline().strip() == "ready"

        def mark() -> dict:
            server.stdin.write("mark\n")
            server.stdin.flush()
            return json.loads(server.stdout.readline())

        quiet_ticks, busy_ticks, server_cpu_s, replies = [], [], 0.0, 0
        previous = mark()
        for _ in range(rounds):
            time.sleep(1.0)                                 # quiet
            now = mark()
            quiet_ticks += now["tick_s"]
            previous = now
            replies += one_round(path, clients)
            now = mark()
            busy_ticks += now["tick_s"]
            server_cpu_s += (now["process_cpu_s"] - previous["process_cpu_s"]) - (now["loop_cpu_s"] - previous["loop_cpu_s"])
            previous = now
    finally:
        server.stdin.close()
        server.wait(30)
    return {"replies": replies, "asked": clients * rounds, "cpu_ms_per_reply": 1e3 * server_cpu_s / max(replies, 1),
            "quiet_ms": np.percentile(np.array(quiet_ticks) * 1e3, [50, 99, 100]),
            "clients_ms": np.percentile(np.array(busy_ticks) * 1e3, [50, 99, 100]) if busy_ticks else [np.nan] * 3}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tree", type=Path, default=REPOSITORY, help="cryod checkout whose control socket is measured")
    parser.add_argument("--clients", type=int, default=100)
    parser.add_argument("--rounds", type=int, default=10)
    parser.add_argument("--repeat", type=int, default=3)
    arguments = parser.parse_args()
    print(f"tree {arguments.tree}: {arguments.clients} clients x {arguments.rounds} rounds")
    print(f"{'replies':>12} {'CPU ms/reply':>12} {'quiet tick p50/p99/max ms':>26} {'clients tick p50/p99/max ms':>28}")
    for _ in range(arguments.repeat):
        result = measure(arguments.tree.resolve(), arguments.clients, arguments.rounds)
        quiet, busy = result["quiet_ms"], result["clients_ms"]
        print(f"{result['replies']:>5}/{result['asked']:<6} {result['cpu_ms_per_reply']:>12.3f} "
              f"{quiet[0]:>8.1f}/{quiet[1]:>6.1f}/{quiet[2]:>6.1f}     {busy[0]:>8.1f}/{busy[1]:>6.1f}/{busy[2]:>6.1f}")
    print(f"load average at the end: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
