"""Signals that end the process, and exceptions nobody caught: the heater off and the reason said first.

Every signal whose action would end the process and that a handler may catch stops the
daemon as SIGTERM does (:func:`terminating_signals`): SIGABRT (what systemd's watchdog sends),
SIGQUIT, SIGUSR1, SIGUSR2, SIGALRM, SIGPWR, the real-time signals, ... SIGHUP reloads. The
process then ends with the heater at 0 W, a journal line and a ``stop`` event in the record
saying which signal, and the exit code :func:`exit_code_for` (0 for SIGTERM and SIGINT, the
shell's 128 + number for the others, so systemd restarts after them).

Left as they are:

- SIGKILL and SIGSTOP, which no process can catch (docs/explanation/safety.md: what protects the
  cryostat then);
- SIGSEGV, SIGBUS, SIGILL and SIGFPE (:data:`CRASH_SIGNALS`): they mean the process itself is
  broken (a fault in compiled code); returning from a handler would run the faulting
  instruction again and hang the process instead of ending it, so they end it at once, with
  every thread's traceback in the journal (:mod:`faulthandler`), like SIGKILL;
- signals already ignored when cryod starts (SIGPIPE and SIGXFSZ, which Python ignores: a write
  to a closed pipe or past the file size limit fails with an error instead, which the part
  that wrote handles; or any a parent process chose to ignore).

A Python signal handler runs in the main thread, which is the loop's, and only between two
bytecodes: while the loop waits for an instrument, it waits too. :class:`SignalWatch`
therefore also reads the signal numbers from :func:`signal.set_wakeup_fd` in a thread of its
own, which learns of each signal at once, whatever the main thread is doing; the daemon uses it
to step in when the loop does not stop in time (:meth:`cryod.service.daemon.Daemon`).

Examples
--------
>>> import signal
>>> signal.SIGABRT in terminating_signals() and signal.SIGHUP not in terminating_signals()
True
>>> exit_code_for(signal.SIGTERM), exit_code_for(signal.SIGABRT)
(0, 134)
>>> signal_received(signal.SIGABRT)
"SIGABRT received (systemd's watchdog sends it when the loop stops feeding it)"
>>> signal_received(signal.SIGTERM)
'SIGTERM received'
"""

from __future__ import annotations

import faulthandler
import logging
import os
import signal
import sys
import threading
from typing import Callable

log = logging.getLogger("cryod.signals")

#: A stop asked for in the usual way (systemctl stop, Ctrl-C): exit 0.
REQUESTED_STOP_SIGNALS = frozenset({signal.SIGTERM, signal.SIGINT})
#: Reloads the configuration.
RELOAD_SIGNAL = signal.SIGHUP
#: The process is broken: left to end it at once (see the module's text).
CRASH_SIGNALS = frozenset({signal.SIGSEGV, signal.SIGBUS, signal.SIGILL, signal.SIGFPE})
#: Signals whose default action ends the process (signal(7): Term and Core), real-time ones aside.
_ENDING_BY_DEFAULT = frozenset(getattr(signal, name) for name in (
    "SIGHUP", "SIGINT", "SIGQUIT", "SIGILL", "SIGTRAP", "SIGABRT", "SIGBUS", "SIGFPE", "SIGUSR1", "SIGSEGV",
    "SIGUSR2", "SIGPIPE", "SIGALRM", "SIGTERM", "SIGSTKFLT", "SIGXCPU", "SIGXFSZ", "SIGVTALRM", "SIGPROF",
    "SIGIO", "SIGPWR", "SIGSYS") if hasattr(signal, name))
#: Who usually sends a signal, for the journal and the record (SIGTERM and SIGINT need no explaining).
_SENDERS = {
    signal.SIGABRT: "systemd's watchdog sends it when the loop stops feeding it",
    signal.SIGQUIT: "Ctrl-\\, or kill -QUIT",
    signal.SIGALRM: "an alarm timer, or kill -ALRM",
}


def terminating_signals() -> list[int]:
    """The signals :class:`SignalWatch` turns into a stop with the heater off, in this process now.

    Those whose default action ends the process (the real-time signals included), except
    SIGKILL and SIGSTOP (uncatchable), :data:`CRASH_SIGNALS`, SIGHUP (reload) and any that is
    ignored at the moment (its default action does not apply)."""
    realtime = range(signal.SIGRTMIN, signal.SIGRTMAX + 1) if hasattr(signal, "SIGRTMIN") else ()
    chosen = []
    for number in sorted(set(_ENDING_BY_DEFAULT) | set(realtime)):
        if number in CRASH_SIGNALS or number == RELOAD_SIGNAL or number not in signal.valid_signals():
            continue
        if signal.getsignal(number) == signal.SIG_IGN:
            continue
        chosen.append(number)
    return chosen


def signal_name(number: int) -> str:
    """``SIGABRT``, ``SIGRTMIN+3``."""
    try:
        return signal.Signals(number).name
    except ValueError:
        return f"SIGRTMIN+{number - signal.SIGRTMIN}" if number > signal.SIGRTMIN else f"signal {number}"


def signal_received(number: int) -> str:
    """``SIGABRT received``, with who usually sends it where that helps (the reason of the stop)."""
    sender = _SENDERS.get(number)
    return f"{signal_name(number)} received ({sender})" if sender else f"{signal_name(number)} received"


def exit_code_for(number: int) -> int:
    """0 after SIGTERM or SIGINT (a stop asked for), 128 + the signal's number after another one."""
    return 0 if number in REQUESTED_STOP_SIGNALS else 128 + int(number)


class SignalWatch:
    """Handlers for the terminating signals and the reload signal, and a thread that sees each signal at once.

    Parameters
    ----------
    on_stop_signal : callable
        ``on_stop_signal(number)``, in the main thread as a signal handler: must only set flags.
    on_reload_signal : callable
        ``on_reload_signal()``, in the main thread as a signal handler.
    on_signal_seen : callable
        ``on_signal_seen(number)`` for each terminating signal, in the watching thread, as soon as
        it arrives (the journal line, and stepping in when the loop does not stop).
    """

    def __init__(self, on_stop_signal: Callable[[int], None], on_reload_signal: Callable[[], None],
                 on_signal_seen: Callable[[int], None]):
        self.on_stop_signal = on_stop_signal
        self.on_reload_signal = on_reload_signal
        self.on_signal_seen = on_signal_seen
        self.signals: list[int] = []
        self._previous: dict[int, object] = {}
        self._previous_wakeup: int | None = None
        self._pipe: tuple[int, int] | None = None
        self._thread: threading.Thread | None = None
        self._faulthandler_was_on = False

    def install(self) -> None:
        """Install the handlers and start the watching thread (main thread only)."""
        self._faulthandler_was_on = faulthandler.is_enabled()
        if not self._faulthandler_was_on and sys.stderr is not None:
            # the crash signals: every thread's traceback into the journal; first, so that the handlers
            # below take SIGABRT from it
            faulthandler.enable(all_threads=True)
        self.signals = terminating_signals()
        read_end, write_end = os.pipe2(os.O_CLOEXEC)
        os.set_blocking(write_end, False)
        self._pipe = (read_end, write_end)
        self._previous_wakeup = signal.set_wakeup_fd(write_end, warn_on_full_buffer=False)
        self._thread = threading.Thread(target=self._watch, name="cryod-signals", daemon=True)
        self._thread.start()
        for number in self.signals:
            self._previous[number] = signal.signal(number, self._stop_handler)
        self._previous[RELOAD_SIGNAL] = signal.signal(RELOAD_SIGNAL, self._reload_handler)

    def _stop_handler(self, number, frame) -> None:
        self.on_stop_signal(number)

    def _reload_handler(self, number, frame) -> None:
        self.on_reload_signal()

    def _watch(self) -> None:
        read_end = self._pipe[0]
        while True:
            try:
                data = os.read(read_end, 64)
            except InterruptedError:
                continue
            except OSError:
                return
            for number in data:
                if number == 0:             # uninstall() is done with us
                    return
                if number in self.signals:
                    try:
                        self.on_signal_seen(number)
                    except Exception:       # noqa: BLE001 - the watch must go on; the loop still stops
                        log.exception("handling %s", signal_name(number))

    def uninstall(self) -> None:
        """The previous handlers back, the watching thread ended (main thread only)."""
        if self._pipe is None:
            return
        for number, handler in self._previous.items():
            signal.signal(number, handler)
        self._previous.clear()
        signal.set_wakeup_fd(self._previous_wakeup if self._previous_wakeup is not None else -1)
        read_end, write_end = self._pipe
        os.set_blocking(write_end, True)
        os.write(write_end, b"\0")
        self._thread.join(2.0)
        os.close(write_end)
        os.close(read_end)
        self._pipe = None
        if not self._faulthandler_was_on and faulthandler.is_enabled():
            faulthandler.disable()


def install_thread_exception_hook(on_exception: Callable[[str, BaseException], None]) -> Callable[[], None]:
    """Route exceptions nobody caught in other threads to ``on_exception(thread name, error)``
    (after the usual traceback); returns what puts the previous hook back."""
    previous = threading.excepthook

    def hook(arguments) -> None:
        if arguments.exc_type is SystemExit:
            return
        name = arguments.thread.name if arguments.thread is not None else "an unnamed thread"
        log.critical("unhandled exception in thread %s", name,
                     exc_info=(arguments.exc_type, arguments.exc_value, arguments.exc_traceback))
        on_exception(name, arguments.exc_value)

    threading.excepthook = hook

    def restore() -> None:
        threading.excepthook = previous
    return restore


__all__ = ["SignalWatch", "terminating_signals", "exit_code_for", "signal_name", "signal_received",
           "install_thread_exception_hook", "CRASH_SIGNALS", "REQUESTED_STOP_SIGNALS", "RELOAD_SIGNAL"]
