"""``cryod identify --acquire``: the identification experiment on the cryostat, through the daemon itself.

The experiment (:mod:`cryod.identification.experiment`) runs on the daemon's
own code path (:class:`cryod.service.daemon.Daemon`): the real drivers (or the
simulated bench with ``--simulate``), the loop with its safety checks, the
data log. The loop starts with the heater off (no setpoint) and the experiment
drives it open loop through the regulator's manual mode, one command per phase.
What is recorded is a normal cryod-log v1 record, with the plan in its header
and each phase as an event line.

Whatever ends it, the heater is left at 0 W by the loop and everything read
until then is in the record: at the plan's end (outcome ``finished``); on
Ctrl-C or SIGTERM (``interrupted``: the daemon's own stop); on any fault, even
one the daemon would recover from (``fault``: a heater step interrupted by a
fault is no step to fit).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from cryod.config import DaemonConfig
from cryod.identification.experiment import ExperimentPlan, ExperimentRunner, Progress
from cryod.records.columns import Event
from cryod.records.compression import record_path_now
from cryod.service.commands import Command
from cryod.service.daemon import Daemon
from cryod.service.faults import ExitCode, FaultCause
from cryod.service.notify import SystemdNotifier

log = logging.getLogger("cryod.identify")

#: Exit status of an experiment stopped by Ctrl-C or SIGTERM (128 + SIGINT, as shells report it).
INTERRUPTED_EXIT = 130


@dataclass
class Acquisition:
    """How the experiment went.

    Attributes
    ----------
    outcome : str
        ``finished``, ``interrupted``, ``fault`` or ``not_started``.
    exit_code : int
        0 finished; 130 interrupted; the fault's exit code (docs/reference/exit-codes.md) otherwise.
    record_paths : list of pathlib.Path
        The data files written (a run across UTC midnight has two).
    runner : ExperimentRunner
    message : str
        What happened, for the user.
    """

    outcome: str
    exit_code: int
    record_paths: list[Path]
    runner: ExperimentRunner
    message: str
    wall_s: float = 0.0


def experiment_config(config: DaemonConfig) -> DaemonConfig:
    """The configuration the experiment runs with: the loop starts with the heater off (no setpoint)."""
    return dataclasses.replace(config, control=dataclasses.replace(config.control, setpoint_K=None))


class ProgressDisplay:
    """A progress bar on a terminal (tqdm): the phase, the time simulated or measured, the estimated time left.

    Off when the stream is not a terminal. It runs on a thread of its own and
    reads :attr:`ExperimentRunner.progress` twice a second: nothing of it runs
    in the loop's thread.
    """

    def __init__(self, source: Callable[[], Progress], stream=None, enabled: bool | None = None,
                 interval_s: float = 0.5):
        self.source = source
        self.stream = stream or sys.stderr
        self.enabled = (hasattr(self.stream, "isatty") and self.stream.isatty()) if enabled is None else enabled
        self.interval_s = interval_s
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def __enter__(self) -> "ProgressDisplay":
        if self.enabled:
            self._thread = threading.Thread(target=self._run, name="cryod-identify-progress", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)

    @staticmethod
    def describe(progress: Progress) -> str:
        """The text beside the bar: phase, T2, heater, time left."""
        left = f"~{progress.time_left_s / 60:.0f} min left" if math.isfinite(progress.time_left_s) else "time left ?"
        if progress.phase_count and progress.phase_index:
            phase = f"{progress.phase} ({progress.phase_index}/{progress.phase_count})"
        else:
            phase = progress.phase
        temperature = f"T2 {progress.flange_K:.5f} K" if math.isfinite(progress.flange_K) else "T2 -"
        return f"{phase} | {temperature} | heater {progress.heater_w * 1e3:.2f} mW | {left}"

    def _run(self) -> None:
        from tqdm import tqdm

        bar = tqdm(total=1, file=self.stream, unit="s", dynamic_ncols=True, leave=True,
                   bar_format="{desc} {percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} s [{elapsed}]{postfix}")
        try:
            while not self._stop.wait(self.interval_s):
                self._draw(bar)
            self._draw(bar)
        finally:
            bar.close()

    def _draw(self, bar) -> None:
        progress = self.source()
        total = progress.elapsed_s + (progress.time_left_s if math.isfinite(progress.time_left_s) else 0.0)
        bar.total = max(total, 1.0)
        bar.n = progress.elapsed_s
        bar.set_description_str("identify", refresh=False)
        bar.set_postfix_str(self.describe(progress), refresh=False)
        bar.refresh()


def acquire(config: DaemonConfig, plan: ExperimentPlan, open_instruments: Callable, clock, *,
            metadata: dict | None = None, expected_settle_s: float = 900.0, progress: bool | None = None,
            progress_stream=None, install_signal_handlers: bool = True, row_taps: list | None = None,
            notifier: SystemdNotifier | None = None, datalog_options: dict | None = None,
            instrument_addresses: Callable | None = None) -> Acquisition:
    """Run the identification experiment through the daemon.

    Parameters
    ----------
    config : DaemonConfig
        The daemon's configuration (its heater, safety limits, data directory,
        control socket); its setpoint is ignored: the loop starts open.
    plan : ExperimentPlan
        Checked against the configured heater first.
    open_instruments : callable
        As for :class:`~cryod.service.daemon.Daemon` (the real instruments, or
        :class:`cryod.service.simulation.SimulatedInstrumentsOpener`).
    clock : Clock
    metadata : dict, optional
        More header lines for the record.
    expected_settle_s : float
        First guess of a settling phase's length, for the time left (s).
    progress : bool, optional
        Show the progress bar (default: when the stream is a terminal).
    install_signal_handlers : bool
        Ctrl-C (SIGINT) and SIGTERM stop the experiment (main thread only).
    row_taps : list of callable, optional
        Also receive every row and event (tests).
    instrument_addresses : callable, optional
        As for :class:`~cryod.service.daemon.Daemon`: the real instruments' addresses, locked for the run.

    Returns
    -------
    Acquisition

    Raises
    ------
    ValueError
        The plan does not fit the configured heater (nothing was started).
    """
    plan.check(config.heater.max_power_w)
    config = experiment_config(config)
    header = {"identify": "cryod identify --acquire", **plan.metadata(), **(metadata or {})}
    holder: dict = {}

    def submit(name: str, value) -> None:
        holder["daemon"].loop.submit(Command(name, value))

    def stop(reason: str) -> None:
        holder["daemon"].loop.request_stop(reason)

    def note(text: str) -> None:
        log.info("%s", text)
        holder["daemon"].datalog.put(Event("identify", text))

    runner = ExperimentRunner(plan, submit, stop, note, expected_settle_s=expected_settle_s)
    daemon = Daemon(config, open_instruments, clock, notifier=notifier or SystemdNotifier({}), metadata=header,
                    row_taps=[runner, *(row_taps or [])], install_signal_handlers=install_signal_handlers,
                    datalog_options=datalog_options, instrument_addresses=instrument_addresses)
    holder["daemon"] = daemon
    started = time.perf_counter()
    with ProgressDisplay(lambda: runner.progress, stream=progress_stream, enabled=progress):
        result = daemon.run()
    wall = time.perf_counter() - started
    paths = [record_path_now(path) for path in result.log_paths]     # a day that ended is compressed by now
    where = ", ".join(map(str, paths)) if paths else "no record was written"
    if result.exit_code == ExitCode.CONFIG and result.loop is None:
        return Acquisition("not_started", int(ExitCode.CONFIG), paths, runner,
                           f"the experiment did not start: another cryod holds {config.control_socket.path} or one "
                           f"of the instruments (stop the service first: systemctl stop cryod), or the configuration "
                           f"was refused; see above",
                           wall)
    if runner.outcome == "finished":
        unsettled = (f"; NOT settled within --max-settle: {', '.join(runner.unsettled)}" if runner.unsettled else "")
        return Acquisition("finished", 0, paths, runner, f"experiment finished, heater at 0 W; record: {where}"
                           f"{unsettled}", wall)
    if runner.outcome == "fault":
        try:
            code = int(FaultCause(runner.fault).exit_code)
        except ValueError:
            code = int(ExitCode.EXCEPTION)
        return Acquisition("fault", code, paths, runner,
                           f"experiment stopped by the fault {runner.fault} in phase {runner.phase}; the heater "
                           f"was set to 0 W; what was measured is kept: {where}", wall)
    loop = result.loop
    if result.exit_code != ExitCode.OK or loop is None:
        fault = str(loop.last_fault) if loop is not None and loop.last_fault else "the daemon stopped"
        return Acquisition("fault", int(result.exit_code), paths, runner,
                           f"experiment stopped: {fault} (exit {int(result.exit_code)}); heater at 0 W; what was "
                           f"measured is kept: {where}", wall)
    reason = loop.last_fault.message if loop.last_fault else "stopped"
    phase = runner.phase or "before the first phase"
    return Acquisition("interrupted", INTERRUPTED_EXIT, paths, runner,
                       f"experiment interrupted ({reason}) in phase {phase}; the heater was set to 0 W; what was "
                       f"measured is kept: {where}", wall)


__all__ = ["Acquisition", "ProgressDisplay", "acquire", "experiment_config", "INTERRUPTED_EXIT"]
