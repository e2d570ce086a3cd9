"""The alarms in the daemon: fed the loop's rows, said everywhere the lab looks, acknowledged by the operator.

:class:`AlarmMonitor` is the last of the loop's row taps. On the loop's thread it hands
each row's figures to the :class:`~cryod.alarms.board.AlarmBoard` (a few microseconds: a
ring write, T5's phase tracker, a window's mean and standard deviation once a second) and
says each change of an alarm:

* in the journal, at warning (an acknowledgement at info);
* in the record, as ``# event: alarm: NAME KIND: what, with the figures``, right after the
  row that made it;
* to the lab's hook, which runs in the interfaces process (:mod:`cryod.service.alarm_hook`), fed by the
  daemon's stream (:mod:`cryod.service.stream`): the event carries the change's figures.

What stands is published as a snapshot for the other threads: ``alarms`` in the status
(``cryod ctl status``, the web page), ``cryod_alarm{name}`` in the metrics, the reply of
``cryod ctl alarms``. Alarms never touch the heater: that is what faults do.

``cryod ctl alarms`` lists the alarms that are on and is answered at once; ``cryod ctl
alarms ack NAME`` (or ``all``) is carried out at the next row, on the loop's thread, like
every change of an alarm. A reload hands the new ``alarms`` section over the same way.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import math

from cryod.alarms.board import AlarmBoard
from cryod.alarms.latch import LATCHED, RAISED, Transition
from cryod.alarms.settings import AlarmsConfig
from cryod.records.columns import Event, Row
from cryod.service.alarm_hook import AlarmHookRunner
from cryod.service.commands import Command

log = logging.getLogger("cryod.alarms")

#: The snapshot the other threads read is renewed at least this often while alarms stand, in the
#: daemon's clock (s), so that their figures stay current.
PUBLISH_INTERVAL_S = 1.0


def alarm_line(alarm: dict) -> str:
    """One alarm of the status as one line of text."""
    state = alarm["state"]
    if state in (RAISED, LATCHED):
        acknowledged = ", acknowledged" if alarm["acknowledged"] else ""
        since = f" since {alarm['since_s']:.1f} s" if alarm.get("since_s") is not None else ""
        return f"{alarm['name']}: {state}{since}{acknowledged}: {alarm['raised_message']}; now {alarm['message']}"
    return f"{alarm['name']}: {state}" + (f": {alarm['message']}" if alarm["message"] else "")


class AlarmMonitor:
    """Row tap of the alarms, and the ``alarms`` command.

    Parameters
    ----------
    config : AlarmsConfig
    heater_max_power_w : float
        R I_max^2 (W).
    cooler_rad_s : float
        The cooler's angular frequency in the model (rad/s).
    period_s : float
        The loop period (s).
    hook : AlarmHookRunner, optional
        Runs the lab's hook (``alarms.hook``) in this process (the daemon leaves it to the interfaces process).
    """

    def __init__(self, config: AlarmsConfig, heater_max_power_w: float, cooler_rad_s: float, period_s: float,
                 hook: AlarmHookRunner | None = None):
        self.board = AlarmBoard(config, heater_max_power_w, cooler_rad_s, period_s)
        self.hook = hook
        self.emit = lambda item: None
        self._new_config: AlarmsConfig | None = None
        self._requests: collections.deque[Command] = collections.deque()   # acknowledgements, for the loop thread
        self._time_s = math.nan
        self._next_publish_s = -math.inf
        self._published: tuple[dict, ...] = tuple(self.board.alarms())
        self._running = False
        self._broken = False            # an error in the alarms: they are off, the loop goes on

    def attach(self, emit) -> None:
        """Where the alarms' events go: the loop's fan-out of rows and events (the data log among them)."""
        self.emit = emit
        self._running = True

    # -- any thread ---------------------------------------------------------------------------
    def reconfigure(self, config: AlarmsConfig) -> None:
        """A reloaded ``alarms`` section: taken at the next row (the hook's settings at once)."""
        self._new_config = config
        if self.hook is not None:
            self.hook.configure(config.hook)
        if not self._running:
            self._apply_config()

    def alarms(self) -> list[dict]:
        """Every alarm that is on, with its state (``name``, ``state``, ``acknowledged``, ``since_s``, ``value``,
        ``message``, ``raised_message``), as of the last row."""
        return [dict(alarm) for alarm in self._published]

    def raised(self) -> list[dict]:
        """The alarms raised or latched, as of the last row (the status' ``alarms``)."""
        return [dict(alarm) for alarm in self._published if alarm["state"] in (RAISED, LATCHED)]

    def raised_names(self) -> list[str]:
        """The names of the alarms raised or latched (the status line)."""
        return [alarm["name"] for alarm in self._published if alarm["state"] in (RAISED, LATCHED)]

    def states(self) -> dict[str, float]:
        """1.0 for each alarm raised or latched, 0.0 for each other alarm that is on (the metrics)."""
        return {alarm["name"]: 1.0 if alarm["state"] in (RAISED, LATCHED) else 0.0 for alarm in self._published}

    def submit(self, command: Command) -> Command:
        """The ``alarms`` command: the list is answered now, an acknowledgement at the next row."""
        if command.value is None:
            alarms = self.alarms()
            text = "\n".join(alarm_line(alarm) for alarm in alarms) or \
                "no alarm is on (the configuration has no alarms section)"
            command.reply = {"alarms": alarms}
            command.answer(True, text)
        elif not self._running:
            command.answer(False, "not running yet: alarms are acknowledged once the loop runs")
        elif self._broken:
            command.answer(False, "the alarms stopped on an error (see the journal): nothing to acknowledge")
        else:
            self._requests.append(command)
        return command

    # -- the loop thread -------------------------------------------------------------------------
    def __call__(self, item: Row | Event) -> None:
        if type(item) is not Row or self._broken:
            return
        try:
            self._take(item)
        except Exception:               # alarms never stop the loop: they stop themselves, and say so
            self._broken = True
            log.exception("the alarms stopped on an error; regulation goes on without them (restart the daemon "
                          "to have them again)")
            self.emit(Event("alarm", "the alarms stopped on an error (see the journal); regulation goes on "
                                     "without them"))

    def _take(self, item: Row) -> None:
        time_s = self._time_s = item.time_s
        changes: list[Transition] = []
        if self._new_config is not None:
            changes += self._apply_config()
        if self._requests:
            changes += self._acknowledgements()
        changes += self.board.take(time_s, str(item.state), item.T2_K, item.T5_K, item.heater_W, item.setpoint_K)
        for change in changes:
            self._say(change)
        if changes or (time_s >= self._next_publish_s and self.board.latches):
            self._next_publish_s = time_s + PUBLISH_INTERVAL_S
            self._published = tuple(self.board.alarms())

    def _apply_config(self) -> list[Transition]:
        config, self._new_config = self._new_config, None
        if config is None:                  # taken already
            return []
        changes = self.board.reconfigure(config, self._time_s)
        self._published = tuple(self.board.alarms())
        return changes

    def _acknowledgements(self) -> list[Transition]:
        changes: list[Transition] = []
        while self._requests:
            command = self._requests.popleft()
            if not command.take():          # its client stopped waiting: never carried out
                log.info("alarms %s %s withdrawn by its client before it was carried out (by %s)", *command.value,
                         command.sender or "an unknown sender")
                continue
            _, which = command.value
            try:
                acknowledged = self.board.acknowledge(which, self._time_s, command.sender)
            except ValueError as error:
                command.answer(False, f"alarms ack refused: {error}")
                continue
            changes += acknowledged
            self._published = tuple(self.board.alarms())
            command.reply = {"alarms": self.alarms()}
            command.answer(True, "; ".join(change.text for change in acknowledged))
        return changes

    def _say(self, change: Transition) -> None:
        level = logging.INFO if change.kind == "acknowledged" else logging.WARNING
        log.log(level, "alarm %s", change.text)
        self.emit(Event("alarm", change.text, details=dataclasses.asdict(change)))
        if self.hook is not None:
            self.hook.offer(change)
