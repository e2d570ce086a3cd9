"""The feedforward's states, the events that move it from one to another, and what it does in each.

Two tables, read by the term (:mod:`cryod.control.feedforward.term`): :data:`TRANSITIONS`, where
each event takes each state (:func:`next_state` refuses a pair the table does not have), and
:data:`BEHAVIOURS`, what the term does in each state: whether the waveform plays (it fades in to
full and every learning step moves it, and the probe with it) or is held out (it fades out, or
stays out, and the learning steps only estimate), and whether the divergence guard judges the
steps. docs/explanation/feedforward.md ("States") draws the diagram.

The events come from three places:

* the tick's verdict, once per closed-loop tick (:func:`verdict`): the first of the things that
  keep the waveform from playing, or ``READY``. The operator's switch comes first (``SWITCHED_OFF``),
  then the loop's timing (``CYCLES_LATE``: late cycles in a row put the cooler's phase and the
  readings' instants in doubt), the lock on the cooler (``NO_LOCK``), the wait after a divergence
  (``RETRY_PENDING``); a verdict is a level, said every tick, so a state that waits on one thing
  moves to the next thing that holds the waveform back as soon as the first is over;
* the fade: ``FADED_IN`` and ``FADED_OUT`` (also said every tick while the waveform is full, or
  out), and ``LOOP_CLOSED`` (the loop closed again: the waveform starts again from 0, bumpless);
* the learning: each learning step that moves the waveform says what it found (``PROBE_PLAYS``,
  ``PLANT_KNOWN``: the plant at the line learned, ``PLANT_UNKNOWN``); the guard's ``DIVERGED``;
  ``PLANT_FORGOTTEN`` (the setpoint entered another zone: the learned plant starts again from the
  zone's model).

``DIVERGED`` is the one state that outlives every verdict: the waveform fades out whatever the
switch, the timing or the lock say, and only once it is out does the learning start again later
(``WAITING_TO_RETRY``; the term then resets the learned plant and the waveform).

Which T2 readings the estimator takes is not the state's business but the lock's and the loop's
(a reading is taken while the cooler's phase is locked, a second after a gap and half a second
after a change of what the heater plays), and the cooler is tracked while the feedforward is
switched on or its waveform still plays.

Examples
--------
>>> next_state(FeedforwardState.WAITING_FOR_LOCK, verdict(True, True, True, False))
<FeedforwardState.FADING_IN: 'fading in'>
>>> next_state(FeedforwardState.FADING_IN, FeedforwardEvent.FADED_IN)
<FeedforwardState.LEARNING: 'learning'>
>>> BEHAVIOURS[FeedforwardState.CYCLES_LATE].plays
False
>>> next_state(FeedforwardState.OFF, FeedforwardEvent.DIVERGED)
Traceback (most recent call last):
...
cryod.control.feedforward.state_machine.TransitionRefused: the feedforward cannot take 'diverged' while off
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class FeedforwardState(enum.Enum):
    """Where the feedforward is: what its waveform does and what its learning does (:data:`BEHAVIOURS`)."""

    OFF = "off"
    WAITING_FOR_LOCK = "waiting for lock"
    FADING_IN = "fading in"
    LEARNING = "learning"
    PROBING = "probing"
    TRACKING = "tracking"
    FADING_OUT = "fading out"
    CYCLES_LATE = "cycles late"
    DIVERGED = "diverged"
    WAITING_TO_RETRY = "waiting to retry"


class FeedforwardEvent(enum.Enum):
    """What moves the feedforward from one state to another (module notes)."""

    SWITCHED_OFF = "switched off"
    CYCLES_LATE = "cycles late"
    NO_LOCK = "no lock"
    RETRY_PENDING = "retry pending"
    READY = "ready"
    FADED_IN = "faded in"
    FADED_OUT = "faded out"
    LOOP_CLOSED = "loop closed"
    PROBE_PLAYS = "probe plays"
    PLANT_KNOWN = "plant known"
    PLANT_UNKNOWN = "plant unknown"
    DIVERGED = "diverged"
    PLANT_FORGOTTEN = "plant forgotten"


@dataclass(frozen=True)
class Behaviour:
    """What the feedforward does in a state.

    Attributes
    ----------
    plays : bool
        The waveform fades in to full (or stays there) and every learning step moves it and the probe;
        else it fades out (or stays out) and the learning steps only estimate the line and the plant.
    guard_watches : bool
        The divergence guard judges every learning step (only with the waveform at full: a fade moves
        T2's residual by itself).
    waveform : str
        What the waveform does, in words (docs/explanation/feedforward.md's table).
    learning : str
        What the learning does, in words.
    """

    plays: bool
    guard_watches: bool
    waveform: str
    learning: str


_S, _E = FeedforwardState, FeedforwardEvent      # the tables' shorthand

#: What the feedforward does in each state.
BEHAVIOURS: dict[FeedforwardState, Behaviour] = {
    _S.OFF: Behaviour(False, False, "none; the cooler is not tracked", "none"),
    _S.WAITING_FOR_LOCK: Behaviour(False, False, "fades out, stays out", "none: no readings without the lock"),
    _S.FADING_IN: Behaviour(True, False, "fades in", "steps move the waveform and the probe"),
    _S.LEARNING: Behaviour(True, True, "plays", "steps move the waveform; the plant at the line not known yet"),
    _S.PROBING: Behaviour(True, True, "plays, with the probe at a harmonic", "steps move the waveform and the probe"),
    _S.TRACKING: Behaviour(True, True, "plays", "steps move the waveform in the learned plant; no probe"),
    _S.FADING_OUT: Behaviour(False, False, "fades out (switched off)", "steps estimate only"),
    _S.CYCLES_LATE: Behaviour(False, False, "fades out, stays out", "paused: steps estimate only"),
    _S.DIVERGED: Behaviour(False, False, "fades out; then the learned plant and the waveform are reset",
                          "steps estimate only"),
    _S.WAITING_TO_RETRY: Behaviour(False, False, "out", "steps estimate only, until the wait is over"),
}

#: Where each event takes each state; a pair that is not here cannot happen (:func:`next_state` refuses it).
#: Every state but ``DIVERGED`` takes the tick's verdict alike: to the state of the first thing that holds
#: the waveform back (``SWITCHED_OFF``: fading out, until it is out: off), or to fading in (``READY``).
TRANSITIONS: dict[FeedforwardState, dict[FeedforwardEvent, FeedforwardState]] = {
    _S.OFF: {
        _E.SWITCHED_OFF: _S.OFF, _E.CYCLES_LATE: _S.CYCLES_LATE, _E.NO_LOCK: _S.WAITING_FOR_LOCK,
        _E.RETRY_PENDING: _S.WAITING_TO_RETRY, _E.READY: _S.FADING_IN,
        _E.FADED_OUT: _S.OFF, _E.LOOP_CLOSED: _S.OFF, _E.PLANT_FORGOTTEN: _S.OFF},
    _S.WAITING_FOR_LOCK: {
        _E.SWITCHED_OFF: _S.FADING_OUT, _E.CYCLES_LATE: _S.CYCLES_LATE, _E.NO_LOCK: _S.WAITING_FOR_LOCK,
        _E.RETRY_PENDING: _S.WAITING_TO_RETRY, _E.READY: _S.FADING_IN,
        _E.FADED_OUT: _S.WAITING_FOR_LOCK, _E.LOOP_CLOSED: _S.WAITING_FOR_LOCK,
        _E.PLANT_FORGOTTEN: _S.WAITING_FOR_LOCK},
    _S.FADING_IN: {
        _E.SWITCHED_OFF: _S.FADING_OUT, _E.CYCLES_LATE: _S.CYCLES_LATE, _E.NO_LOCK: _S.WAITING_FOR_LOCK,
        _E.READY: _S.FADING_IN,
        _E.FADED_IN: _S.LEARNING, _E.LOOP_CLOSED: _S.FADING_IN,
        _E.PROBE_PLAYS: _S.FADING_IN, _E.PLANT_KNOWN: _S.FADING_IN, _E.PLANT_UNKNOWN: _S.FADING_IN,
        _E.PLANT_FORGOTTEN: _S.FADING_IN},
    _S.LEARNING: {
        _E.SWITCHED_OFF: _S.FADING_OUT, _E.CYCLES_LATE: _S.CYCLES_LATE, _E.NO_LOCK: _S.WAITING_FOR_LOCK,
        _E.READY: _S.LEARNING,
        _E.FADED_IN: _S.LEARNING, _E.LOOP_CLOSED: _S.FADING_IN,
        _E.PROBE_PLAYS: _S.PROBING, _E.PLANT_KNOWN: _S.TRACKING, _E.PLANT_UNKNOWN: _S.LEARNING,
        _E.DIVERGED: _S.DIVERGED, _E.PLANT_FORGOTTEN: _S.LEARNING},
    _S.PROBING: {
        _E.SWITCHED_OFF: _S.FADING_OUT, _E.CYCLES_LATE: _S.CYCLES_LATE, _E.NO_LOCK: _S.WAITING_FOR_LOCK,
        _E.READY: _S.PROBING,
        _E.FADED_IN: _S.PROBING, _E.LOOP_CLOSED: _S.FADING_IN,
        _E.PROBE_PLAYS: _S.PROBING, _E.PLANT_KNOWN: _S.TRACKING, _E.PLANT_UNKNOWN: _S.LEARNING,
        _E.DIVERGED: _S.DIVERGED, _E.PLANT_FORGOTTEN: _S.PROBING},
    _S.TRACKING: {
        _E.SWITCHED_OFF: _S.FADING_OUT, _E.CYCLES_LATE: _S.CYCLES_LATE, _E.NO_LOCK: _S.WAITING_FOR_LOCK,
        _E.READY: _S.TRACKING,
        _E.FADED_IN: _S.TRACKING, _E.LOOP_CLOSED: _S.FADING_IN,
        _E.PROBE_PLAYS: _S.PROBING, _E.PLANT_KNOWN: _S.TRACKING, _E.PLANT_UNKNOWN: _S.LEARNING,
        _E.DIVERGED: _S.DIVERGED, _E.PLANT_FORGOTTEN: _S.LEARNING},
    _S.FADING_OUT: {
        _E.SWITCHED_OFF: _S.FADING_OUT, _E.CYCLES_LATE: _S.CYCLES_LATE, _E.NO_LOCK: _S.WAITING_FOR_LOCK,
        _E.RETRY_PENDING: _S.WAITING_TO_RETRY, _E.READY: _S.FADING_IN,
        _E.FADED_OUT: _S.OFF, _E.LOOP_CLOSED: _S.FADING_OUT, _E.PLANT_FORGOTTEN: _S.FADING_OUT},
    _S.CYCLES_LATE: {
        _E.SWITCHED_OFF: _S.FADING_OUT, _E.CYCLES_LATE: _S.CYCLES_LATE, _E.NO_LOCK: _S.WAITING_FOR_LOCK,
        _E.RETRY_PENDING: _S.WAITING_TO_RETRY, _E.READY: _S.FADING_IN,
        _E.FADED_OUT: _S.CYCLES_LATE, _E.LOOP_CLOSED: _S.CYCLES_LATE, _E.PLANT_FORGOTTEN: _S.CYCLES_LATE},
    _S.DIVERGED: {
        _E.SWITCHED_OFF: _S.DIVERGED, _E.CYCLES_LATE: _S.DIVERGED, _E.NO_LOCK: _S.DIVERGED,
        _E.RETRY_PENDING: _S.DIVERGED, _E.READY: _S.DIVERGED,
        _E.FADED_OUT: _S.WAITING_TO_RETRY, _E.LOOP_CLOSED: _S.DIVERGED, _E.PLANT_FORGOTTEN: _S.DIVERGED},
    _S.WAITING_TO_RETRY: {
        _E.SWITCHED_OFF: _S.FADING_OUT, _E.CYCLES_LATE: _S.CYCLES_LATE, _E.NO_LOCK: _S.WAITING_FOR_LOCK,
        _E.RETRY_PENDING: _S.WAITING_TO_RETRY, _E.READY: _S.FADING_IN,
        _E.FADED_OUT: _S.WAITING_TO_RETRY, _E.LOOP_CLOSED: _S.WAITING_TO_RETRY,
        _E.PLANT_FORGOTTEN: _S.WAITING_TO_RETRY},
}


class TransitionRefused(ValueError):
    """An event the feedforward's state cannot take: the term's bookkeeping has gone wrong."""


def next_state(state: FeedforwardState, event: FeedforwardEvent) -> FeedforwardState:
    """Where ``event`` takes ``state`` (:data:`TRANSITIONS`).

    Raises
    ------
    TransitionRefused
        The pair is not in the table: it cannot happen.
    """
    try:
        return TRANSITIONS[state][event]
    except KeyError:
        raise TransitionRefused(f"the feedforward cannot take {event.value!r} while {state.value}") from None


def verdict(switched_on: bool, cycles_on_time: bool, locked: bool, retry_pending: bool) -> FeedforwardEvent:
    """The tick's verdict: the first thing that holds the waveform back, or ``READY``.

    Parameters
    ----------
    switched_on : bool
        The operator's switch (``cryod ctl feedforward on|off``, ``enabled`` in the configuration).
    cycles_on_time : bool
        The loop's cycles keep their deadlines (not late many in a row).
    locked : bool
        The cooler's phase is tracked and locked.
    retry_pending : bool
        Learning still waits after a divergence.
    """
    if not switched_on:
        return FeedforwardEvent.SWITCHED_OFF
    if not cycles_on_time:
        return FeedforwardEvent.CYCLES_LATE
    if not locked:
        return FeedforwardEvent.NO_LOCK
    if retry_pending:
        return FeedforwardEvent.RETRY_PENDING
    return FeedforwardEvent.READY


__all__ = ["BEHAVIOURS", "Behaviour", "FeedforwardEvent", "FeedforwardState", "TRANSITIONS", "TransitionRefused",
           "next_state", "verdict"]
