"""One alarm's life: from its condition to raised, latched, acknowledged and cleared.

A condition is checked again and again (:class:`Condition`); the alarm is raised once it
has held for ``delay_s`` without a break, and cleared when it is clearly over (beyond the
deadband: a figure between the threshold and the deadband changes nothing). A latching
alarm whose condition is over stays raised as *latched* until someone acknowledges it;
one acknowledged while its condition holds is cleared when the condition is over.

Examples
--------
>>> latch = AlarmLatch("ptc_stage_warm", delay_s=5.0, latching=False)
>>> latch.update(0.0, Condition(True, 4.6, "T5 4.6 K"))           # pending: not raised yet
>>> latch.update(5.0, Condition(True, 4.7, "T5 4.7 K")).kind
'raised'
>>> latch.update(6.0, Condition(None, 4.45, "T5 4.45 K"))          # in the deadband: still raised
>>> latch.update(7.0, Condition(False, 4.2, "T5 4.2 K")).kind
'cleared'
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, NamedTuple

#: An alarm's states, as the status and ``cryod ctl alarms`` show them.
CLEAR, PENDING, RAISED, LATCHED = "clear", "pending", "raised", "latched"


class Condition(NamedTuple):
    """One check of an alarm's condition.

    Attributes
    ----------
    holds : bool or None
        True: the condition holds; False: it is clearly over (or does not apply now, e.g. the
        loop is not regulating); None: between the threshold and the deadband (no change).
    value : float
        The figure checked, in the alarm's unit (NaN when there is none).
    words : str or callable
        The figure in words, with its unit and threshold, or what makes them when asked (a check at
        every row formats its words only when they are shown).
    """

    holds: bool | None
    value: float
    words: str | Callable[[], str]

    @property
    def text(self) -> str:
        """The figure in words."""
        return self.words() if callable(self.words) else self.words


@dataclass(frozen=True)
class Transition:
    """A change of an alarm, as the journal, the record and the hook say it.

    Attributes
    ----------
    name : str
        The alarm (:data:`cryod.alarms.settings.ALARM_NAMES`).
    kind : str
        ``raised``, ``cleared``, ``latched`` (its condition is over, it waits for an acknowledgement)
        or ``acknowledged``.
    time_s : float
        The daemon's clock time of the row that made the change (s).
    message : str
        What happened, with the figures.
    value : float
        The alarm's figure at the change (NaN when there is none).
    """

    name: str
    kind: str
    time_s: float
    message: str
    value: float = math.nan

    @property
    def text(self) -> str:
        """``name kind: message`` (the record's event line after ``alarm:``)."""
        return f"{self.name} {self.kind}: {self.message}"


class AlarmLatch:
    """The state of one alarm.

    Parameters
    ----------
    name : str
    delay_s : float
        How long the condition must hold without a break before the alarm is raised (s).
    latching : bool
        A raised alarm whose condition is over stays raised (latched) until acknowledged.
    """

    def __init__(self, name: str, delay_s: float, latching: bool):
        self.name = name
        self.delay_s = float(delay_s)
        self.latching = bool(latching)
        self.state = CLEAR
        self.acknowledged = False
        self.since_s = math.nan          # pending: when the condition began; raised or latched: when raised
        self.value = math.nan
        self._condition: Condition | None = None    # the latest check
        self.raised_text = ""            # the figure in words when it was raised

    @property
    def text(self) -> str:
        """The latest figure in words."""
        return self._condition.text if self._condition is not None else ""

    @property
    def raised(self) -> bool:
        """Raised or latched: the alarm stands."""
        return self.state in (RAISED, LATCHED)

    def reconfigure(self, delay_s: float, latching: bool) -> None:
        """New settings (a reload): the state is kept and the next checks use them."""
        self.delay_s, self.latching = float(delay_s), bool(latching)

    def update(self, time_s: float, condition: Condition) -> Transition | None:
        """Take one check of the condition at ``time_s``; the change it makes, if any."""
        self.value, self._condition = float(condition.value), condition
        if condition.holds:
            if self.state == CLEAR:
                self.state, self.since_s = PENDING, time_s
            if self.state == PENDING and time_s - self.since_s >= self.delay_s:
                held_s = time_s - self.since_s
                self.state, self.since_s, self.acknowledged, self.raised_text = RAISED, time_s, False, condition.text
                held = f" for {held_s:.0f} s" if held_s else ""
                return Transition(self.name, RAISED, time_s, condition.text + held, self.value)
            if self.state == LATCHED:           # back while waiting for its acknowledgement: it stands as before
                self.state = RAISED
            return None
        if condition.holds is None and self.state != PENDING:
            return None
        if self.state == PENDING:
            self.state, self.since_s = CLEAR, math.nan
        elif self.state == RAISED:
            if self.latching and not self.acknowledged:
                self.state = LATCHED
                return Transition(self.name, LATCHED, time_s, f"{condition.text}; latched until acknowledged "
                                                              f"(cryod ctl alarms ack {self.name})", self.value)
            return self._clear(time_s, condition.text, self.value)
        return None

    def acknowledge(self, time_s: float, sender: str = "") -> Transition:
        """Someone has seen it: a latched alarm is cleared, a raised one is cleared when its condition is over.

        Raises
        ------
        ValueError
            The alarm is not raised, or was acknowledged already.
        """
        by = f" by {sender}" if sender else ""
        if self.state == LATCHED:
            return self._clear(time_s, f"acknowledged{by}; {self.text}", self.value)
        if self.state != RAISED:
            raise ValueError(f"{self.name} is not raised ({self.state})")
        if self.acknowledged:
            raise ValueError(f"{self.name} was acknowledged already; it clears when its condition is over")
        self.acknowledged = True
        return Transition(self.name, "acknowledged", time_s, f"acknowledged{by}; it clears when its condition is "
                                                             f"over ({self.text})", self.value)

    def clear(self, time_s: float, reason: str) -> Transition | None:
        """Clear it whatever its state (the alarm was switched off by a reload); the transition when it stood."""
        stood = self.raised
        self.state, self.since_s = CLEAR, math.nan
        return self._clear(time_s, reason, self.value) if stood else None

    def _clear(self, time_s: float, message: str, value: float) -> Transition:
        self.state, self.since_s, self.acknowledged = CLEAR, math.nan, False
        return Transition(self.name, "cleared", time_s, message, value)

    def as_dict(self) -> dict:
        """The alarm as the status shows it: ``name``, ``state``, ``acknowledged``, ``since_s``, ``value``,
        ``message`` (the figure now), ``raised_message`` (the figure when it was raised)."""
        return {"name": self.name, "state": self.state, "acknowledged": self.acknowledged,
                "since_s": None if math.isnan(self.since_s) else self.since_s,
                "value": None if not math.isfinite(self.value) else self.value, "message": self.text,
                "raised_message": self.raised_text if self.raised else ""}
