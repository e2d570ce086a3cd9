"""Ticks fed straight into a feedforward term, as the regulator gives them, with T2 answering the heater.

``feed`` drives a :class:`cryod.control.feedforward.FeedforwardTerm` without the regulator or a
simulated cryostat: T5 carries the cooler's line (0.12 K at 10.83 rad/s), T2 its own line plus what
the heater played the tick before through a given plant at each harmonic.
"""

import math

import numpy as np

from cryod.control.terms import TickInputs

OMEGA = 10.83           # the cooler's line, rad/s
PERIOD = 0.08           # the loop's period, s


def feed(term, seconds, start_s=0.0, cooler=True, flange_K=5.0, plant=None):
    """Ticks into the term as the regulator would give them, T2 answering what the heater played last tick
    through ``plant`` (K/W per harmonic; the term's model by default); returns the outputs."""
    outputs = []
    answer = np.zeros(term.settings.harmonics, dtype=complex)
    orders = np.arange(1, term.settings.harmonics + 1)
    for k in range(int(seconds / PERIOD)):
        t = start_s + k * PERIOD
        stage = 3.34 + (0.12 * math.cos(OMEGA * t) if cooler else 0.0)
        played = float(np.real(np.sum(answer * np.exp(1j * orders * OMEGA * t))))
        tick = TickInputs.at(t, PERIOD, flange_K + 1.7e-3 * math.cos(OMEGA * t - 1.1) + played, stage, 5.0)
        tick = term.condition(tick)
        outputs.append(term.update(tick))
        term.limit(0.113 + outputs[-1], 0.113 + outputs[-1])
        response = term.plant if plant is None else plant
        answer = response * (term.coefficients + term.probe) * (term.scale if outputs[-1] else 0.0)
    return np.array(outputs)
