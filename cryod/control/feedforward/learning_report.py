"""What the feedforward's learning tells the journal and the data log, as it happens.

Events, each a (logging level, text) pair the regulator hands on with the
term's name (the loop writes them into the record as ``# event: feedforward:
...`` lines and logs them):

* the plant at the line learned, or back to the model's;
* the learned plant differing from the model beyond its uncertainty, in
  words, with what to do (:meth:`cryod.control.feedforward.plant_learner.LearnedPlant.differences_said`),
  and when it agrees again (a warning each time the harmonics that differ
  change, and when the plant has moved since by more than :data:`MOVED_BY`
  in gain or :data:`MOVED_BY_DEG` in phase, at most every
  :data:`SAY_AGAIN_S`: not each time a ratio's last digit wobbles). Only
  on settled data: T2 at its setpoint for :data:`SETTLED_FOR_S`, and the same
  harmonics differing at every step for :data:`DIFFERING_FOR_S`. The learning
  goes on through a setpoint change or a zone's entry, but what it finds in the
  transient (T2 ramping under the cooler's line, PI's power moving with it) is
  not what the cryostat is, and a warning that clears itself seconds later
  teaches the operator to ignore the one that matters;
* the learned plant itself, every :data:`RECORD_EVERY_S` and when the
  harmonics learned have changed (at most every :data:`SAY_AGAIN_S`; the data
  log keeps it with the readings);
* a probe burst that ended before the plant was known to the precision asked;
* a divergence, and the reset;
* the setpoint in use entering another zone (``control.zones``): the learned plant
  starts again from the zone's model.

Examples
--------
>>> import numpy as np
>>> from cryod.control.feedforward.plant_learner import LearnedPlant
>>> report = LearningReport()
>>> plant = LearnedPlant(np.array([7.36e-3 * np.exp(-2.0j)]), np.array([0.62 * np.exp(-1.22j)]),
...                      np.array([np.eye(2) * 1e-4]))
>>> for time_s in range(0, 301, 2):         # T2 at its setpoint throughout, learning a step every 2 s
...     report.step(float(time_s), plant, given_up=[], settled=True)
>>> for level, text in report.take():
...     print(level, text)
20 plant learned at the line: 0.620 x the model's, -69.9 deg
20 learned plant: harmonic 1: 0.6200 +-0.0100 x, -69.90 +-0.92 deg
30 the heater reaches T2 1.6x weaker and 70 degrees later than the model at the line: re-commission with cryod identify --acquire
>>> report.take()
()
"""

from __future__ import annotations

import logging
import math

import numpy as np

from cryod.control.feedforward.plant_learner import LearnedPlant

#: The learned plant is written into the data log this often (s), and when the harmonics learned have changed.
RECORD_EVERY_S = 600.0
#: A difference from the model is said again when the plant moved since, at most this often (s).
SAY_AGAIN_S = 60.0
#: ... by this fraction of its gain at a harmonic that differs,
MOVED_BY = 0.15
#: ... or by this much in phase (degrees).
MOVED_BY_DEG = 15.0
#: A difference is said only once T2 has been at its setpoint this long (s): three times the learning's memory, so
#: that what it learned in a setpoint's transient is forgotten.
SETTLED_FOR_S = 180.0
#: ... and once the same harmonics have differed at every step for this long (s).
DIFFERING_FOR_S = 60.0


class LearningReport:
    """Turns the learning's steps into events (module notes)."""

    def __init__(self) -> None:
        self._events: list[tuple[int, str]] = []
        self._fundamental_learned = False
        self._differences: tuple[int, ...] = ()
        self._said: LearnedPlant | None = None
        self._said_at_s = -math.inf
        self._learned: tuple[bool, ...] = ()
        self._recorded_at_s = -math.inf
        self._given_up: tuple[int, ...] = ()
        self._settled_since_s: float | None = None
        self._seen: tuple[int, ...] = ()        # the harmonics that differed at the last step ...
        self._seen_since_s = -math.inf          # ... and since when they have, at every step

    def step(self, time_s: float, plant: LearnedPlant, given_up: list[int], settled: bool = True) -> None:
        """What a learning step found: the plant, and the harmonics whose probe burst ended short; ``settled``:
        T2 at its setpoint (:attr:`cryod.control.feedforward.power_levels.PowerLevels.settled`)."""
        learned = bool(plant.learned[0])
        if learned != self._fundamental_learned:
            self._fundamental_learned = learned
            self._say(logging.INFO, f"plant learned at the line: {plant.gain_ratio[0]:.3f} x the model's, "
                                    f"{plant.phase_deg[0]:+.1f} deg" if learned else
                      "plant at the line no longer known well enough: the model's is used")
        differing = tuple(index for index in range(plant.harmonics) if any(plant.differs(index)))
        if differing != self._seen:
            self._seen, self._seen_since_s = differing, time_s
        if not settled:
            self._settled_since_s = None
        elif self._settled_since_s is None:
            self._settled_since_s = time_s
        if self._on_settled_data(time_s) and (
                differing != self._differences or (self._moved_since_said(plant, differing)
                                                   and time_s - self._said_at_s >= SAY_AGAIN_S)):
            self._differences, self._said, self._said_at_s = differing, plant, time_s
            if differing:
                self._say(logging.WARNING, plant.differences_said() or "")
            else:
                self._say(logging.INFO, "the learned plant agrees with the model within its uncertainty")
        harmonics_learned = tuple(bool(value) for value in plant.learned)
        since = time_s - self._recorded_at_s
        if (harmonics_learned != self._learned and since >= SAY_AGAIN_S) or since >= RECORD_EVERY_S:
            self._learned = harmonics_learned
            self._recorded_at_s = time_s
            if any(harmonics_learned):
                self._say(logging.INFO, f"learned plant: {plant.record_text()}")
        short = tuple(given_up)
        new = [order for order in short if order not in self._given_up]
        self._given_up = short
        for order in new:
            spread = plant.relative_spread[order - 1]
            self._say(logging.INFO, f"probe at harmonic {order} ended with the plant known to {100 * spread:.0f} % "
                                    f"(the heater's room or the plant's weakness limits it); "
                                    + ("the learned value is used" if plant.learned[order - 1]
                                       else "the model's is used and the waveform leaves that harmonic alone"))

    def _on_settled_data(self, time_s: float) -> bool:
        """T2 has been at its setpoint for :data:`SETTLED_FOR_S`, and the harmonics that differ now have differed
        at every step for :data:`DIFFERING_FOR_S`: what the plant says now is the cryostat, not a transient."""
        return (self._settled_since_s is not None and time_s - self._settled_since_s >= SETTLED_FOR_S
                and time_s - self._seen_since_s >= DIFFERING_FOR_S)

    def _moved_since_said(self, plant: LearnedPlant, differing: tuple[int, ...]) -> bool:
        """At a harmonic that differs, the plant's gain moved by :data:`MOVED_BY` or its phase by
        :data:`MOVED_BY_DEG` since the difference was last said."""
        if not differing:
            return False
        if self._said is None:
            return True
        index = list(differing)
        gain_moved = np.abs(plant.gain_ratio[index] / self._said.gain_ratio[index] - 1.0)
        phase_moved = np.abs((plant.phase_deg[index] - self._said.phase_deg[index] + 180.0) % 360.0 - 180.0)
        return bool(np.any(gain_moved > MOVED_BY) or np.any(phase_moved > MOVED_BY_DEG))

    def diverged(self, reason: str, retry_s: float) -> None:
        """The divergence guard tripped."""
        self._say(logging.WARNING, f"learning diverged: {reason}; the waveform fades out, the learned plant is "
                                   f"reset to the model and learning starts again in {retry_s:.0f} s")
        self._forget_the_plant()

    def zone_entered(self, index: int, model_source: str) -> None:
        """The setpoint in use moved into zone ``index`` (from 0): the learned plant starts again from its model."""
        self._say(logging.INFO, f"zone {index + 1} entered: the plant learned at the previous zone's operating point "
                                f"is dropped; learning starts again from the zone's model ({model_source})")
        self._forget_the_plant()

    def _forget_the_plant(self) -> None:
        """What was said of the learned plant no longer holds: the next learning is reported afresh."""
        self._fundamental_learned = False
        self._differences = ()
        self._said = None
        self._learned = ()

    def _say(self, level: int, text: str) -> None:
        self._events.append((level, text))

    def take(self) -> tuple[tuple[int, str], ...]:
        """The events since the last call (cheap when there are none)."""
        if not self._events:
            return ()
        events, self._events = tuple(self._events), []
        return events


__all__ = ["LearningReport", "RECORD_EVERY_S", "SAY_AGAIN_S"]
