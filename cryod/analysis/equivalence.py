"""Readings of a record that fit it equally: the equivalence classes ``cryod analyze`` reports.

* **A heater lag and both thermometers lagging alike.** The line is measured
  in T5, so a lag common to T2 and T5 leaves T2's line against T5's as it is
  and shows only on the heater's paths, exactly as a first-order lag of the
  heater's power would. ``sensor_lag`` with the stage thermometer's time
  constant within :data:`ALIKE_FRACTION` of the flange thermometer's is
  reported as equivalent to it.
* **A link that differs and the line's gain on T2 off.** At the one
  frequency of the line a link ``g / (tau s + 1)`` whose lag moves the line's
  phase by less than the recalibration's 0.1 rad is the line's gain on T2
  scaled by ``g``: a base model further off than the recalibration allows
  (the benchmark's records of a line gain 20 % off are named
  ``link_dynamics``). ``link_dynamics`` with ``atan(omega tau)`` within
  that tolerance is reported as equivalent to that gain.
* **Causes the record cannot tell apart** (rule 4 of
  :mod:`cryod.analysis.decision`): each of the tied causes.

Each reading comes with what would tell it from the cause named.
"""

from __future__ import annotations

import math

from cryod.analysis.recalibration import LINE_PHASE_TOLERANCE_RAD

#: Thermometer time constants within this fraction of each other lag "alike".
ALIKE_FRACTION = 0.25

TOLD_APART = {
    "heater lag": ("a temperature change the heater does not make (a step of the cooler's power, or a third "
                   "thermometer on the flange) shows a thermometer lag and not a heater lag; so does the "
                   "thermometers' own response measured on the bench"),
    "link_dynamics": "a record with the line at two cooler frequencies, or T2's line against a heater modulation",
    "line gain": ("nothing at the one frequency of the line: the cryostat identified (`cryod identify`) gives the "
                  "line's gain, and an analysis with that model says whether a link is left"),
    "sensor_lag": "a heater modulation at a few tenths of a hertz (a thermometer lags every path alike)",
    "dead_time": "heater steps of two sizes and a modulation above 0.1 Hz (a delay's phase grows with frequency)",
    "heater_nonlinearity": "steps of several heights from the same power (the response to P^2)",
    "heat_capacity_temperature": "steps at two temperatures (the time constants move with T)",
}


def equivalents(analysis, named) -> list[dict]:
    """Other readings that fit the record as well as the named cause ``named`` (a NamedCause)."""
    found = []
    if named.cause == "sensor_lag":
        flange = named.fit.parameters.get("flange_thermometer_time_constant_s", 0.0)
        stage = named.fit.parameters.get("ptc_stage_thermometer_time_constant_s", 0.0)
        if flange > 0.0 and abs(stage - flange) <= ALIKE_FRACTION * flange:
            found.append({"reading": f"heater lag: the heater's power reaching the flange and the stage through "
                                     f"1 / ({flange:.3g} s s + 1)", "cause": None,
                          "told_apart_by": TOLD_APART["heater lag"]})
    if named.cause == "link_dynamics":
        tau = named.fit.parameters.get("time_constant_s", 0.0)
        gain = named.fit.parameters.get("gain_factor", 1.0)
        omega = analysis.base_line.angular_frequency_rad_s
        if math.atan(omega * max(tau, 0.0)) <= LINE_PHASE_TOLERANCE_RAD:
            found.append({"reading": f"line gain: the base model's line on T2 x{gain:.3g} (beyond the "
                                     "recalibration when more than 10 % off)", "cause": "base_model_off",
                          "told_apart_by": TOLD_APART["line gain"]})
    if analysis.causes and named is analysis.causes[0]:
        for cause in analysis.decision.tied:
            found.append({"reading": cause, "cause": cause,
                          "told_apart_by": TOLD_APART.get(cause, "a record with another protocol")})
    return found


def sentence(named, readings: list[dict]) -> str:
    """The report's sentence on a cause's equivalents ('' without)."""
    if not readings:
        return ""
    others = "; ".join(reading["reading"] for reading in readings)
    apart = "; ".join(reading["told_apart_by"] for reading in readings)
    return (f"`{named.cause}` and these readings fit this record alike: {others}. What would tell them apart: "
            f"{apart}.")


__all__ = ["equivalents", "sentence"]
