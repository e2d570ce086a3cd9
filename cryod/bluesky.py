"""Bluesky: a cryod IOC as an ophyd-async device (``pip install 'cryod[bluesky]'``).

:class:`Cryostat` reads and drives one cryostat through the PVs of ``cryod ioc`` (Channel Access by
default, pvAccess with ``pva://`` before the prefix): ``bps.mv(cryostat, 5.2)`` puts 5.2 K to
``SETPOINT`` with completion, which cryod's IOC completes once ``STABLE`` (T2's 10 s average within
the IOC's tolerance of the setpoint for its hold time, the rule of ``wait_until_stable``), and checks
that it is; ``count([cryostat])`` records T2 (hinted), T5, the heater's power and level, T2's 10 s
average and the cooler line, with the line's limit, the setpoint and STABLE's tolerance and hold time
as configuration. Units, precisions and limits come from the PVs (EGU, PREC, DRVL/DRVH), so the
device is right for whatever ``control.setpoint_min_K``/``setpoint_max_K`` the daemon runs on.

Examples
--------
An experiment's plan (not run here)::

    from bluesky import RunEngine, plans as bp, plan_stubs as bps
    from cryod.bluesky import Cryostat

    cryostat = Cryostat("CRYO1:", name="cryostat")
    RE = RunEngine()
    RE(ensure_connected(cryostat))                 # bluesky.plan_stubs.ensure_connected
    RE(bps.mv(cryostat, 5.2))                      # returns when cryod says stable at 5.2 K
    RE(bp.count([cryostat], num=10, delay=1.0))
"""

from __future__ import annotations

import asyncio

from ophyd_async.core import AsyncStatus, StandardReadable, wait_for_value
from ophyd_async.core import StandardReadableFormat as Format
from ophyd_async.epics.core import epics_signal_r, epics_signal_rw

#: How long after the put's completion STABLE may take to read 1 (its update and the completion travel apart), s.
STABLE_SHOWN_S = 5.0


class NotStableError(RuntimeError):
    """A move ended without the flange settled at the setpoint (a newer setpoint, a heater-off, a fault, the IOC's
    settle timeout); the message has cryod's words."""


class Cryostat(StandardReadable):
    """One cryostat regulated by cryod, through its IOC.

    Parameters
    ----------
    prefix : str
        ``ioc.prefix`` of the cryostat's IOC (``CRYO1:``); ``pva://CRYO1:`` for pvAccess.
    name : str
    settle_timeout_s : float or None
        The longest a move waits for STABLE (None: as long as the IOC waits, ``ioc.settle_timeout_s``).
    """

    def __init__(self, prefix: str, name: str = "", settle_timeout_s: float | None = None):
        self.settle_timeout_s = settle_timeout_s
        with self.add_children_as_readables(Format.HINTED_SIGNAL):
            self.flange = epics_signal_r(float, prefix + "T2")
        with self.add_children_as_readables():
            self.ptc_stage = epics_signal_r(float, prefix + "T5")
            self.heater = epics_signal_r(float, prefix + "HEATER")
            self.heater_level = epics_signal_r(float, prefix + "HEATER_MEAN")
            self.flange_average = epics_signal_r(float, prefix + "T2_AVG")
            self.line = epics_signal_r(float, prefix + "LINE")
        with self.add_children_as_readables(Format.CONFIG_SIGNAL):
            self.line_limit = epics_signal_r(float, prefix + "LINE_LIMIT")
            self.target = epics_signal_r(float, prefix + "SETPOINT_RBV")
            self.stable_tolerance = epics_signal_r(float, prefix + "STABLE_TOL")
            self.stable_hold = epics_signal_r(float, prefix + "STABLE_HOLD")
        self.setpoint = epics_signal_rw(float, prefix + "SETPOINT")
        self.stable = epics_signal_r(bool, prefix + "STABLE")
        self.message = epics_signal_r(str, prefix + "MESSAGE")
        self.state = epics_signal_r(str, prefix + "STATE")
        super().__init__(name=name)

    async def limits(self) -> tuple[float, float]:
        """The setpoints the daemon takes (K), from SETPOINT's drive limits."""
        description = (await self.setpoint.describe())[self.setpoint.name]
        control = description["limits"]["control"]
        return float(control["low"]), float(control["high"])

    async def units(self) -> str:
        """The temperatures' unit, from SETPOINT's EGU."""
        return str((await self.setpoint.describe())[self.setpoint.name].get("units", ""))

    @AsyncStatus.wrap
    async def set(self, value: float) -> None:
        """Regulate to ``value`` (K) and return once cryod says the flange is stable there.

        Raises
        ------
        ValueError
            ``value`` is outside the daemon's setpoint limits (nothing was put).
        NotStableError
            The wait ended without STABLE (the message says why, in cryod's words).
        """
        low, high = await self.limits()
        if not low <= value <= high:
            raise ValueError(f"{self.name}: setpoint {value} K outside {low:g}..{high:g} K (the daemon's "
                             f"control.setpoint_min_K/max_K)")
        await self.setpoint.set(float(value), timeout=self.settle_timeout_s)
        try:
            await wait_for_value(self.stable, True, timeout=STABLE_SHOWN_S)
        except asyncio.TimeoutError:
            message, state = await asyncio.gather(self.message.get_value(), self.state.get_value())
            raise NotStableError(f"{self.name}: not stable at {value} K (state {state}): {message}") from None
        target = await self.target.get_value()
        if target != float(value):
            raise NotStableError(f"{self.name}: the target is now {target} K, not {value} K "
                                 f"(set elsewhere meanwhile)")


__all__ = ["Cryostat", "NotStableError"]
