"""A thread's scheduling: the loop thread's real-time priority, and normal priority for its workers.

Linux threads inherit the scheduling of the thread that starts them, so a
worker the loop thread starts (the feedforward's limit, its learning after a
reload) would run at the loop's real-time priority and compete with it: such
workers call :func:`at_normal_priority` first. Both the control terms' workers
and the service's loop use these, so they sit in cryod's base layer.
"""

from __future__ import annotations

import os


def set_realtime_priority(priority: int) -> str | None:
    """SCHED_FIFO at ``priority`` for the calling thread; None if done, else why not."""
    if priority <= 0:
        return "real-time priority not requested (loop.realtime_priority: 0)"
    if not hasattr(os, "sched_setscheduler"):
        return "real-time scheduling is not available on this platform"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (PermissionError, OSError) as error:
        return f"real-time priority {priority} not permitted ({error.strerror or error}); running at normal priority"
    return None


def at_normal_priority() -> None:
    """Put the calling thread back on normal scheduling if it inherited a real-time one."""
    if not hasattr(os, "sched_getscheduler"):
        return
    try:
        if os.sched_getscheduler(0) in (os.SCHED_FIFO, os.SCHED_RR):
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except OSError:              # lowering one's own priority is always permitted; nothing else to do
        pass
