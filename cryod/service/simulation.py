"""``cryod --simulate``: the daemon's own code path against the simulated cryostat.

The configuration is validated as for ``cryod run``; the drivers are the real
ones; only the far end differs: the simulated bench (simulated cryostat,
Keithley 2002s and heater supply speaking their SCPI). By default the drivers
reach it through pyvisa-py over TCP on 127.0.0.1, in real time. ``--speed X``
above 1 runs on simulated time paced to X times real time
(:class:`~drivers.paced_clock.PacedClock`): a machine that cannot keep
that pace slows the simulated clock instead of missing deadlines, and the
speed it achieved is in the status line and the summary (``achieved_speed``);
below 1 the clock runs X times real time. ``--speed max`` runs on virtual time
as fast as the CPU allows, with the in-process transport (a clock that never
waits cannot be shared with server threads).

Trigger modes: ``external`` and ``sequential`` are simulated as configured;
``gpib-group`` uses the simulated GPIB board in process, and over TCP (which
has no GPIB bus) the simulated external trigger wire, equally simultaneous;
``prologix`` serves all three instruments behind a simulated Prologix
GPIB-ETHERNET controller (TCP only).
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import json
import logging
import resource
import sys
import threading
from pathlib import Path

import numpy as np

from drivers.clock import clock_for_speed
from drivers.paced_clock import PacedClock
from cryod.config import EXAMPLE_CONFIG_PATH, DaemonConfig, load_config, located_error
from cryod.service.daemon import Daemon
from cryod.service.discovery import simulation_socket
from cryod.service.instance_lock import AlreadyRunning, InstanceLock
from cryod.service.instruments import assemble_instruments, check_calibrations, load_curves
from cryod.control.feedforward.limit import FeedforwardLimitError, feedforward_limit, limit_changes
from cryod.control.feedforward.limit_binding import limit_binding
from cryod.records.columns import Event, Row
from cryod.records.metrics import regulation_metrics
from cryod.model import DEFAULT_MODEL_PATH, linearised_at, load_model
from cryod.service.stream import finite_or_none
from cryod.service.logs import ServiceLogging
from cryod.service.readable import readable, rounded
from cryod.service.status_line import StatusLine
from cryod.yaml_source import FileFormatError
from drivers.keithley2002 import TriggerSource
from drivers.pair_triggers import GpibGroupTrigger, HardwareTrigger, PrologixGroupTrigger, SequentialTrigger
from drivers.transports.prologix import PrologixAdapter
from drivers.transports.visa import VisaTransport
from drivers.trigger_lines import SerialControlLine
from simulated_hw.bench import PROLOGIX_ADDRESSES, SimulatedBench

log = logging.getLogger("cryod.simulate")

SIMULATION_DIRECTORY = Path("cryod-simulate")
MAX_SOCKET_PATH = 100
SUPPLY_MODELS = {"keithley6221": "6221", "keithley2400": "2400"}


#: Rows before the metrics window that let the cooler's phase tracker lock (s).
TRACKER_LEAD_IN_S = 30.0


class WindowCollector:
    """Keeps the last ``window_s`` of rows (and a lead-in for the phase tracker) for the end-of-run metrics."""

    def __init__(self, window_s: float, period_s: float):
        self.rows = collections.deque(maxlen=int((window_s + TRACKER_LEAD_IN_S) / period_s) + 2)
        self.window_s = window_s + TRACKER_LEAD_IN_S

    def __call__(self, item: Row | Event) -> None:
        if type(item) is Row:
            self.rows.append((item.time_s, item.T2_K, item.T5_K, item.setpoint_K, item.T2_sample_s, item.T5_sample_s))

    def arrays(self) -> tuple[np.ndarray, ...]:
        """Trigger times, T2, T5, setpoint, T2's and T5's sample instants over the window."""
        if not self.rows:
            return (np.zeros(0),) * 6
        data = np.array(self.rows, dtype=float)
        data = data[data[:, 0] >= data[-1, 0] - self.window_s]
        return tuple(data[:, i] for i in range(6))


@dataclasses.dataclass(frozen=True)
class DryRunOptions:
    """What a dry run is asked for (``cryod --simulate``'s options, :func:`simulate`'s arguments); None: the
    configuration's own, or the dry run's default.

    Attributes
    ----------
    config : pathlib.Path, optional
        The daemon's configuration (default: the example, ``config/cryod.yaml``).
    duration_s : float, optional
        Simulated seconds to run (None: until stopped).
    speed : float or "max"
        Simulated seconds per real second; "max" runs on virtual time.
    json : bool
        Print the summary as one JSON object (on one line).
    pretty : bool
        With ``json``: indented, a key a line.
    window_s : float
        The summary's metrics window (s).
    setpoint_K : float, optional
    sim_model : pathlib.Path, optional
        The simulated cryostat's model.
    seed : int, optional
        Sensor-noise seed.
    feedforward : bool
        False: PI alone.
    data_dir, socket : pathlib.Path, optional
        Where the record goes and the control socket.
    transport : str, optional
        ``tcp`` or ``in-process`` (default: in-process on virtual time, else the configuration's).
    """

    config: Path | None = None
    duration_s: float | None = None
    speed: float | str = 1.0
    json: bool = False
    pretty: bool = False
    window_s: float = 300.0
    setpoint_K: float | None = None
    sim_model: Path | None = None
    seed: int | None = None
    feedforward: bool = True
    data_dir: Path | None = None
    socket: Path | None = None
    transport: str | None = None


def simulation_config(args: DryRunOptions, config: DaemonConfig) -> DaemonConfig:
    """The configuration with the dry run's overrides (setpoint, seed, paths, transport).

    A run on any clock but real time (``--speed`` other than 1) is a computation,
    not a service keeping deadlines: it neither takes real-time priority nor
    locks memory.
    """
    control = config.control
    if args.setpoint_K is not None:
        if not control.setpoint_min_K <= args.setpoint_K <= control.setpoint_max_K:
            raise ValueError(f"--setpoint {args.setpoint_K:g} K is outside control.setpoint_min_K.."
                             f"setpoint_max_K = {control.setpoint_min_K:g}..{control.setpoint_max_K:g} K "
                             f"of {config.source}")
        control = dataclasses.replace(control, setpoint_K=args.setpoint_K)
    if not args.feedforward:
        control = dataclasses.replace(control, terms=tuple(
            (name, dataclasses.replace(settings, enabled=False) if name == "feedforward" else settings)
            for name, settings in control.terms))
    simulation = config.simulation
    transport = args.transport or ("in-process" if args.speed == "max" else simulation.transport)
    if args.speed == "max" and transport == "tcp":
        raise ValueError("--speed max runs on virtual time, which only the in-process transport can share; "
                         "use --transport in-process or a numeric --speed")
    simulation = dataclasses.replace(simulation, transport=transport,
                                     seed=args.seed if args.seed is not None else simulation.seed)
    data = dataclasses.replace(config.data, directory=args.data_dir or SIMULATION_DIRECTORY / "data")
    try:
        socket_path = args.socket or simulation_socket(create_directory=True)
    except PermissionError as error:
        raise ValueError(f"no control socket for the dry run: {error}") from None
    if len(str(socket_path.absolute())) > MAX_SOCKET_PATH:
        raise ValueError(f"control socket path {socket_path.absolute()} is too long for a Unix socket; "
                         f"give a shorter one with --socket")
    control_socket = dataclasses.replace(config.control_socket, path=socket_path, owner=None, group=None)
    loop = config.loop
    if args.speed != 1.0:       # not real time: no real-time priority, no locked memory
        loop = dataclasses.replace(loop, realtime_priority=0, lock_memory=False)
    return dataclasses.replace(config, control=control, simulation=simulation, data=data,
                               control_socket=control_socket, loop=loop)


class SimulatedInstrumentsOpener:
    """``open_instruments`` for the daemon: the drivers on the simulated bench."""

    def __init__(self, model, seed: int):
        self.model = model
        self.seed = seed
        self.bench: SimulatedBench | None = None
        self.trigger_note = ""
        self._stack = contextlib.ExitStack()

    def __call__(self, config: DaemonConfig, clock):
        flange_curve, stage_curve = load_curves(config)
        self.bench = bench = SimulatedBench(
            clock, flange_curve, stage_curve, model=self.model, heater_resistance_ohm=config.heater.resistance_ohm,
            supply=SUPPLY_MODELS[config.instruments.heater_model], seed=self.seed,
            line_frequency_hz=config.instruments.dmm.line_frequency_hz)
        mode = config.instruments.trigger
        timeout = config.instruments.timeout_s
        if config.simulation.transport == "in-process":
            links = bench.in_process_transports(timeout_s=timeout)
            flange, stage, heater = links.flange_dmm, links.ptc_stage_dmm, links.heater_supply
        elif mode == "prologix":
            server = self._stack.enter_context(bench.serve_prologix())
            adapter = PrologixAdapter.ethernet(server.host, server.port, timeout_s=timeout)
            self._stack.callback(adapter.close)
            flange = adapter.instrument(PROLOGIX_ADDRESSES["flange"], name="flange DMM (T2)")
            stage = adapter.instrument(PROLOGIX_ADDRESSES["ptc_stage"], name="PTC-stage DMM (T5)")
            heater = adapter.instrument(PROLOGIX_ADDRESSES["heater"], name="heater supply")
        else:
            resources = self._stack.enter_context(bench.serve_tcp())
            flange, stage, heater = (VisaTransport(resources[key], visa_library="@py", timeout_s=timeout, name=name)
                                     for key, name in (("flange_dmm", "flange DMM (T2)"),
                                                       ("ptc_stage_dmm", "PTC-stage DMM (T5)"),
                                                       ("heater_supply", "heater supply")))

        def external_wire():
            return HardwareTrigger(SerialControlLine(bench.trigger_port, clock), clock,
                                   dmm_input=TriggerSource.EXTERNAL)

        def make_trigger():
            in_process = config.simulation.transport == "in-process"
            if mode == "sequential":
                self.trigger_note = "sequential *TRG"
                return SequentialTrigger([flange, stage], clock)
            if mode == "gpib-group" and in_process:
                self.trigger_note = "GPIB group execute trigger on the simulated board"
                return GpibGroupTrigger(bench.gpib_interface, [flange, stage], clock)
            if mode == "prologix" and not in_process:
                self.trigger_note = "Prologix ++trg on the simulated controller"
                return PrologixGroupTrigger(adapter, [PROLOGIX_ADDRESSES["flange"],
                                                      PROLOGIX_ADDRESSES["ptc_stage"]], clock)
            if mode != "external":
                self.trigger_note = (f"{mode} has no simulated counterpart over this transport: "
                                     f"the simulated external trigger wire (also simultaneous)")
            else:
                self.trigger_note = "the simulated external trigger wire"
            return external_wire()

        try:
            instruments = assemble_instruments(config, clock, flange, stage, heater, make_trigger,
                                               on_close=self._stack.close)
        except BaseException:
            self._stack.close()
            raise
        if isinstance(clock, PacedClock) and config.simulation.transport != "in-process":
            instruments.wait_on_loop_path(config.instruments.timeout_s)
        log.info("simulated instruments over %s; trigger: %s", config.simulation.transport, self.trigger_note)
        return instruments, flange_curve, stage_curve


class SimulationNotStarted(ValueError):
    """The dry run could not start (configuration, calibration, model or command line); says why."""


@dataclasses.dataclass
class SimulationRun:
    """What a dry run leaves: the exit code, the ``--json`` summary and the data files.

    Attributes
    ----------
    exit_code : int
        0, or the daemon's fault code (docs/reference/exit-codes.md).
    summary : dict
        The ``cryod --simulate --json`` object (regulation metrics over the last window, timing, limit).
    log_paths : list of pathlib.Path
        The cryod-log v1 files written (``cryod.read_record`` reads them).
    """

    exit_code: int
    summary: dict
    log_paths: list[Path]


def prepare_simulation(args: DryRunOptions) -> tuple[DaemonConfig, object, Path]:
    """The dry run's configuration, simulated model and its path, or SimulationNotStarted saying why."""
    config_path = args.config or EXAMPLE_CONFIG_PATH
    try:
        config = simulation_config(args, load_config(config_path))
    except FileFormatError as error:
        raise SimulationNotStarted(f"configuration not usable, nothing was started: {error}") from None
    except ValueError as error:
        raise SimulationNotStarted(str(error)) from None
    problem = socket_taken(config.control_socket.path) or check_calibrations(config)
    if problem:
        raise SimulationNotStarted(problem)
    model_path = args.sim_model or config.simulation.model or DEFAULT_MODEL_PATH
    try:
        model = load_model(model_path)
    except FileFormatError as error:
        raise SimulationNotStarted(f"simulated cryostat model not usable: {error}") from None
    problem = limits_against_model(config, model, model_path)
    if problem is not None:
        raise SimulationNotStarted(f"configuration not usable, nothing was started: {problem}")
    return config, model, Path(model_path)


def execute_simulation(args: DryRunOptions, stream=None) -> SimulationRun:
    """Run the daemon on the simulated cryostat as ``args`` say; the log and status line go to ``stream``.

    Raises
    ------
    SimulationNotStarted
        Nothing was started (see :func:`prepare_simulation`).
    """
    stream = stream if stream is not None else sys.stderr
    config, model, model_path = prepare_simulation(args)
    config_path = args.config or EXAMPLE_CONFIG_PATH
    clock = clock_for_speed(args.speed)
    opener = SimulatedInstrumentsOpener(model, config.simulation.seed)
    collector = WindowCollector(args.window_s, config.loop.period_s)
    metadata = {"simulated": "yes (cryod --simulate)", "simulated_model": str(model_path),
                "simulation_seed": config.simulation.seed, "simulation_speed": args.speed,
                "simulation_transport": config.simulation.transport}
    daemon = Daemon(config, opener, clock, metadata=metadata, row_taps=[collector],
                    reload_config=lambda: simulation_config(args, load_config(config_path)),
                    install_signal_handlers=threading.current_thread() is threading.main_thread())
    status_line = StatusLine(daemon.live_view, stream, duration_s=args.duration_s,
                             speed=clock.recent_speed if isinstance(clock, PacedClock) else None)
    logging_service = ServiceLogging(stream=status_line.log_stream)
    logging_service.start()
    status_line.start()
    log.info("talk to it: cryod ctl %sstatus", "" if args.socket is None else f"--socket {config.control_socket.path} ")
    cpu_start = _cpu_seconds()
    try:
        result = daemon.run(args.duration_s)
    except Exception as error:
        logging.getLogger("cryod").critical("simulation stopped: %s: %s", type(error).__name__, error)
        raise
    finally:
        status_line.stop()
        logging_service.stop()
    if daemon.not_started is not None:         # another dry run took the socket meanwhile
        raise SimulationNotStarted(f"{daemon.not_started}; {ANOTHER_SOCKET}")
    summary = summarize(result, collector, model.ptc.angular_frequency_rad_s, _cpu_seconds() - cpu_start)
    summary["achieved_speed"] = achieved_speed(clock, summary["duration_s"], result.wall_s)
    summary.update(simulated_limit(model, config, result.loop, summary["setpoint_K"]))
    summary.update(feedforward_learning(result.loop))
    summary["trigger"] = opener.trigger_note
    return SimulationRun(result.exit_code, summary, list(result.log_paths))


#: What to do when this user's dry run socket is taken.
ANOTHER_SOCKET = "stop that dry run, or give this one a socket of its own with --socket PATH"


def socket_taken(socket_path: Path) -> str | None:
    """Why a dry run cannot use ``socket_path`` (another daemon holds its lock), or None."""
    lock = InstanceLock(socket_path)
    try:
        lock.acquire()
    except AlreadyRunning as error:
        return f"another cryod ({error.holder}) is using the control socket {socket_path}: {ANOTHER_SOCKET}"
    except OSError:
        return None             # the daemon says at its start why the lock cannot be taken
    lock.release()
    return None


def run_simulation(args: DryRunOptions) -> int:
    """Run ``cryod --simulate``; prints the summary, returns the exit code."""
    try:
        run = execute_simulation(args)
    except SimulationNotStarted as error:
        print(f"cryod: {error}", file=sys.stderr)
        return 2
    except Exception as error:
        print(f"cryod: {type(error).__name__}: {error}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(rounded(finite_or_none(run.summary)), indent=2 if args.pretty else None))
    else:
        for key, value in run.summary.items():
            print(f"{key}: {readable_summary(key, value)}")
    return run.exit_code


def simulate(duration_s: float, setpoint_K: float | None = None, *, config: str | Path | None = None,
             sim_model: str | Path | None = None, seed: int | None = None, feedforward: bool = True,
             data_dir: str | Path | None = None, socket: str | Path | None = None, window_s: float = 300.0,
             speed: float | str = "max", log_stream=None) -> SimulationRun:
    """Run the daemon on the simulated cryostat from Python (the same run as ``cryod --simulate``).

    Parameters
    ----------
    duration_s : float
        Simulated seconds to run.
    setpoint_K : float, optional
        Setpoint (default: the configuration's).
    config, sim_model : path, optional
        Daemon configuration (default: the example) and the simulated cryostat's model (default: the shipped).
    seed : int, optional
        Sensor-noise seed.
    feedforward : bool
        False: PI alone.
    data_dir, socket : path, optional
        Where the record goes (default ./cryod-simulate/data) and the control socket (default: this user's).
    window_s : float
        The summary's metrics window (s).
    speed : float or "max"
        Simulated seconds per real second; "max" (default) runs on virtual time.
    log_stream : file, optional
        Where the daemon's log goes (default stderr).

    Returns
    -------
    SimulationRun

    Raises
    ------
    SimulationNotStarted
        A bad configuration, model or argument; nothing ran.
    """
    args = DryRunOptions(config=Path(config) if config else None, duration_s=float(duration_s), speed=speed,
                         json=True, window_s=float(window_s), setpoint_K=setpoint_K,
                         sim_model=Path(sim_model) if sim_model else None, seed=seed, feedforward=feedforward,
                         data_dir=Path(data_dir) if data_dir else None, socket=Path(socket) if socket else None)
    return execute_simulation(args, stream=log_stream)


def readable_summary(key: str, value) -> str:
    """One summary value as text with its unit (lists item by item, the limit's changes one per line)."""
    if key == "feedforward_plant":
        return "".join(f"\n  harmonic {entry['harmonic']}: {entry['gain_ratio']:.3f} x the model's, "
                       f"{entry['phase_deg']:+.1f} deg ({'learned' if entry['learned'] else 'model'})"
                       for entry in value) or "-"
    if key == "feedforward_limit_changes":
        return "".join(f"\n  {change['change']}: {readable('ptc_periodic_limit_K', change['ptc_periodic_limit_K'])}"
                       f" ({change['limited_by'] or change['problem']})" for change in value) or "-"
    if isinstance(value, list):
        return ", ".join(readable(key, item) for item in value) if value else "-"
    return readable(key, value)


def limits_against_model(config: DaemonConfig, model, model_path) -> FileFormatError | None:
    """An over-temperature limit the simulated cryostat is above with the heater off, or None.

    Start-up holds the heater off until both temperatures are below their limits; a limit at or
    below the cryostat's heater-off temperature would hold it off for the whole run, and one
    below the top of the cooler's oscillation at T5 would stop the run at its first peak.

    Parameters
    ----------
    config : DaemonConfig
    model : cryod.model.CryostatModel
        The simulated cryostat.
    model_path : str or pathlib.Path
        Named in the message.

    Returns
    -------
    cryod.yaml_source.FileFormatError or None
        Naming the configuration's file, line and key.
    """
    operating_point = model.operating_point
    stage_peak_K = operating_point.ptc_stage_temperature_K + sum(abs(amplitude) for _, amplitude, _
                                                                 in model.ptc.components())
    if config.safety.ptc_stage_max_K <= stage_peak_K:
        return located_error(config, "safety.ptc_stage_max_K",
                             f"{config.safety.ptc_stage_max_K:g} K: the simulated cryostat's PTC stage is at "
                             f"{operating_point.ptc_stage_temperature_K:g} K with the heater off, up to "
                             f"{stage_peak_K:.3f} K with the cooler's oscillation (model {model_path}), so the "
                             f"heater would never regulate: held off while T5 is above the limit, stopped "
                             f"(over_temperature) at the first peak above it")
    if config.safety.flange_max_K <= operating_point.flange_temperature_K:
        return located_error(config, "safety.flange_max_K",
                             f"{config.safety.flange_max_K:g} K: the simulated cryostat's flange is at "
                             f"{operating_point.flange_temperature_K:g} K with the heater off (model "
                             f"{model_path}), so the heater would never regulate: held off for the whole run")
    return None


def _cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def simulated_limit(model, config: DaemonConfig, loop, setpoint_K: float | None) -> dict:
    """The physical limit of the feedforward on the simulated cryostat (its model, not the controller's;
    a temperature-dependent one linearised about the setpoint) at the run's last setpoint, with the heater
    set as late after T2's reading as the loop set it."""
    term = loop.regulator.term("feedforward") if loop is not None else None
    delay = term.setting_delay_s if term is not None else 0.0
    empty = {"ptc_periodic_limit_K": None, "feedforward_authority": None, "feedforward_limited_by": None,
             "feedforward_limit_bound": None, "feedforward_limit_explained": None, "feedforward_limit_changes": []}
    if setpoint_K is None:
        return empty
    try:
        if model.temperature_dependence is not None:     # the cryostat's linear model about the setpoint
            model = linearised_at(model, setpoint_K)
        limit = feedforward_limit(model, setpoint_K, config.heater.resistance_ohm, config.heater.max_current_A,
                                  config.loop.period_s, heater_delay_s=delay, certify=False)
    except (FeedforwardLimitError, ValueError):
        return empty
    changes = limit_changes(model, setpoint_K, limit.max_heater_power_W, config.loop.period_s, heater_delay_s=delay)
    binding = limit_binding(limit, changes)
    return {"ptc_periodic_limit_K": limit.ptc_periodic_limit_K, "feedforward_authority": round(limit.authority, 4),
            "feedforward_limited_by": limit.limited_by, "feedforward_limit_bound": binding.bound,
            "feedforward_limit_explained": binding.explanation,
            "feedforward_limit_changes": [change.to_dict() for change in changes]}


def achieved_speed(clock, simulated_s: float, wall_s: float) -> float | None:
    """Simulated seconds per real second the run achieved (the paced clock's own figure when it has one)."""
    if isinstance(clock, PacedClock):
        return round(clock.achieved_speed(), 3)
    return round(simulated_s / wall_s, 3) if wall_s > 0 else None


def feedforward_learning(loop) -> dict:
    """What the feedforward learned of the simulated cryostat by the end (nothing without a feedforward term)."""
    term = loop.regulator.term("feedforward") if loop is not None else None
    return term.learning_summary() if term is not None else {}


def summarize(result, collector: WindowCollector, line_rad_s: float, cpu_s: float) -> dict:
    """The ``--json`` object: timing, regulation metrics over the window, where the log is."""
    loop = result.loop
    timing = loop.timing.summary() if loop else {}
    _, flange, stage, setpoint, flange_instants, stage_instants = collector.arrays()
    metrics = regulation_metrics(flange_instants, flange, stage, setpoint, line_rad_s, ptc_stage_time_s=stage_instants,
                                 lead_in_s=TRACKER_LEAD_IN_S)
    # the loop's time in ticks; deadlines an overrun skipped add missed_deadlines periods to the record's span
    duration = timing.get("ticks", 0) * (loop.period_s if loop else 0.0)
    return {
        "duration_s": round(duration, 3),
        "ticks": timing.get("ticks", 0),
        "overruns": timing.get("overruns", 0),
        "missed_deadlines": timing.get("missed_deadlines", 0),
        "lateness_ms_p50": timing.get("lateness_ms_p50"),
        "lateness_ms_p99": timing.get("lateness_ms_p99"),
        "lateness_ms_max": timing.get("lateness_ms_max"),
        "gc_ms_max": timing.get("gc_ms_max"),
        "wall_s": round(result.wall_s, 3),
        "cpu_s": round(cpu_s, 3),
        "cpu_percent_of_one_core": round(100.0 * cpu_s / result.wall_s, 2) if result.wall_s > 0 else None,
        "window_s": round(metrics["window_s"], 3),
        "ptc_line_amplitude_K": metrics["ptc_line_amplitude_K"],
        "ptc_line_rad_s": metrics["ptc_line_rad_s"],
        "ptc_periodic_amplitude_K": metrics["ptc_periodic_amplitude_K"],
        "ptc_harmonic_amplitudes_K": metrics["ptc_harmonic_amplitudes_K"],
        "rms_K": metrics["rms_K"],
        "mean_error_K": metrics["mean_error_K"],
        "lowfreq_rms_K": metrics["lowfreq_rms_K"],
        "setpoint_K": float(setpoint[-1]) if setpoint.size and np.isfinite(setpoint[-1]) else None,
        "state": loop.status.state if loop else None,
        "zone": loop.status.zone if loop else None,
        "last_fault": str(loop.last_fault) if loop and loop.last_fault else None,
        "setpoint_warning": loop.setpoint_warning if loop else None,
        "exit_code": result.exit_code,
        "log_path": str(result.log_paths[0]) if result.log_paths else None,
        "record_path": str(result.log_paths[-1]) if result.log_paths else None,
        "log_paths": [str(path) for path in result.log_paths],
    }
