"""``cryod run`` as a real process against the simulated instruments served over TCP from the test's process.

The bench (cryostat, two Keithley 2002s, a heater supply) lives in the test process and serves
each instrument on its own 127.0.0.1 port; the daemon under test is ``cryod run --config`` in a
child process that reaches them through pyvisa-py, as it reaches real ones. The supply keeps
what it delivered and when (:attr:`simulated_hw.current_source.EmulatedCurrentSource.delivered_w`,
on ``time.monotonic``, the clock of the test process too), so a test reads what the heater
really got, whatever the daemon said or wrote.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml

from cryod.records.record import read_record
from drivers.clock import MonotonicClock
from cryod.service.control_socket import send_command
from simulated_hw.bench import SimulatedBench
from tests.conftest import CONFIG, REPOSITORY


class BenchOverTcp:
    """The simulated instruments on 127.0.0.1 for the life of a ``with`` block.

    Parameters
    ----------
    heater_resistance_ohm : float
    supply : {'6221', '2400'}
    """

    def __init__(self, heater_resistance_ohm: float = 50.0, supply: str = "6221"):
        self.bench = SimulatedBench(MonotonicClock(), heater_resistance_ohm=heater_resistance_ohm, supply=supply,
                                    seed=3)
        self.supply_model = {"6221": "keithley6221", "2400": "keithley2400"}[supply]
        self._stack = contextlib.ExitStack()
        self.resources: dict[str, str] = {}

    def __enter__(self) -> "BenchOverTcp":
        self.resources = self._stack.enter_context(self.bench.serve_tcp())
        return self

    def __exit__(self, *exc_info) -> None:
        self._stack.close()

    @property
    def supply(self):
        return self.bench.heater_supply

    def write_config(self, folder: Path, name: str = "cryod.yaml", **sections) -> Path:
        """A ``cryod run`` configuration for these instruments, its data, socket and instrument locks in
        ``folder``; ``sections`` replace keys (``safety={"instruments_wait_s": 5}``)."""
        folder.mkdir(parents=True, exist_ok=True)
        data = yaml.safe_load((CONFIG / "cryod.yaml").read_text())
        instruments = data["instruments"]
        instruments.update(trigger="sequential", timeout_s=1.0, lock_directory=str(folder.parent / "locks"))
        instruments["flange_dmm"] = {"resource": self.resources["flange_dmm"]}
        instruments["ptc_stage_dmm"] = {"resource": self.resources["ptc_stage_dmm"]}
        instruments["heater_supply"] = {"model": self.supply_model, "resource": self.resources["heater_supply"]}
        data["loop"].update(realtime_priority=0, lock_memory=False)
        for sensor in ("flange", "ptc_stage"):
            data["sensors"][sensor]["calibration"] = str(CONFIG / data["sensors"][sensor]["calibration"])
        data["data"]["directory"] = str(folder / "data")
        data["control_socket"]["path"] = str(folder / "control.sock")
        for section, values in sections.items():
            if data.get(section) is None:           # a section that is off (null) in the example
                data[section] = {}
            data[section].update(values)
        path = folder / name
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        return path


#: ``cryod run`` whose loop thread hangs inside its next reading while the file named first exists (a hung
#: instrument call no timeout ends): what the reading watchdog and the last resort of a stop are for.
HANGING_RUN = """\
import pathlib, runpy, sys, time
from cryod.service import instruments
marker = pathlib.Path(sys.argv.pop(1))
measure = instruments.DriverInstruments.measure
def hanging_measure(self):
    while marker.exists():
        time.sleep(0.01)
    return measure(self)
instruments.DriverInstruments.measure = hanging_measure
sys.argv[0] = "cryod"
runpy.run_module("cryod.cli", run_name="__main__")
"""


class RunProcess:
    """``cryod run --config PATH`` in a child process, its journal (stderr) kept.

    ``hang_when`` names a file whose creation hangs the loop thread in its next reading (:data:`HANGING_RUN`).
    """

    def __init__(self, config: Path, *arguments: str, hang_when: Path | None = None):
        self.config = config
        folder = config.parent
        settings = yaml.safe_load(config.read_text())
        self.socket_path = Path(settings["control_socket"]["path"])
        self.data = Path(settings["data"]["directory"])
        self.journal_path = folder / f"{config.stem}.journal"
        env = dict(os.environ, PYTHONPATH=str(REPOSITORY))
        env.pop("NOTIFY_SOCKET", None)
        self._journal = self.journal_path.open("w")
        program = ["-m", "cryod.cli"] if hang_when is None else ["-c", HANGING_RUN, str(hang_when)]
        self.process = subprocess.Popen([sys.executable, *program, "run", "--config", str(config), *arguments],
                                        env=env, cwd=folder, stdout=subprocess.DEVNULL, stderr=self._journal)

    @property
    def journal(self) -> str:
        return self.journal_path.read_text(errors="replace")

    def wait_until(self, condition, what: str, timeout_s: float = 60.0, poll_s: float = 0.02):
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            value = condition()
            if value:
                return value
            if self.process.poll() is not None:
                raise AssertionError(f"cryod run ended (exit {self.process.returncode}) before {what}:\n"
                                     f"{self.journal[-3000:]}")
            time.sleep(poll_s)
        raise AssertionError(f"no {what} within {timeout_s:g} s:\n{self.journal[-3000:]}")

    def wait_for_heating(self, supply, minimum_w: float = 0.02, timeout_s: float = 60.0) -> None:
        """Until the loop regulates and the supply delivers at least ``minimum_w``."""
        self.wait_until(lambda: supply.heater_power_w >= minimum_w, f"heater power of {minimum_w} W", timeout_s)

    def status(self) -> dict:
        return send_command(self.socket_path, "status")["status"]

    def send(self, number: int) -> float:
        """Send signal ``number``; the monotonic time just before."""
        sent_at = time.monotonic()
        os.kill(self.process.pid, number)
        return sent_at

    def wait(self, timeout_s: float = 30.0) -> int:
        try:
            return self.process.wait(timeout_s)
        finally:
            self._journal.flush()

    def record(self):
        files = sorted(self.data.glob("cryod-*.csv"))
        return read_record(files[-1]) if files else None

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
            self.process.wait(10)
        self._journal.close()


def faults_of_its_own(journal: str) -> list[str]:
    """The journal's lines of faults the loop found by itself (a reply later than the loop's wait, on a busy
    machine): the heater went to 0 W for them, whatever a test did to the daemon."""
    return [line for line in journal.splitlines() if "cryod.loop: warning: heater off: " in line]


def delay_to_zero_s(supply, since_s: float) -> float | None:
    """How long after ``since_s`` (monotonic) the supply's output went to 0 W and stayed there; None if it
    is not at 0 W now."""
    zero_since = supply.zero_since(since_s)
    return None if zero_since is None else zero_since - since_s
