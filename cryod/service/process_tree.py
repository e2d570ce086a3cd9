"""A child process and everything it started, ended together: new sessions and orphans included.

An alarm hook is a command of the lab's, and a command can leave processes behind:
``sleep 100 &`` in its process group, ``setsid sleep 100 &`` in a session of its own, a
daemonising helper whose parent has exited. Killing the hook's process group misses the last
two, and a process that keeps the hook's output pipe open would keep a reader of that pipe
waiting for good. So the process that runs hooks makes itself the *child subreaper* of its
descendants (``prctl(PR_SET_CHILD_SUBREAPER)``, Linux 3.4): an orphaned descendant is handed
to it rather than to init, and so stays findable as one of its children. :class:`ProcessTree`
follows one child's tree through ``/proc`` (parent links, and the children handed to this
process that started after the child did), kills all of it at once and reaps what became
this process's own.

Examples
--------
>>> import subprocess, sys
>>> child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"], start_new_session=True)
>>> tree = ProcessTree(child.pid)
>>> tree.end() >= 1
True
>>> child.wait(5) != 0
True
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal
import time
from pathlib import Path

#: prctl option that makes the calling process the reaper of its orphaned descendants (linux/prctl.h).
PR_SET_CHILD_SUBREAPER = 36
#: /proc/PID/stat fields (from 1): the parent's pid and the start time in clock ticks since boot.
_PARENT_FIELD, _START_FIELD = 4, 22
#: How often, and how far apart, a killed orphan is looked for to be reaped (a second in all).
REAP_TRIES, REAP_PAUSE_S = 100, 0.01


def become_subreaper() -> bool:
    """Make this process the reaper of its orphaned descendants; False where the system does not allow it."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return libc.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _stat_fields(pid: int) -> tuple[int, int] | None:
    """(parent pid, start time in ticks) of ``pid``, None when it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    # the command's name (field 2) is in parentheses and may hold spaces: split after its closing one
    fields = text[text.rindex(")") + 2:].split()
    return int(fields[_PARENT_FIELD - 3]), int(fields[_START_FIELD - 3])


def _processes() -> dict[int, tuple[int, int]]:
    """Every process now: pid -> (parent pid, start time)."""
    found = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            fields = _stat_fields(int(entry))
            if fields is not None:
                found[int(entry)] = fields
    return found


class ProcessTree:
    """One child of this process and its descendants, wherever they moved.

    Parameters
    ----------
    root_pid : int
        The child (started by this process).
    """

    def __init__(self, root_pid: int):
        self.root_pid = int(root_pid)
        fields = _stat_fields(self.root_pid)
        self.started = fields[1] if fields else 0
        #: Every pid seen in the tree, with its start time (a pid used again by another process is not it).
        self.seen: dict[int, int] = {}
        self.look()

    def look(self) -> list[int]:
        """The tree's processes alive now (the child first, when alive), remembered for :meth:`end`."""
        processes = _processes()
        own = os.getpid()
        members = {pid for pid, (parent, started) in processes.items()
                   if pid == self.root_pid or (parent == own and pid != self.root_pid and started >= self.started)}
        members |= {pid for pid, started in self.seen.items() if processes.get(pid, (0, -1))[1] == started}
        grown = True
        while grown:                                # the descendants of every member, by parent links
            more = {pid for pid, (parent, _) in processes.items() if parent in members} - members
            grown = bool(more)
            members |= more
        for pid in members:
            self.seen.setdefault(pid, processes[pid][1])
        return sorted(members, key=lambda pid: pid != self.root_pid)

    def end(self) -> int:
        """Kill every process of the tree (SIGKILL) and reap those that are this process's children (the root
        is left to its ``Popen``); how many were killed."""
        killed = 0
        for _ in range(5):                          # a process forked while the others were killed
            alive = [pid for pid in self.look() if not _is_zombie(pid)]
            if not alive:
                break
            for pid in alive:
                try:
                    os.kill(pid, signal.SIGKILL)
                    killed += 1
                except ProcessLookupError:
                    pass
        self._reap()
        return killed

    def _reap(self) -> None:
        """Collect the orphans handed to this process (the root is its Popen's to wait for)."""
        own = os.getpid()
        for pid, started in self.seen.items():
            fields = _stat_fields(pid)
            if pid == self.root_pid or fields is None or fields[0] != own or fields[1] != started:
                continue
            for _ in range(REAP_TRIES):               # killed: gone within moments, unless stuck in the kernel
                try:
                    if os.waitpid(pid, os.WNOHANG)[0] == pid:
                        break
                except ChildProcessError:
                    break
                time.sleep(REAP_PAUSE_S)


def _is_zombie(pid: int) -> bool:
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True
    return text[text.rindex(")") + 2:].startswith("Z")


__all__ = ["ProcessTree", "become_subreaper"]
