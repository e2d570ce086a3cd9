"""The feedforward's state machine: its table, pair by pair, and the term that follows it.

The table is checked for what each transition means (a verdict leads to the state of what holds the
waveform back, a fade's end to a state whose waveform is where the fade left it, a divergence is
outlived by nothing but the fade-out), not against a copy of itself; every pair it leaves out is
refused. The term, fed ticks on its own (``tests/feedforward_ticks.py``), is then checked to be in
the state its waveform, its lock and its learning say, tick after tick.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest

from cryod.control.feedforward import FeedforwardSettings, FeedforwardTerm
from cryod.control.feedforward.state_machine import (BEHAVIOURS, TRANSITIONS, FeedforwardEvent,
                                                     FeedforwardState, TransitionRefused, next_state, verdict)
from cryod.control.terms import TickInputs
from tests.feedforward_ticks import OMEGA, PERIOD, feed

S, E = FeedforwardState, FeedforwardEvent
VERDICTS = {E.SWITCHED_OFF: S.FADING_OUT, E.CYCLES_LATE: S.CYCLES_LATE, E.NO_LOCK: S.WAITING_FOR_LOCK,
            E.RETRY_PENDING: S.WAITING_TO_RETRY, E.READY: S.FADING_IN}
PLAYING = {S.FADING_IN, S.LEARNING, S.PROBING, S.TRACKING}
FINDINGS = {E.PROBE_PLAYS: S.PROBING, E.PLANT_KNOWN: S.TRACKING, E.PLANT_UNKNOWN: S.LEARNING}
ALLOWED = [(state, event) for state, row in TRANSITIONS.items() for event in row]
REFUSED = [(state, event) for state, event in itertools.product(S, E) if event not in TRANSITIONS[state]]


# ---------------------------------------------------------------------------
# the table
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("state, event", ALLOWED, ids=[f"{s.value}/{e.value}" for s, e in ALLOWED])
def test_every_allowed_transition_goes_where_its_event_says(state, event):
    after = next_state(state, event)
    if state is S.DIVERGED:             # nothing but the fade-out ends a divergence
        assert after is (S.WAITING_TO_RETRY if event is E.FADED_OUT else S.DIVERGED)
    elif event in VERDICTS:
        held = VERDICTS[event]
        if event is E.READY:            # nothing holds it back: the waveform plays (fading in, or on at full)
            assert after is (state if state in PLAYING else S.FADING_IN)
        elif event is E.SWITCHED_OFF and state in (S.OFF, S.FADING_OUT):
            assert after is state
        else:
            assert after is held and not BEHAVIOURS[after].plays
    elif event is E.FADED_IN:           # the waveform is at full: playing, the guard judging
        assert BEHAVIOURS[state].plays and after in PLAYING - {S.FADING_IN} and BEHAVIOURS[after].guard_watches
    elif event is E.FADED_OUT:          # the waveform is out: switched off is off, other waits go on
        assert not BEHAVIOURS[state].plays and not BEHAVIOURS[after].plays
        assert after is (S.OFF if state is S.FADING_OUT else state)
    elif event is E.LOOP_CLOSED:        # the waveform starts again from 0: one that plays fades in again
        assert after is (S.FADING_IN if state in PLAYING else state)
    elif event in FINDINGS:             # only a step that moves the waveform finds anything
        assert state in PLAYING and after is (S.FADING_IN if state is S.FADING_IN else FINDINGS[event])
    elif event is E.DIVERGED:           # the guard judges only a waveform at full
        assert BEHAVIOURS[state].guard_watches and after is S.DIVERGED and not BEHAVIOURS[after].plays
    elif event is E.PLANT_FORGOTTEN:    # another zone: the plant at the line is not known any more
        assert after is (S.LEARNING if state is S.TRACKING else state)
    else:
        pytest.fail(f"an event the test does not know: {event}")


@pytest.mark.parametrize("state, event", REFUSED, ids=[f"{s.value}/{e.value}" for s, e in REFUSED])
def test_every_transition_not_in_the_table_is_refused(state, event):
    with pytest.raises(TransitionRefused, match=f"cannot take '{event.value}' while {state.value}$"):
        next_state(state, event)


def test_what_is_refused_is_what_cannot_happen():
    """A fade cannot end the other way, a step that does not move the waveform finds nothing, the guard
    judges only a waveform at full, and a retry cannot be pending while the waveform plays."""
    expected = {(state, event) for state in S for event in E
                if (event is E.FADED_IN and not BEHAVIOURS[state].plays)
                or (event is E.FADED_OUT and BEHAVIOURS[state].plays)
                or (event in FINDINGS and state not in PLAYING)
                or (event is E.DIVERGED and not BEHAVIOURS[state].guard_watches)
                or (event is E.RETRY_PENDING and state in PLAYING)}
    assert set(REFUSED) == expected


def test_every_state_is_reached_and_off_is_reached_from_each():
    def reachable(start):
        seen, todo = {start}, [start]
        while todo:
            for after in TRANSITIONS[todo.pop()].values():
                if after not in seen:
                    seen.add(after)
                    todo.append(after)
        return seen

    assert reachable(S.OFF) == set(S)
    assert all(S.OFF in reachable(state) for state in S)


def test_the_waveform_plays_and_the_guard_judges_only_where_they_should():
    assert {state for state in S if BEHAVIOURS[state].plays} == PLAYING
    assert {state for state in S if BEHAVIOURS[state].guard_watches} == {S.LEARNING, S.PROBING, S.TRACKING}


@pytest.mark.parametrize("switched_on, on_time, locked, retry_pending, expected", [
    (False, False, False, True, E.SWITCHED_OFF),        # the operator first
    (True, False, False, True, E.CYCLES_LATE),          # then the loop's timing
    (True, True, False, True, E.NO_LOCK),               # then the lock
    (True, True, True, True, E.RETRY_PENDING),
    (True, True, True, False, E.READY)])
def test_the_verdict_is_the_first_thing_that_holds_the_waveform_back(switched_on, on_time, locked, retry_pending,
                                                                     expected):
    assert verdict(switched_on, on_time, locked, retry_pending) is expected


# ---------------------------------------------------------------------------
# the term in its states
# ---------------------------------------------------------------------------
def consistent(term) -> None:
    """The term's state agrees with its waveform and its lock."""
    behaviour = BEHAVIOURS[term.state]
    if behaviour.guard_watches:             # at full, and only there
        assert term.scale == 1.0
    elif term.state is not S.DIVERGED:
        assert term.scale < 1.0 or not behaviour.plays
    if term.state is S.OFF:
        assert term.scale == 0.0 and not term.switched_on
    if term.state is S.FADING_OUT:
        assert not term.switched_on and term.scale > 0.0
    if term.state is S.TRACKING:
        assert term.learned_plant.learned[0] and not np.any(term.probe)
    if term.state is S.PROBING:
        assert np.any(term.probe)


def ticks(term, seconds, start_s, **more):
    """``feed`` one second at a time, checking the state after each."""
    for second in range(int(seconds)):
        feed(term, 1.0, start_s + second, **more)
        consistent(term)
    return start_s + int(seconds)


@pytest.fixture
def term(reference_model):
    term = FeedforwardTerm(FeedforwardSettings(model=reference_model), 0.5)
    term.start(None, 0.113)
    yield term
    term.close()


def test_it_waits_for_the_lock_fades_in_and_learns(term):
    assert term.state is S.WAITING_FOR_LOCK
    feed(term, 2.0)
    assert term.state is S.WAITING_FOR_LOCK and term.scale == 0.0 and not term.phase.locked
    seen = set()
    for second in range(2, 40):
        feed(term, 1.0, float(second))
        consistent(term)
        seen.add(term.state)
    assert {S.FADING_IN, S.LEARNING, S.PROBING} <= seen
    assert term.state in (S.LEARNING, S.PROBING, S.TRACKING) and term.scale == 1.0


def test_switched_off_it_fades_out_then_stops_tracking_the_cooler_and_comes_back(term):
    time_s = ticks(term, 40, 0.0)
    term.switch(False)
    feed(term, 1.0, time_s)
    assert term.state is S.FADING_OUT and 0.0 < term.scale < 1.0
    time_s = ticks(term, 6, time_s + 1)
    assert term.state is S.OFF and term.scale == 0.0
    feed(term, PERIOD, time_s)
    assert term.phase is None                         # off: the cooler is not tracked
    term.switch(True)
    ticks(term, 15, time_s + 1)
    assert term.state in (S.LEARNING, S.PROBING, S.TRACKING) and term.scale == 1.0


def test_late_cycles_fade_it_out_and_pause_the_learning(term):
    time_s = ticks(term, 40, 0.0)
    term.follow_timing(False)
    feed(term, 6.0, time_s)
    waveform = term.coefficients.copy()
    assert term.state is S.CYCLES_LATE and term.scale == 0.0
    time_s = ticks(term, 10, time_s + 6)
    assert term.state is S.CYCLES_LATE and np.array_equal(term.coefficients, waveform)    # learning paused
    term.follow_timing(True)
    ticks(term, 8, time_s)
    assert term.state in (S.LEARNING, S.PROBING, S.TRACKING)


def test_without_the_cooler_it_waits_for_the_lock(term):
    time_s = ticks(term, 40, 0.0)
    time_s = ticks(term, 10, time_s, cooler=False)
    assert term.state is S.WAITING_FOR_LOCK and term.scale == 0.0 and not term.phase.locked


def test_closing_the_loop_again_fades_the_waveform_in_from_zero(term):
    time_s = ticks(term, 40, 0.0)
    term.start(None, 0.113)
    assert term.state is S.FADING_IN and term.scale == 0.0
    ticks(term, 6, time_s)
    assert term.state in (S.LEARNING, S.PROBING, S.TRACKING)


def test_with_the_plant_known_and_the_probe_stopped_it_tracks(term):
    time_s = ticks(term, 60, 0.0)
    assert term.learned_plant.learned[0]
    term.reconfigure(dataclasses.replace(term.settings, probe_amplitude_K=0.0), 0.5)
    ticks(term, 6, time_s)
    assert term.state is S.TRACKING and not np.any(term.probe)
    term.enter_zone(1)                                  # another operating point: the plant learned is dropped
    assert term.state is S.LEARNING


def test_a_divergence_fades_out_waits_and_learns_again(reference_model):
    """The plant turned by 180 degrees once learned, then turning (tests/test_feedforward_learning.py): the
    guard trips, the waveform fades out whatever the switch says, and learning waits before it tries again."""
    term = FeedforwardTerm(FeedforwardSettings(model=reference_model, retry_after_s=30.0), 0.5)
    term.start(None, 0.113)
    time_s = ticks(term, 90, 0.0)
    model_plant = term.plant.copy()
    for second in range(150):
        turned = model_plant * np.exp(1j * (math.pi + 2.0 * math.pi * second / 60.0))
        feed(term, 1.0, time_s, plant=turned)
        time_s += 1
        consistent(term)
        if term.state is S.DIVERGED:
            break
    assert term.state is S.DIVERGED and term.divergences == 1 and term.scale > 0.0
    term.switch(False)                                  # a divergence is outlived by its fade-out only
    term.follow_timing(False)
    feed(term, 1.0, time_s, plant=model_plant)
    assert term.state is S.DIVERGED
    term.switch(True)
    term.follow_timing(True)
    time_s = ticks(term, 6, time_s + 1, plant=model_plant)
    assert term.state is S.WAITING_TO_RETRY and term.scale == 0.0 and not np.any(term.coefficients)
    assert "starts again in" in term.describe()
    time_s = ticks(term, 22, time_s, plant=model_plant)
    assert term.state is S.WAITING_TO_RETRY
    ticks(term, 20, time_s, plant=model_plant)
    assert term.state in PLAYING and term.scale > 0.0


def test_any_sequence_of_switching_timing_lock_and_loop_keeps_the_state_consistent(reference_model):
    """Switched on and off, cycles late and on time, the cooler stopping and the loop opening, at random:
    every event the term says is one the table takes, and its state agrees with its waveform every second."""
    generator = np.random.default_rng(7)
    term = FeedforwardTerm(FeedforwardSettings(model=reference_model, fade_time_s=3.0), 0.5)
    term.start(None, 0.113)
    time_s, cooler, closed = 0.0, True, True
    for _ in range(50):
        action = generator.integers(8)
        if action == 0:
            term.switch(not term.switched_on)
        elif action == 1:
            term.follow_timing(not term.on_time)
        elif action == 2:
            cooler = not cooler
        elif action == 3 and closed:
            closed = False
        elif action == 4:
            term.enter_zone(1)
        else:                                           # all well again
            term.switch(True)
            term.follow_timing(True)
            cooler = True
        if not closed and action != 3:
            term.start(None, 0.113)
            closed = True
        for _ in range(int(generator.integers(2, 13))):
            if closed:
                feed(term, 1.0, time_s, cooler=cooler)
            else:                                       # the loop open: T2 conditioned, nothing played
                for k in range(int(1.0 / PERIOD)):
                    t = time_s + k * PERIOD
                    term.condition(TickInputs.at(t, PERIOD, 5.0 + 1.7e-3 * math.cos(OMEGA * t - 1.1),
                                                 3.34 + (0.12 * math.cos(OMEGA * t) if cooler else 0.0), 5.0))
            time_s += 1.0
            if closed:
                consistent(term)
    term.close()
