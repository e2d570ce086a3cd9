"""The lab's own alarm command (``alarms.hook``), run on a thread of its own.

Every change of an alarm (raised, latched, acknowledged, cleared) is offered to the hook
from the loop's thread, which only appends it to a queue. The hook's thread runs the
command with the alarm's details in its environment (``CRYOD_ALARM``, ``CRYOD_ALARM_EVENT``,
``CRYOD_ALARM_MESSAGE``, ``CRYOD_ALARM_VALUE``, ``CRYOD_ALARM_TIME_S``, ``CRYOD_ALARM_UTC``,
``CRYOD_ALARM_SKIPPED``, ``CRYOD_CRYOSTAT``, ``CRYOD_HOST``) and as one JSON object on its
standard input; a command still running after ``timeout_s`` is killed (its whole process
group). Each alarm runs the hook at most once per ``min_interval_s`` of the daemon's clock:
changes in between are folded into the next run, which carries the latest and says how
many it stands for (:class:`HookSchedule`). Nothing the hook does reaches the loop: its
failures are said in the journal.

Examples
--------
>>> from cryod.alarms.latch import Transition
>>> schedule = HookSchedule(min_interval_s=60.0)
>>> schedule.offer(Transition("deviation", "raised", 10.0, "T2 ..."))
>>> [(notice.transition.kind, notice.skipped) for notice in schedule.due(10.0)]
[('raised', 0)]
>>> schedule.offer(Transition("deviation", "cleared", 20.0, "T2 ..."))
>>> schedule.offer(Transition("deviation", "raised", 30.0, "T2 ..."))
>>> schedule.due(40.0), schedule.next_due_s()
([], 70.0)
>>> [(notice.transition.kind, notice.skipped) for notice in schedule.due(70.0)]
[('raised', 1)]
"""

from __future__ import annotations

import collections
import datetime
import json
import logging
import math
import os
import signal
import socket
import subprocess
import threading
from dataclasses import dataclass

from cryod.alarms.latch import Transition
from cryod.alarms.settings import AlarmHook
from drivers.clock import Clock

log = logging.getLogger("cryod.alarms")

#: Wall time between two looks at the schedule while a notice waits for its alarm's interval to end (s).
POLL_S = 0.2
#: Characters of the hook's output quoted in the journal when it fails.
OUTPUT_QUOTED = 300


@dataclass(frozen=True)
class HookNotice:
    """One run of the hook: the latest change of an alarm and how many earlier ones it stands for."""

    transition: Transition
    skipped: int = 0


class HookSchedule:
    """Which changes run the hook when: at most once per ``min_interval_s`` for each alarm (no threads here).

    Parameters
    ----------
    min_interval_s : float
        Least time between two runs for one alarm, in the daemon's clock (s).
    """

    def __init__(self, min_interval_s: float):
        self.min_interval_s = float(min_interval_s)
        self._last_run_s: dict[str, float] = {}
        self._waiting: dict[str, HookNotice] = {}

    def offer(self, transition: Transition) -> None:
        """A change to tell; it replaces one of the same alarm still waiting (counted as skipped)."""
        earlier = self._waiting.get(transition.name)
        self._waiting[transition.name] = HookNotice(transition, 0 if earlier is None else earlier.skipped + 1)

    def due(self, now_s: float) -> list[HookNotice]:
        """The notices to run now (each alarm's interval counts from this run)."""
        ready = [name for name in self._waiting
                 if now_s - self._last_run_s.get(name, -math.inf) >= self.min_interval_s]
        for name in ready:
            self._last_run_s[name] = now_s
        return [self._waiting.pop(name) for name in ready]

    def next_due_s(self) -> float:
        """When the next waiting notice may run (daemon clock, s); inf when none waits."""
        return min((self._last_run_s.get(name, -math.inf) + self.min_interval_s for name in self._waiting),
                   default=math.inf)

    @property
    def waiting(self) -> int:
        """Notices waiting for their alarm's interval to end."""
        return len(self._waiting)


def hook_details(notice: HookNotice, cryostat: str) -> dict[str, str]:
    """The notice's details as the hook's environment variables (strings)."""
    change = notice.transition
    return {"CRYOD_ALARM": change.name, "CRYOD_ALARM_EVENT": change.kind, "CRYOD_ALARM_MESSAGE": change.message,
            "CRYOD_ALARM_VALUE": "" if not math.isfinite(change.value) else repr(float(change.value)),
            "CRYOD_ALARM_TIME_S": f"{change.time_s:.3f}",
            "CRYOD_ALARM_UTC": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "CRYOD_ALARM_SKIPPED": str(notice.skipped), "CRYOD_CRYOSTAT": cryostat, "CRYOD_HOST": socket.gethostname()}


def run_hook(hook: AlarmHook, details: dict[str, str]) -> str | None:
    """Run the hook once (this thread waits for it, at most ``hook.timeout_s``); what went wrong, or None.

    The command gets ``details`` in its environment and as JSON on its standard input; one that is still
    running at the timeout is killed with its process group.
    """
    environment = dict(os.environ, **details)
    payload = json.dumps({key.removeprefix("CRYOD_").lower(): value for key, value in details.items()})
    try:
        process = subprocess.Popen(hook.command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                   stderr=subprocess.STDOUT, env=environment, start_new_session=True,
                                   close_fds=True)
    except OSError as error:
        return f"could not be started: {error}"
    try:
        output, _ = process.communicate(payload.encode("utf-8"), timeout=hook.timeout_s)
    except subprocess.TimeoutExpired:
        try:
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        process.communicate()
        return f"still running after {hook.timeout_s:g} s (alarms.hook.timeout_s): killed"
    if process.returncode != 0:
        text = output.decode("utf-8", "replace").strip()[-OUTPUT_QUOTED:]
        return f"exit {process.returncode}" + (f": {text}" if text else "")
    return None


class AlarmHookRunner:
    """The hook's thread: takes changes from the loop without blocking it, runs the hook as scheduled.

    Parameters
    ----------
    clock : Clock
        The daemon's clock (the intervals between runs are counted on it).
    cryostat : str
        The lab's name for this cryostat (``metrics.cryostat``), passed to the hook.
    hook : AlarmHook or None
        The hook; None: changes are dropped.
    runner : callable, optional
        ``runner(hook, details) -> problem or None`` (default :func:`run_hook`).
    """

    def __init__(self, clock: Clock, cryostat: str = "", hook: AlarmHook | None = None, runner=run_hook):
        self.clock = clock
        self.cryostat = cryostat
        self.hook = hook
        self.runner = runner
        self.schedule = HookSchedule(hook.min_interval_s if hook else 0.0)
        self._incoming: collections.deque[Transition] = collections.deque()
        self._wake = threading.Event()
        self._stopping = False
        self._thread: threading.Thread | None = None
        #: Runs made and runs that failed (for the status and tests).
        self.runs = 0
        self.failures = 0

    def configure(self, hook: AlarmHook | None) -> None:
        """New settings (a reload), from any thread."""
        self.hook = hook
        self._wake.set()

    def offer(self, transition: Transition) -> None:
        """A change to tell (any thread; never waits)."""
        if self.hook is not None:
            self._incoming.append(transition)
            self._wake.set()

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="cryod-alarm-hook", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float | None = None) -> None:
        """Stop after the run under way (waiting at most the hook's timeout); notices waiting are said and dropped."""
        self._stopping = True
        self._wake.set()
        if self._thread is not None:
            hook = self.hook
            self._thread.join(timeout_s if timeout_s is not None else (hook.timeout_s + 1.0 if hook else 1.0))
        left = len(self._incoming) + self.schedule.waiting
        if left:
            log.warning("%d alarm change(s) not passed to the hook: the daemon stopped first", left)

    def _run(self) -> None:
        while not self._stopping:
            self._wake.wait(POLL_S if self.schedule.waiting else None)     # idle: until a change comes
            self._wake.clear()
            hook = self.hook
            if hook is None:
                self._incoming.clear()
                continue
            self.schedule.min_interval_s = hook.min_interval_s
            while self._incoming:
                self.schedule.offer(self._incoming.popleft())
            for notice in self.schedule.due(self.clock.now()):
                if self._stopping:
                    return
                self._run_one(hook, notice)

    def _run_one(self, hook: AlarmHook, notice: HookNotice) -> None:
        self.runs += 1
        try:
            problem = self.runner(hook, hook_details(notice, self.cryostat))
        except Exception as error:      # whatever the hook does, the daemon goes on
            problem = f"{type(error).__name__}: {error}"
        if problem is not None:
            self.failures += 1
            log.warning("alarm hook %s for %s %s: %s", hook.command[0], notice.transition.name,
                        notice.transition.kind, problem)
