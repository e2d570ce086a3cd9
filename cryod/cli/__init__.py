"""Command line of cryod.

    cryod run --config PATH [--check]           the service (--supply-off: only the heater supply to 0 A)
    cryod init DIR --gpib|--prologix-usb|--prologix-lan ...   a new lab's configuration in a folder
    cryod --simulate [--config PATH] [...]      the same daemon on the simulated cryostat
    cryod simulate [...]                        the same as cryod --simulate
    cryod ctl [--socket PATH] COMMAND           talk to the running daemon (found by itself)
    cryod ioc [--config FILE] [--socket PATH]   the daemon as an EPICS IOC (the ioc section's PVs)
    cryod analyze RECORD [...]                  what the simulation gets wrong, and why
    cryod identify RECORD [...]                 fit a model from measured records
    cryod feedforward-limit [...]               the feedforward's physical limit for a heater
    cryod tune [...]                            PI gains from the model, compared
    cryod plot RECORD                           a quick look at a record (PNG beside it)

Errors go to stderr with a non-zero exit code: 2 for unusable input (a bad
configuration, a bad command line), the daemon's fault codes otherwise
(docs/reference/exit-codes.md); 141 (as for SIGPIPE), quietly, when whatever reads the
output stops reading it.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import signal
import sys
from pathlib import Path

from cryod import __version__
from cryod.argument_types import positive, speed, whole_number
from cryod.service.commands import COMMANDS, socket_usage
from cryod.service.discovery import SERVICE_CONFIG as DEFAULT_CONFIG

#: Model tools with a module of their own (``configure_parser(parser)``, ``run(args) -> int``).
MODEL_TOOLS = (
    ("analyze", "cryod.cli.analyze", "what the simulation gets wrong on a record, the cause, the extended model"),
    ("identify", "cryod.cli.identify", "fit the model's transfer functions to measured records"),
    ("feedforward-limit", "cryod.cli.feedforward_limit",
     "the least cooler-synchronous oscillation any heater waveform can leave, and what would change it"),
    ("tune", "cryod.cli.tune", "PI gains for the lab's model and heater, beside the configured ones"),
    ("plot", "cryod.cli.plot", "a quick look at a record: temperatures, heater, cooler line, spectrum"),
)



def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cryod",
        description="Temperature regulation of a pulse-tube cooled cryostat flange.",
        epilog="Dry run: cryod --simulate --duration 600 --speed max --json",
    )
    parser.add_argument("--version", action="version", version=f"cryod {__version__}")
    simulate = parser.add_argument_group("dry run on the simulated cryostat (cryod --simulate ...)")
    simulate.add_argument("--simulate", action="store_true",
                          help="run the daemon against simulated instruments and a simulated cryostat")
    simulate.add_argument("--config", type=Path, default=None, metavar="PATH",
                          help="daemon configuration (default: the example shipped with cryod, cryod/data/cryod.yaml "
                               "in the installed package: config/cryod.yaml of the source tree)")
    simulate.add_argument("--duration", type=positive, default=None, metavar="S",
                          help="simulated seconds to run (default: until stopped)")
    simulate.add_argument("--speed", type=speed, default=1.0,
                          help="simulated seconds per real second, or 'max' for virtual time (default 1); above 1 "
                               "the simulated clock slows when the machine cannot keep that pace (the speed "
                               "achieved is on the status line and in --json's achieved_speed)")
    simulate.add_argument("--json", action="store_true", help="print one summary object on stdout at the end")
    simulate.add_argument("--pretty", action="store_true", help="with --json: indented, one key a line")
    simulate.add_argument("--window", type=positive, default=300.0, metavar="S",
                          help="length of the metrics window at the end, s (default 300)")
    simulate.add_argument("--setpoint", type=positive, default=None, metavar="K", help="setpoint in K (overrides the config)")
    simulate.add_argument("--sim-model", type=Path, default=None, metavar="PATH",
                          help="model file of the simulated cryostat (the controller keeps its config)")
    simulate.add_argument("--seed", type=whole_number, default=None, metavar="N",
                          help="sensor-noise seed (overrides the config)")
    simulate.add_argument("--no-feedforward", action="store_true",
                          help="PI alone: the feedforward locked to the cooler starts switched off")
    simulate.add_argument("--data-dir", type=Path, default=None, metavar="PATH",
                          help="where the data log goes (default ./cryod-simulate/data)")
    simulate.add_argument("--socket", type=Path, default=None, metavar="PATH",
                          help="control socket (default: this user's, $XDG_RUNTIME_DIR/cryod/simulate.sock, "
                               "where `cryod ctl` looks)")
    simulate.add_argument("--transport", choices=("tcp", "in-process"), default=None,
                          help="drivers to simulated instruments over TCP on 127.0.0.1 (default, or "
                               "in-process with --speed max)")

    commands = parser.add_subparsers(dest="command", metavar="COMMAND")
    run = commands.add_parser("run", help="run the service on the real instruments",
                              description="Run the daemon on the real instruments (under systemd: Type=notify).")
    run.add_argument("--config", type=Path, default=DEFAULT_CONFIG, dest="run_config", metavar="PATH",
                     help=f"daemon configuration (default {DEFAULT_CONFIG})")
    run.add_argument("--check", action="store_true",
                     help="only validate the configuration, the calibration files and what they need of this "
                          "computer (VISA library, serial devices, socket owner and folders), then exit; no "
                          "instrument is touched")
    run.add_argument("--duration", type=positive, default=None, dest="run_duration", metavar="S",
                     help="stop after this many seconds (default: until SIGTERM)")
    run.add_argument("--supply-off", action="store_true",
                     help="only set the heater supply to 0 A with its output off, then exit (what the unit runs "
                          "after the daemon ended, however it ended; left alone while another cryod drives it)")

    ctl = commands.add_parser("ctl", help="talk to the running daemon",
                              description="Send one command to the running daemon's control socket.")
    ctl.add_argument("--socket", type=Path, default=None, dest="ctl_socket", metavar="PATH",
                     help="control socket path (default: the service's, from its configuration, if it runs, "
                          "else this user's cryod --simulate)")
    ctl.add_argument("--config", type=Path, default=None, dest="ctl_config", metavar="PATH",
                     help=f"take the socket path from this configuration (the service's is {DEFAULT_CONFIG})")
    ctl.add_argument("--json", action="store_true", dest="ctl_json", help="print the raw JSON reply")
    ctl.add_argument("words", nargs="+", metavar="COMMAND", help=socket_usage())
    ctl.epilog = "commands:\n" + "\n".join(f"  {spec.usage:<20} {spec.help}" for spec in COMMANDS.values()
                                            if spec.from_socket)
    ctl.formatter_class = argparse.RawDescriptionHelpFormatter
    ioc = commands.add_parser("ioc", help="serve the running daemon as an EPICS IOC (Channel Access, pvAccess)",
                              description="Serve the running daemon's readings, settings and alarms as EPICS PVs "
                                          "under the ioc section's prefix (needs cryod[ioc]; docs/reference/exit-codes.md, "
                                          "\"EPICS and Bluesky\"). The daemon is found as cryod ctl finds it.")
    ioc.add_argument("--config", type=Path, default=None, dest="ioc_config", metavar="FILE",
                     help="the configuration whose ioc section is served, and whose control_socket.path is the "
                          "daemon's (default: the configuration the daemon runs on)")
    ioc.add_argument("--socket", type=Path, default=None, dest="ioc_socket", metavar="PATH",
                     help="the daemon's control socket (default: as cryod ctl finds it)")
    commands.add_parser("simulate", help="the same as cryod --simulate (its options follow)", add_help=False)
    from cryod.cli import init

    init.add_parser(commands)
    for name, _, summary in MODEL_TOOLS:      # listed here, loaded only when used (see main)
        commands.add_parser(name, help=summary, add_help=False)
    return parser


#: Options of the dry run (``--simulate``), which mean nothing to the commands.
SIMULATE_ONLY = ("config", "duration", "speed", "json", "pretty", "window", "setpoint", "sim_model", "seed",
                 "no_feedforward", "data_dir", "socket", "transport")


def _misplaced_simulate_options(parser: argparse.ArgumentParser, args) -> list[str]:
    """Dry-run options given without --simulate (``cryod --duration 5 run``), as on the command line."""
    given = [name for name in SIMULATE_ONLY if getattr(args, name) != parser.get_default(name)]
    if args.command in ("ctl", "ioc") and "socket" in given and getattr(args, f"{args.command}_socket") is None:
        given.remove("socket")            # cryod --socket PATH ctl ...: the socket of the daemon to talk to
    return ["--" + name.replace("_", "-") for name in given]


#: The variables by which a user chooses the BLAS libraries' thread count; a number chosen there is kept.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def use_one_blas_thread() -> None:
    """One thread for the BLAS libraries numpy and scipy load, unless the environment chose a number.

    cryod's matrices are tall and narrow (a few columns by up to a few hundred thousand rows in the
    model tools) or tiny (the loop's estimators): a second BLAS thread costs more than it brings
    (``cryod identify`` took 1.7 times as long with two, docs/reference/exit-codes.md), and idle BLAS threads
    spin on the cores the daemon's loop needs. threadpoolctl sets the limit in the libraries already
    loaded, whenever it is called; numpy and scipy each bring their own OpenBLAS, so both are loaded
    first. ``cryod ctl`` loads neither and is not slowed by them.
    """
    if any(name in os.environ for name in BLAS_THREAD_VARIABLES):
        return
    import numpy  # noqa: F401  (its BLAS library)
    import scipy.linalg  # noqa: F401  (scipy's own BLAS library)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")


def _run_model_tool(name: str, argv: list[str]) -> int:
    """``cryod analyze ...``, ``cryod identify ...``, ...: the tool's module parses its own arguments."""
    module = importlib.import_module(dict((n, m) for n, m, _ in MODEL_TOOLS)[name])
    parser = module.configure_parser(argparse.ArgumentParser(prog=f"cryod {name}"))
    args = parser.parse_args(argv)
    use_one_blas_thread()
    return module.run(args)


#: Exit code when the reader of the output went away (``cryod ctl status | head -2``): as a Unix tool killed
#: by SIGPIPE, 128 + 13.
READER_GONE = 128 + signal.SIGPIPE


def main(argv: list[str] | None = None) -> int:
    """Run one cryod command line; the exit code.

    When whatever reads the output stops reading (``cryod ctl status | head -2``), the command
    ends quietly with :data:`READER_GONE`, as Unix tools do, instead of a traceback.
    """
    try:
        code = _main(argv)
        sys.stdout.flush()
    except BrokenPipeError:
        # nothing more can reach the reader; send what Python would flush at exit nowhere
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return READER_GONE
    return code


def _main(argv: list[str] | None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in {name for name, _, _ in MODEL_TOOLS}:
        return _run_model_tool(argv[0], argv[1:])
    if argv and argv[0] == "simulate":
        argv = ["--simulate", *argv[1:]]
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.simulate and args.command:
        parser.error("--simulate runs the daemon itself; do not combine it with a command")
    misplaced = [] if args.simulate else _misplaced_simulate_options(parser, args)
    if misplaced:
        parser.error(f"{', '.join(misplaced)}: option(s) of the dry run (cryod --simulate {misplaced[0]} ...); "
                     f"a command's own options go after it (cryod {args.command or 'COMMAND'} --help)")
    if args.simulate:
        from cryod.service.simulation import DryRunOptions, run_simulation

        use_one_blas_thread()
        return run_simulation(DryRunOptions(
            config=args.config, duration_s=args.duration, speed=args.speed, json=args.json, pretty=args.pretty,
            window_s=args.window,
            setpoint_K=args.setpoint, sim_model=args.sim_model, seed=args.seed, feedforward=not args.no_feedforward,
            data_dir=args.data_dir, socket=args.socket, transport=args.transport))
    if args.command == "run":
        use_one_blas_thread()
        return _run_service(args)
    if args.command == "ctl":
        return _ctl(args)
    if args.command == "ioc":
        return _ioc(args)
    if args.command == "init":
        from cryod.cli import init

        return init.run(args)
    parser.print_help(sys.stderr)
    return 2


def _run_service(args) -> int:
    from cryod.service.daemon import Daemon, config_or_exit
    from cryod.service.instruments import instrument_addresses, open_instruments
    from cryod.service.logs import ServiceLogging
    from cryod.service.startup_checks import check_before_run
    from cryod.service.status_line import StatusLine
    from cryod.yaml_source import FileFormatError
    from drivers.clock import MonotonicClock

    config = config_or_exit(args.run_config, sys.stderr)
    if config is None:
        return 2
    if args.supply_off:                 # the heater off whatever else this computer lacks
        return _supply_off(config)
    try:
        notes = check_before_run(config, before_systemd_start=args.check)
    except FileFormatError as error:
        print(f"cryod: configuration not usable on this computer, nothing was started: {error}", file=sys.stderr)
        return 2
    if args.check:
        for note in notes:
            print(f"note: {note}")
        print(f"{args.run_config}: configuration and calibration files are valid, and this computer has what "
              f"they name")
        return 0
    daemon = Daemon(config, open_instruments, MonotonicClock(), instrument_addresses=instrument_addresses)
    status_line = StatusLine(daemon.live_view, sys.stderr, duration_s=args.run_duration)   # a terminal only
    logging_service = ServiceLogging(stream=status_line.log_stream)
    logging_service.start()
    status_line.start()
    try:
        result = daemon.run(args.run_duration)
    except Exception as error:
        print(f"cryod: stopped: {type(error).__name__}: {error}", file=sys.stderr)
        return 1
    finally:
        status_line.stop()
        logging_service.stop()
    return result.exit_code


def _ioc(args) -> int:
    """``cryod ioc``: the EPICS IOC, when softioc (cryod[ioc]) is installed."""
    try:
        import softioc  # noqa: F401
    except ImportError as error:
        print(f"cryod ioc: pythonSoftIOC is not installed ({error}); install cryod with its ioc extra: "
              f"pip install 'cryod[ioc]'", file=sys.stderr)
        return 2
    from cryod.ioc.process import run
    from cryod.service.logs import ServiceLogging

    logging_service = ServiceLogging()
    logging_service.start()
    try:
        return run(args.ioc_config, args.ioc_socket or args.socket)
    finally:
        logging_service.stop()


def _supply_off(config) -> int:
    """``cryod run --supply-off``: 0 done, 2 another cryod drives the supply, 4 the supply out of reach."""
    from cryod.service.instance_lock import InstrumentInUse
    from cryod.service.instruments import switch_supply_off
    from drivers.clock import MonotonicClock
    from drivers.errors import InstrumentError

    ended = ", ".join(f"{name} {os.environ[name]}" for name in ("SERVICE_RESULT", "EXIT_CODE", "EXIT_STATUS")
                      if os.environ.get(name))          # how the daemon ended, when systemd runs this
    after = f" (the daemon ended: {ended})" if ended else ""
    try:
        switch_supply_off(config, MonotonicClock())
    except InstrumentInUse as error:
        print(f"cryod: supply left alone{after}: {error}", file=sys.stderr)
        return 2
    except (InstrumentError, OSError) as error:
        print(f"cryod: could not switch the heater supply off{after}: {error}; check it at the supply",
              file=sys.stderr)
        return 4
    print(f"cryod: heater supply at 0 A, output off{after}", file=sys.stderr)
    return 0


def interfaces_line(interfaces: dict | None) -> str:
    """The interfaces process in one line of ``cryod ctl status``: where it serves, and what is wrong."""
    if not interfaces:
        return "none configured (web, lakeshore336, metrics.address and alarms.hook are off)"
    if not interfaces.get("running"):
        return (f"NOT running (ended: {interfaces.get('last_exit') or 'unknown'}; started again "
                f"{interfaces.get('restarts', 0)} times)")
    served = [f"{name} {interfaces[name]}" for name in ("web", "lakeshore336", "metrics") if interfaces.get(name)]
    hook = interfaces.get("alarm_hook")
    if hook:
        served.append(f"alarm hook {hook.get('command')} ({hook.get('runs', 0)} runs, {hook.get('failures', 0)} "
                      f"failed)")
    text = f"pid {interfaces.get('pid')}: " + (", ".join(served) or "starting")
    problems = interfaces.get("problems") or []
    if interfaces.get("restarts"):
        text += f"; started again {interfaces['restarts']} times (last end: {interfaces.get('last_exit')})"
    return text + (f"; PROBLEMS: {'; '.join(problems)}" if problems else "")


def _ctl(args) -> int:
    from cryod.service.control_socket import CLIENT_TIMEOUT_S, send_command
    from cryod.service.discovery import find_daemon_socket
    from cryod.yaml_source import FileFormatError

    path = args.ctl_socket or args.socket
    if path is None and args.ctl_config is not None:
        from cryod.service.daemon import config_or_exit

        config = config_or_exit(args.ctl_config, sys.stderr)
        if config is None:
            return 2
        path = config.control_socket.path
    try:
        if path is None:
            path = find_daemon_socket()
    except FileFormatError as error:
        print(f"cryod ctl: the service's configuration is not usable to find its socket: {error}; "
              f"give --socket PATH", file=sys.stderr)
        return 2
    except ConnectionError as error:
        print(f"cryod ctl: {error}", file=sys.stderr)
        return 3
    try:
        reply = send_command(path, " ".join(args.words), on_busy=lambda message: print(
            f"cryod ctl: the daemon answered {message}; trying again for up to {CLIENT_TIMEOUT_S:g} s",
            file=sys.stderr))
    except ValueError as error:
        print(f"cryod ctl: {error}", file=sys.stderr)
        return 2
    except (ConnectionError, OSError) as error:
        print(f"cryod ctl: {error}", file=sys.stderr)
        return 3
    if args.ctl_json:
        print(json.dumps(reply))
    elif reply.get("message") == "status" and reply.get("ok"):
        from cryod.service.alarms import alarm_line
        from cryod.service.readable import readable

        for key, value in reply["status"].items():
            if key == "time_s":
                key = "daemon_clock_s"          # the daemon's monotonic clock, not a date
            if key == "alarms":
                print("alarms: none raised" if not value else "alarms:")
                for alarm in value or []:
                    print(f"  {alarm_line(alarm)}")
                continue
            if key == "alarm_states":           # the metrics' view of the alarms above
                continue
            if key == "interfaces":
                print(f"interfaces: {interfaces_line(value)}")
                continue
            print(f"{key}: {readable(key, value)}")
    else:
        print(reply.get("message", ""), file=sys.stdout if reply.get("ok") else sys.stderr)
    return 0 if reply.get("ok") else 1

