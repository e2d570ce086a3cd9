"""What the daemon's drivers say to the simulated instruments, exchange by exchange.

:func:`recorded_exchange` runs ``cryod --simulate`` in process on virtual time and keeps every
(command, reply) pair the drivers exchange with the simulated instruments through their
in-process transports, and every GPIB group execute trigger: the bytes a real 2002 or 6221
would get, and the replies the drivers parse. ``tests/data/daemon_exchange.txt`` holds such
an exchange as the tree before the simulated tick was made cheaper recorded it; the test
beside this module holds the present tree to it.

Run as a script (``PYTHONPATH=<checkout> python tests/instruments/daemon_exchange.py SECONDS OUT``)
it writes the exchange of any checkout, to record the file again or to compare two trees.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import sys
import tempfile
from pathlib import Path

from cryod.service.simulation import simulate
from drivers.transports.in_process import InProcessTransport
from simulated_hw.trigger_wiring import SimulatedGpibInterface

#: Seconds of the example configuration recorded (start-up hold, closing the loop, the feedforward's
#: first steps), and the noise seed.
RECORDED_S = 80.0
SEED = 1


@contextlib.contextmanager
def exchange_recorder():
    """Within the block, the in-process transports and the simulated GPIB board append to the list yielded:
    ``"<transport>|<command>|<reply>"`` lines (reply empty for a write, ``<GET>`` for a group trigger)."""
    lines: list[str] = []
    originals = {name: getattr(InProcessTransport, name) for name in ("write", "read", "query")}
    group_trigger = SimulatedGpibInterface.group_execute_trigger
    inside = [False]

    def write(self, command):
        if inside[0]:
            return originals["write"](self, command)
        originals["write"](self, command)
        lines.append(f"{self.name}|{command}|")

    def read(self):
        if inside[0]:
            return originals["read"](self)
        reply = originals["read"](self)
        lines.append(f"{self.name}|<read>|{reply}")
        return reply

    def query(self, command):
        inside[0] = True
        try:
            reply = originals["query"](self, command)
        finally:
            inside[0] = False
        lines.append(f"{self.name}|{command}|{reply}")
        return reply

    def trigger(interface, *devices):
        group_trigger(interface, *devices)
        lines.append(f"board|<GET>|{len(devices)}")

    try:
        InProcessTransport.write, InProcessTransport.read, InProcessTransport.query = write, read, query
        SimulatedGpibInterface.group_execute_trigger = trigger
        yield lines
    finally:
        for name, method in originals.items():
            setattr(InProcessTransport, name, method)
        SimulatedGpibInterface.group_execute_trigger = group_trigger


def recorded_exchange(duration_s: float = RECORDED_S, seed: int = SEED, feedforward: bool = True) -> list[str]:
    """The exchange of ``duration_s`` simulated seconds of the example configuration (see :func:`exchange_recorder`)."""
    with tempfile.TemporaryDirectory() as folder, exchange_recorder() as lines:
        simulate(duration_s, seed=seed, feedforward=feedforward, data_dir=Path(folder) / "data",
                 socket=Path(folder) / "c.sock", log_stream=io.StringIO())
    return lines


def digest(lines: list[str]) -> str:
    """SHA-256 of the exchange's lines (each ended by a newline)."""
    return hashlib.sha256("".join(line + "\n" for line in lines).encode()).hexdigest()


if __name__ == "__main__":
    seconds, out = float(sys.argv[1]), Path(sys.argv[2])
    exchange = recorded_exchange(seconds)
    out.write_text("".join(line + "\n" for line in exchange))
    print(f"{len(exchange)} exchanges, sha256 {digest(exchange)}")
