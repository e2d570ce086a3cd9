"""The physical limit from what the feedforward learned: the cryostat it is on, not the model.

Why, and how well it works: docs/explanation/feedforward.md ("The limit from what was learned").

The limit of :mod:`cryod.control.feedforward.limit` is computed from the
controller's model: its line, its plant at the harmonics, the mean power its
DC gain says the setpoint needs. On a cryostat that differs from the model
each of those is off; once the feedforward has learned them, the limit comes
from what it learned:

* the line ``L_n`` and the plant ``H_n`` at the waveform's harmonics, as
  estimated (:class:`cryod.control.feedforward.plant_learner.LearnedPlant`);
* the mean heater power that holds the setpoint, as PI has found it.

What would change it is computed from the same: a setpoint moved by ``step_K``
needs the mean power the measured DC gain, ``(setpoint - T2_0) / P_mean``,
says (T2_0, the flange's temperature with the heater off, from the model), and
R * I_max**2 doubled leaves the rest as it is.

Examples
--------
>>> import numpy as np
>>> from cryod.control.feedforward.plant_learner import LearnedPlant
>>> plant = LearnedPlant(np.array([7.36e-3 * np.exp(-2.0j)]), np.array([0.6 + 0j]), np.array([np.eye(2) * 1e-4]))
>>> learned = LearnedLimitInputs(plant, np.array([1.73e-3 + 0j]), 0.433, 0.5, 6.0, 0.08, 0.03)
>>> limit = learned_limit(learned, cooler_angular_frequency_rad_s=10.83, sensor_noise_rms_K=20e-6)
>>> limit.limited_by, round(limit.authority, 2), round(limit.mean_heater_power_W, 3)
('authority', 0.33, 0.433)
>>> for change in learned_limit_changes(learned, flange_base_K=4.23, cooler_angular_frequency_rad_s=10.83,
...                                     sensor_noise_rms_K=20e-6):
...     print(change.describe())
setpoint 5.5 K: 894.0 µK (authority-limited)
setpoint 6.5 K: out of reach
R I_max^2 x 2 (1000 mW): 0.0 µK (noise-limited)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cryod.control.feedforward.limit import (
    FeedforwardLimit, FeedforwardLimitError, LimitChange, SweepPoint, limit_for_plant,
)
from cryod.control.feedforward.plant_learner import LearnedPlant


@dataclass(frozen=True, eq=False)
class LearnedLimitInputs:
    """What the limit is computed from, taken together on the loop's thread.

    Attributes
    ----------
    plant : LearnedPlant
    line : numpy.ndarray
        The estimated line on T2 (K, complex per harmonic).
    mean_heater_power_w : float
        PI's mean power at the setpoint (W).
    max_heater_power_w : float
        R * I_max**2 (W).
    setpoint_K, period_s, heater_delay_s : float
    """

    plant: LearnedPlant
    line: np.ndarray
    mean_heater_power_w: float
    max_heater_power_w: float
    setpoint_K: float
    period_s: float
    heater_delay_s: float


def learned_limit(inputs: LearnedLimitInputs, *, cooler_angular_frequency_rad_s: float,
                  sensor_noise_rms_K: float, mean_heater_power_w: float | None = None,
                  max_heater_power_w: float | None = None, setpoint_K: float | None = None) -> FeedforwardLimit:
    """The limit for the learned cryostat (at another mean power, R * I_max**2 or setpoint when given).

    Raises
    ------
    FeedforwardLimitError
        When the mean power leaves no room within the heater's range.
    """
    return limit_for_plant(inputs.line, inputs.plant.plant,
                           inputs.mean_heater_power_w if mean_heater_power_w is None else mean_heater_power_w,
                           inputs.max_heater_power_w if max_heater_power_w is None else max_heater_power_w,
                           inputs.setpoint_K if setpoint_K is None else setpoint_K, inputs.period_s,
                           heater_delay_s=inputs.heater_delay_s,
                           cooler_angular_frequency_rad_s=cooler_angular_frequency_rad_s,
                           sensor_noise_rms_K=sensor_noise_rms_K)


def learned_limit_changes(inputs: LearnedLimitInputs, *, flange_base_K: float, step_K: float = 0.5,
                          **noise) -> tuple[LimitChange, ...]:
    """What would change the learned limit: the setpoint ``step_K`` down and up, R * I_max**2 doubled."""
    gain_K_per_W = (inputs.setpoint_K - flange_base_K) / inputs.mean_heater_power_w
    changes = []
    for setpoint in (inputs.setpoint_K - step_K, inputs.setpoint_K + step_K):
        mean = (setpoint - flange_base_K) / gain_K_per_W if gain_K_per_W > 0.0 else float("nan")
        changes.append(LimitChange(f"setpoint {setpoint:g} K", _point(
            inputs, setpoint, setpoint, mean, inputs.max_heater_power_w, noise)))
    doubled = 2.0 * inputs.max_heater_power_w
    changes.append(LimitChange(f"R I_max^2 x 2 ({1e3 * doubled:.0f} mW)", _point(
        inputs, doubled, inputs.setpoint_K, inputs.mean_heater_power_w, doubled, noise)))
    return tuple(changes)


def _point(inputs: LearnedLimitInputs, value: float, setpoint_K: float, mean_w: float, max_w: float,
           noise: dict) -> SweepPoint:
    """One change: the limit at that setpoint, mean power and R * I_max**2, or why there is none."""
    try:
        limit = learned_limit(inputs, mean_heater_power_w=mean_w, max_heater_power_w=max_w, setpoint_K=setpoint_K,
                              **noise)
    except FeedforwardLimitError as error:
        return SweepPoint(value, mean_w, max_w, None, str(error))
    return SweepPoint(value, mean_w, max_w, limit)


__all__ = ["LearnedLimitInputs", "learned_limit", "learned_limit_changes"]
