"""The writable PVs: a put is one of the daemon's commands, answered before the put completes.

A put to SETPOINT, RAMP, FEEDFORWARD, HEATER_OFF, NOTE or ALARM_ACK becomes the daemon's command
(``setpoint K``, ``ramp K_PER_MIN``, ``feedforward on|off``, ``heater-off``, ``note TEXT``,
``alarms ack NAME``), relayed through the control socket with the EPICS client's user and host
(:mod:`cryod.ioc.client_identity`), so that the daemon's command table checks it against its
configured limits and its journal and record name who sent it. The put waits for the daemon's answer
(the next tick, at most :data:`PUT_REPLY_S`), in softioc's ``validate``:

- **taken**: the record keeps the value put, which is what the daemon now holds;
- **refused** (a setpoint outside ``control.setpoint_min_K..setpoint_max_K``, a ramp beyond
  ``control.max_ramp_K_per_min``, no answer): the record goes back to the value the daemon holds and
  to alarm MINOR with STAT WRITE, which a client reads with the value, until its next put is taken;
  MESSAGE says why (the daemon's own words).

SETPOINT's drive limits are the configured setpoint limits, each widened by the smallest step a
double takes: an ``ao`` record clamps a put beyond DRVH to DRVH without a word, and a flange must not
be sent to its highest setpoint by a typo, so the clamped value lands just outside the daemon's range,
which refuses it. A put with completion on SETPOINT (``caput -c``, ophyd-async's ``set``) completes
once STABLE (the same rule as ``wait_until_stable``), or when the wait can end no other way: a newer
put to SETPOINT, a target set elsewhere, a loop that stops regulating (heater off, a fault), the
daemon gone, or ``ioc.settle_timeout_s``. While one waits, a plain put to SETPOINT is taken at once
and ends it; another put with completion waits its turn, as EPICS queues puts to a busy record.

SETPOINT keeps the last value put through EPICS (SETPOINT_RBV is the target however it was set);
RAMP and HEATER_OFF follow the daemon when it changes by another way (``cryod ctl``, the web page).
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

from cryod.interfaces.daemon_link import DaemonLink
from cryod.interfaces.mirror import DaemonMirror
from cryod.ioc.access_security import SETTINGS_GROUP
from cryod.ioc.alarm_severity import MINOR, STAT_WRITE
from cryod.ioc.client_identity import ClientIdentity
from cryod.ioc.pv_table import PVS
from cryod.ioc.records import build_record
from cryod.service.daemon_status import DaemonStatus, status_from_json
from cryod.service.settling import SettlingWatch

log = logging.getLogger("cryod.ioc")

#: The longest a put waits for the daemon's answer (s); the daemon answers after its next tick. A put
#: that gets none is refused, and the daemon withdraws the command when the IOC stops waiting.
PUT_REPLY_S = 3.0
#: How long after a taken SETPOINT put the stream may take to show the new target (s).
SHOWN_WITHIN_S = 5.0


class Refused(ValueError):
    """A put the IOC refuses before asking the daemon (not writable, no command for the value)."""


def setpoint_line(value: float) -> str:
    """The setpoint command for a put (the daemon checks the limits)."""
    if not math.isfinite(value):
        raise Refused(f"setpoint {value} K refused: not a finite number")
    return f"setpoint {value!r}"


def ramp_line(value: float) -> str:
    if not math.isfinite(value):
        raise Refused(f"ramp {value} K/min refused: not a finite number")
    return f"ramp {value!r}"


def text_line(command: str) -> Callable[[str], str]:
    def line(value: str) -> str:
        text = value.strip()
        if not text:
            raise Refused(f"{command}: empty")
        return f"{command} {text}"
    return line


class SettingRecords:
    """The writable records and what a put to each does.

    Parameters
    ----------
    prefix : str
    ioc : cryod.config.IocConfig
    control : cryod.control.regulator.ControlConfig
        The daemon's configured limits (DRVL/DRVH).
    link : DaemonLink
    mirror : DaemonMirror
    identity : ClientIdentity
    message : callable
        ``message(text)`` shows the daemon's answer to the last put (MESSAGE).
    """

    def __init__(self, prefix: str, ioc, control, link: DaemonLink, mirror: DaemonMirror,
                 identity: ClientIdentity, message: Callable[[str], None]):
        self.prefix = prefix
        self.ioc = ioc
        self.link = link
        self.mirror = mirror
        self.identity = identity
        self.message = message
        #: The thread that shows on RAMP and HEATER_OFF what the daemon holds (its puts send no command), and
        #: the one that looks whether a newer put waits on SETPOINT: both may wait for a record a put holds while
        #: the daemon answers it, which the event loop (every reading's update) must never do.
        self._echo = ThreadPoolExecutor(1, thread_name_prefix="cryod-ioc-echo")
        self._echo_thread = self._echo.submit(threading.get_ident).result()
        self._looks = ThreadPoolExecutor(1, thread_name_prefix="cryod-ioc-rpro")
        self._echoing: dict[str, object] = {}
        status = mirror.status()
        target = status.loop.target_K if status.loop.target_K is not None else status.loop.last_target_K
        if target is None:
            target = control.setpoint_K if control.setpoint_K is not None else control.setpoint_min_K
        self.setpoint = build_record(
            prefix, PVS["SETPOINT"], initial_value=target, DRVL=math.nextafter(control.setpoint_min_K, -math.inf),
            DRVH=math.nextafter(control.setpoint_max_K, math.inf), LOPR=control.setpoint_min_K,
            HOPR=control.setpoint_max_K, blocking=True, always_update=True, ASG=SETTINGS_GROUP,
            validate=self._validator("SETPOINT", setpoint_line, self._held_setpoint), on_update=self._settle)
        self.ramp = build_record(
            prefix, PVS["RAMP"], initial_value=status.loop.ramp_K_per_min, DRVL=0.0,
            DRVH=math.nextafter(control.max_ramp_K_per_min, math.inf), LOPR=0.0, HOPR=control.max_ramp_K_per_min,
            always_update=True, ASG=SETTINGS_GROUP,
            validate=self._validator("RAMP", ramp_line, lambda held: held.loop.ramp_K_per_min))
        self.feedforward = build_record(
            prefix, PVS["FEEDFORWARD"], initial_value=1, always_update=True, ASG=SETTINGS_GROUP,
            validate=self._validator("FEEDFORWARD", lambda value: f"feedforward {'on' if value else 'off'}", None))
        self.heater_off = build_record(
            prefix, PVS["HEATER_OFF"], initial_value=int(status.loop.state == "off"), always_update=True,
            ASG=SETTINGS_GROUP, validate=self._validator("HEATER_OFF", self._heater_line, self._held_heater_off))
        self.note = build_record(prefix, PVS["NOTE"], always_update=True, ASG=SETTINGS_GROUP,
                                 validate=self._validator("NOTE", text_line("note"), lambda held: ""))
        self.alarm_ack = build_record(prefix, PVS["ALARM_ACK"], always_update=True, ASG=SETTINGS_GROUP,
                                      validate=self._validator("ALARM_ACK", text_line("alarms ack"), lambda held: ""))

    # -- what the daemon holds -------------------------------------------------------------
    @staticmethod
    def _held_setpoint(held: DaemonStatus) -> float | None:
        loop = held.loop
        return loop.target_K if loop.target_K is not None else loop.last_target_K

    @staticmethod
    def _held_heater_off(held: DaemonStatus) -> int:
        return int(held.loop.state == "off")

    def _heater_line(self, value: int) -> str | None:
        """1: heater-off; 0: regulate again at the last target while off (nothing to do otherwise)."""
        if value:
            return "heater-off"
        loop = self.mirror.status().loop
        if loop.state != "off":
            return None
        if loop.last_target_K is None:
            raise Refused("regulate again: no setpoint was ever given; put SETPOINT")
        return f"setpoint {loop.last_target_K!r}"

    # -- puts ------------------------------------------------------------------------------
    def _validator(self, name: str, to_line: Callable, held_value: Callable[[DaemonStatus], object] | None):
        record_name = self.prefix + name

        def validate(record, value) -> bool:
            if self._echo_thread == threading.get_ident():
                return True                           # the IOC showing what the daemon holds: no command
            sender = f"EPICS client {self.identity.take(record_name)}, {record_name}"
            try:
                if not self.ioc.writable:
                    raise Refused(f"{record_name}: writes are off (ioc.writable is false)")
                line = to_line(value)
            except Refused as refusal:
                return self._refused(record, str(refusal), sender, None, held_value)
            if line is None:
                self.message(f"{record_name}: nothing to do")
                return True
            reply = self._relay(line, sender)
            status = reply.get("status")
            held = status_from_json(status) if isinstance(status, dict) else None
            if not reply.get("ok"):
                return self._refused(record, str(reply.get("message", "refused")), sender, held, held_value)
            self.message(str(reply.get("message", "")))
            return True

        return validate

    def _relay(self, line: str, sender: str) -> dict:
        """The daemon's reply to ``line``, waited for on this thread (the put's) with a loop of its own."""
        async def ask():
            return await asyncio.wait_for(self.link.command(line, sender), PUT_REPLY_S)
        try:
            return asyncio.run(ask())
        except asyncio.TimeoutError:
            return {"ok": False, "message": f"no answer from the daemon within {PUT_REPLY_S:g} s; not carried out"}

    def _refused(self, record, message: str, sender: str, held: DaemonStatus | None,
                 held_value: Callable[[DaemonStatus], object] | None) -> bool:
        """A refused put: the record goes back to what the daemon holds, MINOR/WRITE until its next put is taken."""
        log.warning("put refused: %s (by %s)", message, sender)
        self.message(message)
        if held is not None and held_value is not None:
            value = held_value(held)
            if value is not None:
                _hold(record, value)
        record.process_severity(record._record, MINOR, STAT_WRITE)
        return False

    async def _settle(self, value: float) -> None:
        """A taken SETPOINT put: return (completing a put with completion) when STABLE or when the wait must end.

        The stream may be a line behind the daemon's answer: until a status shows the new target, only the
        end of the wait by a newer put counts (at most :data:`SHOWN_WITHIN_S`)."""
        watch = SettlingWatch(self.ioc.stable_tolerance_K, self.ioc.stable_hold_s)
        start_s = None
        shown_by = time.monotonic() + SHOWN_WITHIN_S
        shown = False
        while True:
            changed = self.mirror.changed
            if not self.mirror.connected:
                return
            status = self.mirror.status()
            shown = shown or status.loop.target_K == value
            if shown:
                settling = watch.observe(status)
                start_s = settling.time_s if start_s is None else start_s
                if settling.stable or settling.cannot_settle is not None:
                    return
                if status.loop.target_K != value:
                    return                            # another target, set from elsewhere
                if settling.time_s - start_s > self.ioc.settle_timeout_s:
                    self.message(f"SETPOINT {value:g} K: not stable after ioc.settle_timeout_s "
                                 f"({self.ioc.settle_timeout_s:g} s): {settling.where()}")
                    return
            elif time.monotonic() > shown_by:
                return
            newer = await asyncio.get_running_loop().run_in_executor(self._looks, self.setpoint.get_field, "RPRO")
            if newer not in ("0", "NO"):
                return                                # a newer put waits for this one
            try:
                await asyncio.wait_for(changed.wait(), 1.0)
            except asyncio.TimeoutError:
                pass

    # -- following the daemon ----------------------------------------------------------------
    def follow(self, status: DaemonStatus) -> None:
        """Show what the daemon holds on RAMP and HEATER_OFF when it changed by another way (handed to the echo
        thread; no command goes out)."""
        if status.waiting_for is not None:
            return
        for record, value in ((self.ramp, status.loop.ramp_K_per_min),
                              (self.heater_off, self._held_heater_off(status))):
            if record.get() != value and self._echoing.get(record.name) != value:
                self._echoing[record.name] = value
                self._echo.submit(self._show, record, value)

    def _show(self, record, value) -> None:
        """On the echo thread: ``value`` on ``record`` (its validate sees the echo thread and sends nothing)."""
        try:
            record.set(value)
        finally:
            self._echoing.pop(record.name, None)


def _hold(record, value) -> None:
    """Make ``value`` the one softioc writes back when ``validate`` refuses a put (its last good value).

    softioc restores the record's last value taken; the daemon may have been given another since
    (``cryod ctl``, the web page), and a refused put must leave the record at what the daemon holds.
    """
    record._value = (record._value_to_epics(value),) + tuple(record._value[1:])


__all__ = ["SettingRecords", "PUT_REPLY_S", "setpoint_line"]
