"""Readings of a record that fit it equally: the equivalence classes ``cryod analyze`` reports.

* **A heater lag and both thermometers lagging alike.** The line is measured
  in T5, so a lag common to T2 and T5 leaves T2's line against T5's as it is
  and shows only on the heater's paths, exactly as a first-order lag of the
  heater's power would. ``sensor_lag`` with the stage thermometer's time
  constant within :data:`ALIKE_FRACTION` of the flange thermometer's is
  reported as equivalent to it.
* **A link that differs and the line's gain on T2 off.** At the one
  frequency of the line a link cause is one complex factor F on T2's line
  (``g / (1 + j omega tau)``, or the link refitted when the line leads). When
  F's phase is within the recalibration's 0.1 rad, the cause has no dynamics
  the record shows: its only effect is the line's gain on T2 scaled by
  ``|F|``, a parameter the base model has (:func:`line_gain_stood_for`).
  Beyond the recalibration's 10 % that is a base model further off than the
  recalibration allows, and the verdict is ``base_model_off``
  (:mod:`cryod.analysis.cause_search.base_model_off`) with the link as its equivalent
  reading; within it, the link is reported as equivalent to that gain.
* **The flange thermometer lagging, and a dead time with a link that
  differs.** A lag of T2's thermometer alone (the stage's not alike) delays
  T2 on every path: on the heater's like a dead time, as far as the heater's
  content is slow against the lag, and on the line's like a link that lags.
  With little heater content at the line the record fits both readings, and
  beside a dead time of its own the lag is a link with a dead time longer by
  the lag. When one reading is named (a lag alone, or a link with a dead
  time), the other (a dead time then a link; a lag then a dead time:
  :func:`other_way_round`) is followed as any path of causes is, and reported
  when it leaves no discrepancy either and adds less than a cause must
  (:func:`path_reading`).
* **Causes the record cannot tell apart** (rule 4 of
  :mod:`cryod.analysis.decision`): each of the tied causes.

Each reading comes with what would tell it from the cause named.
"""

from __future__ import annotations

import cmath

from cryod.analysis.recalibration import LINE_PHASE_TOLERANCE_RAD

#: The recalibration's parameter a link cause without a lag stands for.
LINE_GAIN = "line gain on T2"

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
    "dead time and link": ("a heater modulation at a few tenths of a hertz or steps with a fast edge: a "
                           "thermometer's lag rolls the response off as 1 / (1 + j omega tau), a dead time turns "
                           "its phase in proportion to the frequency and leaves its amplitude"),
    "dead_time": "heater steps of two sizes and a modulation above 0.1 Hz (a delay's phase grows with frequency)",
    "heater_nonlinearity": "steps of several heights from the same power (the response to P^2)",
    "heat_capacity_temperature": "steps at two temperatures (the time constants move with T)",
}


def link_factor_at_line(parameters: dict, angular_frequency_rad_s: float) -> complex | None:
    """The complex factor a named ``link_dynamics`` puts on T2's line, from its fitted ``parameters`` (None when
    they hold neither form): ``g / (1 + j omega tau)``, or the factor the refitted link was made from."""
    if "gain_factor" in parameters and "time_constant_s" in parameters:
        tau = max(float(parameters["time_constant_s"]), 0.0)
        return complex(float(parameters["gain_factor"])) / complex(1.0, angular_frequency_rad_s * tau)
    if "factor_at_line_gain" in parameters and "factor_at_line_phase_rad" in parameters:
        return cmath.rect(float(parameters["factor_at_line_gain"]), float(parameters["factor_at_line_phase_rad"]))
    return None


def line_gain_stood_for(named, angular_frequency_rad_s: float) -> float | None:
    """The factor on the line's gain on T2 that a named cause stands for, when it is only that (None otherwise).

    A ``link_dynamics`` whose factor at the line moves T2's line phase by no more than the recalibration's
    :data:`~cryod.analysis.recalibration.LINE_PHASE_TOLERANCE_RAD` changes, at the one frequency the record
    shows the link, only the line's amplitude on T2: the base model's own line gain, scaled by the factor's
    modulus. Whether that is beyond the recalibration's tolerance is for the recalibration to say, in its own
    terms (the link's static gain and time scale, which both move the line's amplitude): a link cause is named
    only where the recalibration within its tolerance could not reach the line.
    """
    if named.cause != "link_dynamics":
        return None
    factor = link_factor_at_line(named.fit.parameters, angular_frequency_rad_s)
    if factor is None or factor == 0 or abs(cmath.phase(factor)) > LINE_PHASE_TOLERANCE_RAD:
        return None
    return abs(factor)


def lag_on_the_flange_only(named) -> bool:
    """Whether a named cause is a lag of the flange thermometer without the stage's lagging alike."""
    if named.cause != "sensor_lag":
        return False
    flange = named.fit.parameters.get("flange_thermometer_time_constant_s", 0.0)
    stage = named.fit.parameters.get("ptc_stage_thermometer_time_constant_s", 0.0)
    return flange > 0.0 and stage < (1.0 - ALIKE_FRACTION) * flange


def other_way_round(causes) -> tuple | None:
    """The causes that read a record the other way round from the NamedCauses ``causes`` (see the module doc), in
    the order they are followed: a dead time then a link for a flange thermometer's lag named alone, the flange
    thermometer's lag then a dead time for a link named with a dead time; None for any other causes."""
    if len(causes) == 1 and lag_on_the_flange_only(causes[0]):
        return ("dead_time", "link_dynamics")
    if sorted(named.cause for named in causes) == ["dead_time", "link_dynamics"]:
        return ("sensor_lag", "dead_time")
    return None


def path_reading(causes, better: float, sigma: float) -> dict:
    """The reading of a record as the NamedCauses ``causes`` (:func:`other_way_round`) beside the causes named;
    ``better``: how much lower they leave the held-out sum of squares (noise units), ``sigma``: that in standard
    deviations of the difference between the two predictions."""
    described = " + ".join(
        f"{named.cause} (" + ", ".join(f"{name} {value:.3g}" for name, value in named.fit.parameters.items()
                                       if isinstance(value, (int, float))) + ")" for named in causes)
    return {"reading": f"{described}: they leave the held-out sum of squares {better:.3g} lower "
                       f"({sigma:.1f} sigma), less than a cause must add",
            "cause": None, "causes": [named.cause for named in causes],
            "told_apart_by": TOLD_APART["dead time and link"]}


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
    factor = line_gain_stood_for(named, analysis.base_line.angular_frequency_rad_s) \
        if named.cause == "link_dynamics" else None
    if factor is not None:
        found.append({"reading": f"line gain: the base model's line on T2 x{factor:.3g} (beyond the "
                                 "recalibration when more than 10 % off)", "cause": "base_model_off",
                      "told_apart_by": TOLD_APART["line gain"]})
    if analysis.causes and named is analysis.causes[0]:
        found.extend(analysis.other_paths)
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


def as_link(factor: float, named) -> dict:
    """The reading of a ``base_model_off`` verdict whose line gain a named link without a lag stood for."""
    parameters = ", ".join(f"{name} {value:.4g}" for name, value in named.fit.parameters.items()
                           if isinstance(value, (int, float)))
    return {"reading": f"link_dynamics ({parameters}): the link's lag too short to move the line's phase beyond "
                       f"the recalibration's {LINE_PHASE_TOLERANCE_RAD:g} rad, its gain the line's on T2 "
                       f"x{factor:.3g}", "cause": "link_dynamics", "told_apart_by": TOLD_APART["line gain"]}


__all__ = ["LINE_GAIN", "as_link", "equivalents", "lag_on_the_flange_only", "line_gain_stood_for",
           "link_factor_at_line", "other_way_round", "path_reading", "sentence"]
