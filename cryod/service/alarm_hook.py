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
import selectors
import shutil
import socket
import subprocess
import threading
import time
from dataclasses import dataclass
from typing import Protocol

from cryod.alarms.latch import Transition
from cryod.alarms.settings import AlarmHook
from cryod.service.process_tree import ProcessTree, become_subreaper

log = logging.getLogger("cryod.alarms")

#: Wall time between two looks at the schedule while a notice waits for its alarm's interval to end (s).
POLL_S = 0.2
#: Characters of the hook's output quoted in the journal when it fails.
OUTPUT_QUOTED = 300
#: Bytes of the hook's output held (its last ones); the rest is read and dropped.
OUTPUT_KEPT = 64 * 1024
#: Bytes read from the hook's output at a time.
READ_CHUNK = 64 * 1024
#: Wall time between two looks at the hook's process tree while it runs (s).
TREE_LOOK_S = 0.1


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
    """Run the hook once (this thread waits for it, at most ``hook.timeout_s`` and a moment); what went wrong,
    or None.

    The command gets ``details`` in its environment and as JSON on its standard input. Its output (standard
    output and error together) is read as it comes and only the last :data:`OUTPUT_KEPT` bytes are held, however
    much it writes. The run is over when the command has exited and its output has ended; at ``timeout_s`` what
    is still running of its process tree (its process group, processes it moved to sessions of their own, their
    orphans: :class:`~cryod.service.process_tree.ProcessTree`) is killed, and the output is no longer read.
    """
    environment = dict(os.environ, **details)
    payload = json.dumps({key.removeprefix("CRYOD_").lower(): value for key, value in details.items()})
    try:
        process = subprocess.Popen(hook.command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                   stderr=subprocess.STDOUT, env=environment, start_new_session=True,
                                   close_fds=True)
    except OSError as error:
        return f"could not be started: {error}"
    deadline = time.monotonic() + hook.timeout_s
    tree = ProcessTree(process.pid)
    output = bytearray()
    ended, exited = False, False
    assert process.stdin is not None and process.stdout is not None        # both asked for as pipes above
    try:
        _give(process.stdin, payload.encode("utf-8"))
        ended = _read_until_done(process, process.stdout, tree, output, deadline)
    finally:
        exited = process.poll() is not None
        left = tree.end()
        process.stdout.close()
        process.wait()
    text = output.decode("utf-8", "replace").strip()[-OUTPUT_QUOTED:]
    if not ended and not exited:
        return f"still running after {hook.timeout_s:g} s (alarms.hook.timeout_s): killed"
    if not ended:
        return (f"exited, but left {left} process(es) running that held its output open until {hook.timeout_s:g} s "
                f"(alarms.hook.timeout_s): killed" + (f"; its output: {text}" if text else ""))
    if process.returncode != 0:
        return f"exit {process.returncode}" + (f": {text}" if text else "")
    return None


def _give(pipe, data: bytes) -> None:
    """The hook's standard input, written without waiting on a hook that does not read it, then closed."""
    try:
        os.set_blocking(pipe.fileno(), False)
        os.write(pipe.fileno(), data)             # less than a pipe's buffer: taken at once or not at all
    except (BlockingIOError, BrokenPipeError):
        pass
    finally:
        try:
            pipe.close()
        except BrokenPipeError:
            pass


def _read_until_done(process: subprocess.Popen, stdout, tree: ProcessTree, output: bytearray, deadline: float) -> bool:
    """Read the hook's output (``stdout``) into ``output`` (its last :data:`OUTPUT_KEPT` bytes) until the hook has
    exited and its output ended (True), or until ``deadline`` (False)."""
    descriptor = stdout.fileno()
    os.set_blocking(descriptor, False)
    with selectors.DefaultSelector() as selector:
        selector.register(descriptor, selectors.EVENT_READ)
        output_open = True
        next_look_s = 0.0
        while True:
            now = time.monotonic()
            if now >= next_look_s:                  # its descendants, before an exit hands them to this process
                tree.look()
                next_look_s = now + TREE_LOOK_S
            left_s = deadline - now
            if not output_open and process.poll() is not None:
                return True
            if left_s <= 0.0:
                return False
            if not output_open:
                try:
                    process.wait(min(left_s, POLL_S))
                except subprocess.TimeoutExpired:
                    pass
                continue
            if selector.select(min(left_s, POLL_S)):
                try:
                    chunk = os.read(descriptor, READ_CHUNK)
                except BlockingIOError:
                    continue
                if not chunk:
                    output_open = False
                    continue
                output += chunk
                del output[:-OUTPUT_KEPT]


class TimeNow(Protocol):
    """What the hook's schedule reads of a clock: the daemon's time now (s)."""

    def now(self) -> float: ...


class AlarmHookRunner:
    """The hook's thread: takes changes from the loop without blocking it, runs the hook as scheduled.

    Parameters
    ----------
    clock : TimeNow
        The daemon's clock (the intervals between runs are counted on it).
    cryostat : str
        The lab's name for this cryostat (``metrics.cryostat``), passed to the hook.
    hook : AlarmHook or None
        The hook; None: changes are dropped.
    runner : callable, optional
        ``runner(hook, details) -> problem or None`` (default :func:`run_hook`).
    """

    def __init__(self, clock: TimeNow, cryostat: str = "", hook: AlarmHook | None = None, runner=run_hook):
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
        #: What went wrong with the last run, or why the hook cannot run at all (None: the last run went well).
        self.problem: str | None = None

    def configure(self, hook: AlarmHook | None) -> None:
        """New settings (a reload), from any thread."""
        self.hook = hook
        self._check_command()
        self._wake.set()

    def _check_command(self) -> None:
        """Say at once, in the journal and :attr:`problem`, when the hook's command cannot be run at all."""
        hook = self.hook
        if hook is None:
            self.problem = None
            return
        program = hook.command[0]
        found = shutil.which(program) if os.sep not in program else (program if os.access(program, os.X_OK) else None)
        if found is None:
            self.problem = (f"{program} cannot be run (not found, or not executable by this user): alarm changes "
                            f"are not passed on (alarms.hook.command)")
            log.error("alarm hook: %s", self.problem)
        else:
            self.problem = None

    def status(self) -> dict:
        """The hook channel for the status: its command, runs, failures, the last problem (None when all is well)."""
        hook = self.hook
        return {"command": hook.command[0] if hook else None, "runs": self.runs, "failures": self.failures,
                "waiting": len(self._incoming) + self.schedule.waiting, "problem": self.problem}

    def offer(self, transition: Transition) -> None:
        """A change to tell (any thread; never waits)."""
        if self.hook is not None:
            self._incoming.append(transition)
            self._wake.set()

    def start(self) -> None:
        """Run hooks from a thread of its own; this process becomes the reaper of what they leave behind
        (:func:`~cryod.service.process_tree.become_subreaper`), so that nothing a hook starts outlives its run."""
        if self.hook is not None and not become_subreaper():
            log.warning("alarm hook: this system does not hand orphaned processes to the daemon (prctl "
                        "PR_SET_CHILD_SUBREAPER): a process a hook moves to a session of its own and leaves behind "
                        "may outlive it")
        self._check_command()
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
        self.problem = problem
        if problem is not None:
            self.failures += 1
            log.warning("alarm hook %s for %s %s: %s", hook.command[0], notice.transition.name,
                        notice.transition.kind, problem)
