"""Whether a record can support the fit of the heater paths, and if not, what it lacks.

Checked before any fit, each with a message a lab user can act on:

* a heater step: the heater must change, by enough to move T2 well above its
  noise (:data:`MINIMUM_STEP_IN_NOISE` times the noise, at the base model's
  DC gain);
* enough response after it: the record must go on for at least
  :data:`MINIMUM_SETTLE_TIME_CONSTANTS` of the base model's longest time
  constant after the first step (a fit cannot tell a time constant it never
  saw decay);
* readings: at most :data:`MAXIMUM_MISSING_FRACTION` of the rows without T2 or T5
  (NaN: a DMM that did not answer);
* a heater that delivered what the record says: at most
  :data:`MAXIMUM_SATURATED_FRACTION` of the rows with the heater at its limit
  R I_max^2 (there the supply may sit in compliance and deliver less).

Examples
--------
>>> import numpy as np
>>> t = np.arange(0.0, 300.0, 0.08)
>>> heater = np.where(t > 100.0, 0.01, 0.0)
>>> flat = np.full(t.size, 4.23)
>>> problems = fit_support_problems(t, heater, flat, flat - 0.9, longest_time_constant_s=165.0,
...                                 dc_gain_K_per_W=6.8, noise_rms_K=2e-5)
>>> print(problems[0])
the record holds 200 s after the heater step at 100 s: the fit needs at least 495 s (3 x the longest time constant, 165 s): record the step for longer
"""

from __future__ import annotations

import numpy as np

from cryod.analysis.record_data import RecordData
from cryod.model import CryostatModel

#: The heater step must move T2 by at least this many times its noise.
MINIMUM_STEP_IN_NOISE = 50.0
#: After the first step the record must last this many of the longest time constant.
MINIMUM_SETTLE_TIME_CONSTANTS = 3.0
#: At most this fraction of rows may lack T2 or T5.
MAXIMUM_MISSING_FRACTION = 0.2
#: At most this fraction of rows may have the heater at its limit.
MAXIMUM_SATURATED_FRACTION = 0.05


def fit_support_problems(time_s, heater_w, flange_K, stage_K, *, longest_time_constant_s: float,
                         dc_gain_K_per_W: float, noise_rms_K: float, heater_limit_w: float | None = None) -> list[str]:
    """What the record lacks for a fit of the heater paths ([] when nothing).

    Parameters
    ----------
    time_s, heater_w, flange_K, stage_K : array_like
        The record's columns (s, W, K, K).
    longest_time_constant_s, dc_gain_K_per_W : float
        What the base model expects of the heater-to-T2 path.
    noise_rms_K : float
        T2's noise.
    heater_limit_w : float, optional
        R I_max^2, where the record states it.
    """
    time_s = np.asarray(time_s, dtype=float)
    heater = np.asarray(heater_w, dtype=float)
    valid = np.isfinite(np.asarray(flange_K, dtype=float)) & np.isfinite(np.asarray(stage_K, dtype=float))
    problems = []
    missing = 1.0 - float(np.mean(valid)) if valid.size else 1.0
    if missing > MAXIMUM_MISSING_FRACTION:
        problems.append(f"{100 * missing:.0f} % of the rows have no T2 or T5 (NaN: a thermometer that did not "
                        f"answer); at most {100 * MAXIMUM_MISSING_FRACTION:.0f} % may: check the DMMs and record "
                        "again")
    change = np.abs(np.diff(heater))
    largest = float(change.max()) if change.size else 0.0
    needed = MINIMUM_STEP_IN_NOISE * noise_rms_K / abs(dc_gain_K_per_W) if dc_gain_K_per_W else 0.0
    if largest <= 0.0:
        problems.append("no heater step: the heater never changes in this record; record a step (cryod identify "
                        "--acquire does)")
    elif largest < needed:
        problems.append(f"the largest heater step, {largest * 1e3:.3g} mW, moves T2 by about "
                        f"{largest * abs(dc_gain_K_per_W) * 1e6:.1f} µK, under {MINIMUM_STEP_IN_NOISE:g} x its noise "
                        f"({noise_rms_K * 1e6:.1f} µK): a step of at least {needed * 1e3:.2g} mW is needed")
    else:
        first = int(np.flatnonzero(change >= 0.5 * largest)[0]) + 1
        after = float(time_s[-1] - time_s[first])
        wanted = MINIMUM_SETTLE_TIME_CONSTANTS * longest_time_constant_s
        if after < wanted:
            problems.append(f"the record holds {after:.0f} s after the heater step at {time_s[first] - time_s[0]:.0f} "
                            f"s: the fit needs at least {wanted:.0f} s ({MINIMUM_SETTLE_TIME_CONSTANTS:g} x the "
                            f"longest time constant, {longest_time_constant_s:.0f} s): record the step for longer")
    if heater_limit_w:
        saturated = float(np.mean(heater >= heater_limit_w * (1.0 - 1e-6)))
        if saturated > MAXIMUM_SATURATED_FRACTION:
            problems.append(f"the heater sits at its limit ({heater_limit_w:g} W) in {100 * saturated:.0f} % of the "
                            f"rows (at most {100 * MAXIMUM_SATURATED_FRACTION:.0f} %): there the supply may be in "
                            "compliance and deliver less than recorded; use a step within the heater's range")
    return problems


def record_problems(data: RecordData, base: CryostatModel) -> list[str]:
    """:func:`fit_support_problems` for a checked record, with the base model's expectations."""
    path = base.heater_to_thermometer
    taus = path.time_constants_s
    return fit_support_problems(data.time_s, data.heater_w, data.flange_K, data.ptc_stage_K,
                                longest_time_constant_s=max(taus) if taus else 0.0, dc_gain_K_per_W=path.dc_gain,
                                noise_rms_K=base.sensor_noise.flange_thermometer_rms_K,
                                heater_limit_w=data.heater_limit_w)


def describe(source: str, problems: list[str]) -> str:
    """One message for a record that cannot support the fit."""
    return f"{source} cannot support the fit: " + "; ".join(problems)


__all__ = ["fit_support_problems", "record_problems", "describe"]
