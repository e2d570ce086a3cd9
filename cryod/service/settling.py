"""When the flange has settled at its setpoint: the one rule the Python client's wait and the IOC's STABLE use.

Settled means: the loop regulates (closed, also while held at a heater bound), the ramp has reached
the target, and for ``hold_s`` of the daemon's clock every status looked at had T2 averaged over its
last 10 s (``T2_average_K``: 17 cooler periods, so the cooler's 0.5 to 1.8 mK line averages out)
within ``tolerance_K`` of the setpoint. Time is the daemon's own clock, so a sped-up dry run settles
as fast as it runs. A loop that is off, manual, stopped or in a fault cannot settle: the watch says
why, and the client's wait gives up on it.

:class:`SettlingWatch` is fed one status after another (the client polls ``status``; the IOC takes
each line of the stream) and says where each one leaves the flange.

Examples
--------
>>> from cryod.service.daemon_status import DaemonStatus, LoopStatus, RecentFigures
>>> def status(time_s, average_K):
...     loop = LoopStatus(time_s=time_s, state="closed", flange_K=average_K, setpoint_K=5.0, target_K=5.0)
...     return DaemonStatus(loop=loop, recent=RecentFigures(flange_average_K=average_K))
>>> watch = SettlingWatch(tolerance_K=1e-4, hold_s=60.0)
>>> [watch.observe(status(t, 5.00002)).stable for t in (0.0, 30.0, 60.0)]
[False, False, True]
>>> watch.observe(status(61.0, 5.0003)).stable            # 300 µK off: the hold starts again
False
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cryod.service.daemon_status import DaemonStatus

#: Loop states in which the flange cannot settle (a wait for it gives up): the heater is not regulated.
NOT_REGULATING = ("off", "stopped", "manual")
#: The ramp has reached the target when the setpoint in use is this close to it (K).
AT_TARGET_K = 1e-9


@dataclass(frozen=True)
class Settling:
    """Where one status leaves the flange.

    Attributes
    ----------
    stable : bool
        Settled: within the tolerance for the whole hold time.
    error_K : float or None
        T2 averaged over 10 s less the setpoint; None while ramping, before the average exists, or
        while not regulating.
    settled_for_s : float
        How long (the daemon's clock) T2's average has been within the tolerance without a break (s).
    cannot_settle : str or None
        Why the flange cannot settle as things are (the loop is off, manual, stopped, in a fault, or the
        daemon is not running its loop yet); None while it can.
    state, setpoint_K, target_K, time_s
        The status' state, setpoint in use, target and daemon clock (for messages).
    """

    stable: bool
    error_K: float | None
    settled_for_s: float
    cannot_settle: str | None
    state: str
    setpoint_K: float | None
    target_K: float | None
    time_s: float

    def where(self) -> str:
        """Where the flange is, in words: T2's averaged error, or the state when there is none."""
        if self.error_K is not None:
            return f"T2 averaged over 10 s {self.error_K * 1e6:+.1f} µK from the setpoint"
        return f"state {self.state}, setpoint {self.setpoint_K}, target {self.target_K}"


class SettlingWatch:
    """Follows statuses one after another and says when the flange has settled.

    Parameters
    ----------
    tolerance_K : float
        Largest distance of T2's 10 s average from the setpoint (K).
    hold_s : float
        How long it must stay within it (s of the daemon's clock).
    """

    def __init__(self, tolerance_K: float = 1e-4, hold_s: float = 60.0):
        if not tolerance_K > 0 or not hold_s >= 0:
            raise ValueError(f"tolerance_K must be above 0 and hold_s not below 0 (got {tolerance_K}, {hold_s})")
        self.tolerance_K = float(tolerance_K)
        self.hold_s = float(hold_s)
        self._settled_since: float | None = None

    def restart(self) -> None:
        """Forget the hold so far (a new setpoint was asked for)."""
        self._settled_since = None

    def observe(self, status: DaemonStatus) -> Settling:
        """Where ``status`` leaves the flange; statuses come in the order of the daemon's clock."""
        loop, now = status.loop, status.loop.time_s
        state = loop.state
        cannot = None
        if status.waiting_for is not None or not math.isfinite(now):
            cannot = f"the daemon is not regulating yet ({status.waiting_for or state})"
        elif state.startswith("fault") or state in NOT_REGULATING:
            cannot = f"the loop is {state}, not regulating" + (f" (last fault: {loop.last_fault})"
                                                               if loop.last_fault else "")
        setpoint, target = loop.setpoint_K, loop.target_K
        average = status.recent.flange_average_K if status.recent is not None else math.nan
        ramping = setpoint is None or target is None or abs(setpoint - target) > AT_TARGET_K
        error = (None if cannot or ramping or not math.isfinite(average) or not status.regulating
                 else average - setpoint)
        if error is None or abs(error) > self.tolerance_K:
            self._settled_since = None
        elif self._settled_since is None:
            self._settled_since = now
        settled_for = 0.0 if self._settled_since is None else now - self._settled_since
        return Settling(stable=self._settled_since is not None and settled_for >= self.hold_s, error_K=error,
                        settled_for_s=settled_for, cannot_settle=cannot, state=state, setpoint_K=setpoint,
                        target_K=target, time_s=now)


__all__ = ["Settling", "SettlingWatch", "NOT_REGULATING"]
