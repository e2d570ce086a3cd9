"""Real-time aids for the loop thread: scheduling priority, memory locking, garbage collection.

Each is used when the system permits it; when it does not, the reason is
returned for the log and the daemon carries on.

A thread's scheduling itself (the loop's real-time priority, the normal one
its workers go back to) is in :mod:`cryod.thread_priority`. A run
leaves the process as it found it (:class:`RealtimeSession`), which matters
when the daemon runs inside another program (the tests, ``cryod.simulate``).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import os
import time

from cryod.thread_priority import set_realtime_priority

MCL_CURRENT = 1
MCL_FUTURE = 2
MCL_ONFAULT = 4         # Linux 4.4: lock pages as they are touched, not every page that is mapped


def unlock_memory() -> None:
    """Undo :func:`lock_memory` (``munlockall``)."""
    name = ctypes.util.find_library("c")
    if name is not None:
        ctypes.CDLL(name, use_errno=True).munlockall()


class RealtimeSession:
    """The loop thread's real-time priority and memory locking for one run, undone at its end.

    Parameters
    ----------
    priority : int
        SCHED_FIFO priority for the calling thread; 0 leaves it as it is.
    lock : bool
        Lock the process's memory (:func:`lock_memory`).
    """

    def __init__(self, priority: int, lock: bool):
        self.priority = priority
        self.lock = lock
        self.problems: list[str] = []        #: what could not be done, for the log
        self.memory = ""                     #: the memory figure after locking
        self._saved: tuple[int, os.sched_param] | None = None
        self._locked = False

    def start(self) -> None:
        """Raise the calling thread's priority and lock memory as asked."""
        if hasattr(os, "sched_getscheduler"):
            self._saved = (os.sched_getscheduler(0), os.sched_getparam(0))
        problem = set_realtime_priority(self.priority)
        if problem:
            self.problems.append(problem)
        if self.lock:
            problem, self.memory = lock_memory()
            self._locked = problem is None
            if problem:
                self.problems.append(problem)

    def end(self) -> None:
        """Give back the calling thread's earlier scheduling and unlock memory if it was locked here."""
        if self._saved is not None:
            policy, parameters = self._saved
            try:
                os.sched_setscheduler(0, policy, parameters)
            except OSError:
                pass
            self._saved = None
        if self._locked:
            unlock_memory()
            self._locked = False


def lock_memory() -> tuple[str | None, str]:
    """Keep the daemon's pages in memory: ``mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT)``.

    With ``MCL_ONFAULT`` only the pages the process touches are locked (what
    the loop and the rest of the daemon use), not every page it maps: the
    shared libraries of numpy and scipy map several hundred MB that are never
    read, and locking them all would make them resident.

    Returns
    -------
    (problem, figure)
        ``problem``: None if done, else why not (for a warning); ``figure``:
        locked and resident memory now, for the start-up log.
    """
    name = ctypes.util.find_library("c")
    if name is None:
        return "memory locking: C library not found", memory_figure()
    libc = ctypes.CDLL(name, use_errno=True)
    if libc.mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT) != 0:
        errno = ctypes.get_errno()
        return f"memory locking not permitted ({os.strerror(errno)}); pages may be swapped", memory_figure()
    return None, memory_figure()


def memory_figure() -> str:
    """Resident and locked memory from /proc/self/status (empty where there is none).

    With ``MCL_ONFAULT`` the locked figure (VmLck) is the size of the locked
    mappings, pages not yet touched included; what is pinned in memory is what
    is resident.
    """
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            fields = dict(line.split(":", 1) for line in status if ":" in line)
    except OSError:
        return ""
    megabytes = {key: int(fields[key].split()[0]) / 1024 for key in ("VmLck", "VmRSS") if key in fields}
    if len(megabytes) < 2:
        return ""
    return (f"{megabytes['VmRSS']:.0f} MB resident; {megabytes['VmLck']:.0f} MB of mappings locked "
            f"(their pages stay in memory once used; untouched pages are not loaded)")


class LoopGarbageCollector:
    """Keeps the garbage collector out of the tick: collect only in the slack after a cycle.

    Automatic collection is switched off; :meth:`collect_if_time` runs a young
    generation collection when the remaining slack allows it and the young
    generation holds ``young_objects`` new objects (the interpreter's own
    threshold for its automatic collection, by default: what it would collect,
    only in the slack instead of anywhere in the tick), and an older one every
    ``full_every`` collections with enough slack (Klipper's approach).
    """

    def __init__(self, minimum_slack_s: float = 0.02, full_every: int = 750, young_objects: int | None = None):
        self.minimum_slack_s = minimum_slack_s
        self.full_every = full_every
        self.young_objects = gc.get_threshold()[0] if young_objects is None else young_objects
        self._calls = 0
        self._was_enabled = gc.isenabled()
        self.longest_s = 0.0          # longest collection so far (real time)

    def start(self) -> None:
        gc.collect()
        gc.freeze()
        gc.disable()

    def stop(self) -> None:
        gc.unfreeze()
        if self._was_enabled:
            gc.enable()

    def collect_if_time(self, slack_s: float) -> None:
        """Collect while ``slack_s`` seconds remain before the next deadline."""
        if slack_s < self.minimum_slack_s or gc.get_count()[0] < self.young_objects:
            return
        self._calls += 1
        generation = 2 if self._calls % self.full_every == 0 else (1 if self._calls % 50 == 0 else 0)
        started = time.perf_counter()
        gc.collect(generation)
        self.longest_s = max(self.longest_s, time.perf_counter() - started)
