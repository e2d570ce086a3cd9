"""Measurement programs run on the simulated cryostat: the records the model tools are tested on.

Three kinds, as in the lab:

* :func:`identification_program`: open-loop heater holds and steps at 4.23 K,
  heater modulation at the PTC line and away from it, a PI segment to 5 K,
  holds and a step near 5 K, and a PI segment to 4.6 K. Every effect the
  analysis knows leaves a mark on one of them.
* :func:`pi_only_program`: the paper's Fig. 6, PI from the zero-heater
  operating point to 5 K and held there.
* ``"feedforward"``: the same PI with the daemon's adaptive feedforward
  (:mod:`cryod.control.feedforward`) running from the start, as the service
  regulates; its controller model is the one given (the shipped model in the
  lab), not the cryostat's.

:func:`make_record` runs a program on a model (with any hidden effect in it)
and returns the cryod-log columns and metadata, ready for
:func:`cryod.records.record.write_record`.

Examples
--------
>>> from cryod.model import load_model
>>> record = make_record(load_model(), "pi_only", duration_s=300.0, seed=1)
>>> sorted(record.columns)[:3], record.metadata["heater_resistance_ohm"]
(['T2_K', 'T5_K', 'heater_W'], '25.0')
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, TypedDict

import numpy as np

from cryod.control.closed_loop import Segment, run_program
from cryod.control.pi import PiGains
from cryod.model import CryostatModel

if TYPE_CHECKING:
    from cryod.control.feedforward import FeedforwardSettings

#: Heater of the simulated records: 25 ohm, 100 mA limit, so at most 0.25 W.
HEATER_RESISTANCE_OHM = 25.0
HEATER_CURRENT_LIMIT_A = 0.1
HEATER_MAX_W = HEATER_RESISTANCE_OHM * HEATER_CURRENT_LIMIT_A ** 2
#: PI gains of the simulated records (W/K, W/(K s)).
RECORD_GAINS = PiGains(proportional_w_per_K=0.4, integral_w_per_K_s=0.01)
#: Angular frequency of the heater modulation away from the line (rad/s).
OFF_LINE_MODULATION_RAD_S = 2.5

PROTOCOLS = ("identification", "pi_only", "feedforward")


class _Action(TypedDict, total=False):
    """What a segment of a program does: one of the two, as :class:`~cryod.control.closed_loop.Segment` takes it."""

    setpoint_K: float
    heater_power_w: float | Callable[[float], float]


def _modulation(mean_w: float, amplitude_w: float, angular_frequency_rad_s: float) -> Callable[[float], float]:
    return lambda t: mean_w + amplitude_w * math.sin(angular_frequency_rad_s * t)


def identification_program(model: CryostatModel, duration_s: float = 3600.0) -> list[Segment]:
    """Segments of an identification-style record, scaled to ``duration_s``.

    Nominal layout (3800 s): hold 0 W (200 s); steps to 10 mW and 30 mW
    (400 s each); 20 +- 15 mW modulated at the PTC line (240 s) and at
    2.5 rad/s (240 s); PI to 5 K (800 s); holds at 110 mW (500 s) and 140 mW
    (520 s); PI to 4.6 K (500 s).
    """
    line = model.ptc.angular_frequency_rad_s
    nominal: list[tuple[float, _Action]] = [
        (200.0, {"heater_power_w": 0.0}),
        (400.0, {"heater_power_w": 0.010}),
        (400.0, {"heater_power_w": 0.030}),
        (240.0, {"heater_power_w": _modulation(0.020, 0.015, line)}),
        (240.0, {"heater_power_w": _modulation(0.020, 0.015, OFF_LINE_MODULATION_RAD_S)}),
        (800.0, {"setpoint_K": 5.0}),
        (500.0, {"heater_power_w": 0.110}),
        (520.0, {"heater_power_w": 0.140}),
        (500.0, {"setpoint_K": 4.6}),
    ]
    scale = duration_s / sum(length for length, _ in nominal)
    segments, start = [], 0.0
    for length, action in nominal:
        segments.append(Segment(start, **action))
        start += length * scale
    return segments


def pi_only_program(setpoint_K: float = 5.0) -> list[Segment]:
    """PI from the zero-heater operating point to ``setpoint_K`` (paper Fig. 6)."""
    return [Segment(0.0, setpoint_K=setpoint_K)]


@dataclass(frozen=True)
class SimulatedRecordColumns:
    """A record made on the simulated cryostat: cryod-log columns and metadata."""

    columns: dict
    metadata: dict


def make_record(model: CryostatModel, protocol: str, *, duration_s: float = 3600.0, seed: int = 0,
                unrecorded_heat_w: Callable[[float], float] | None = None,
                flange_offset_K: Callable[[np.ndarray], np.ndarray] | None = None,
                period_s: float = 0.08, timing_jitter_s: float = 0.0,
                setpoint_K: float = 5.0, controller_model: CryostatModel | None = None) -> SimulatedRecordColumns:
    """Run a protocol on the simulated cryostat.

    Parameters
    ----------
    model : CryostatModel
        The cryostat, with whatever effect it should have.
    protocol : str
        ``"identification"``, ``"pi_only"`` or ``"feedforward"``.
    duration_s : float
    seed : int
        Sensor-noise seed.
    unrecorded_heat_w : callable, optional
        Heat reaching the flange that the record does not show (disturbance).
    flange_offset_K : callable, optional
        Added to the recorded T2 after the run (a thermometer drift the loop did not see).
    period_s, timing_jitter_s : float
        Loop period and the largest lateness of a trigger (s).
    setpoint_K : float
        Setpoint of the PI-only and feedforward protocols.
    controller_model : CryostatModel, optional
        The feedforward's model (default: ``model`` itself).

    Returns
    -------
    SimulatedRecordColumns
    """
    more_terms: tuple[tuple[str, FeedforwardSettings], ...] = ()
    if protocol == "identification":
        segments = identification_program(model, duration_s)
    elif protocol in ("pi_only", "feedforward"):
        segments = pi_only_program(setpoint_K)
        if protocol == "feedforward":
            from cryod.control.feedforward import FeedforwardSettings

            more_terms = (("feedforward", FeedforwardSettings(model=controller_model or model, period_s=period_s)),)
    else:
        raise ValueError(f"unknown protocol {protocol!r}; known: {', '.join(PROTOCOLS)}")
    run = run_program(model, segments, duration_s, gains=RECORD_GAINS, heater_max_w=HEATER_MAX_W, seed=seed,
                      unrecorded_heat_w=unrecorded_heat_w, period_s=period_s, timing_jitter_s=timing_jitter_s,
                      more_terms=more_terms)
    columns = run.columns()
    if flange_offset_K is not None:
        columns["T2_K"] = columns["T2_K"] + flange_offset_K(columns["time_s"])
    metadata = {
        "source": "simulated_hw.measurement_programs",
        "protocol": protocol,
        "heater_resistance_ohm": f"{HEATER_RESISTANCE_OHM}",
        "heater_current_limit_A": f"{HEATER_CURRENT_LIMIT_A}",
        "pi_gains": f"Kp {RECORD_GAINS.proportional_w_per_K} W/K, Ki {RECORD_GAINS.integral_w_per_K_s} W/(K s)",
        "loop_period_s": f"{period_s}",
    }
    return SimulatedRecordColumns(columns, metadata)
