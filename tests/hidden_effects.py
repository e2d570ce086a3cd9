"""Effects hidden in simulated records for the analysis tests: which, how large, and what must be found.

Each cause has three magnitudes (small, realistic, large). The records are
made by :func:`simulated_hw.protocols.make_record` on the shipped model with
the effect added and, per case, the PTC phase (and for some the operating
point and line) of another day, so the analysis cannot lean on the model's own
values.
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache

from cryod.analysis.pipeline import Analysis, analyze
from cryod.analysis.record_data import RecordData
from cryod.model import (
    DeadTime, HeatCapacityTemperature, HeaterNonlinearity, LinkDynamics, OperatingPoint, PtcFrequencyDrift,
    PtcHarmonic, SensorLag, load_model,
)
from cryod.record import Record
from simulated_hw.protocols import make_record

from conftest import CONFIG

#: Per cause: (what to put in the model, {fitted parameter: true value}) for three magnitudes.
MAGNITUDES = {
    "sensor_lag": [
        ({"sensor_lag": SensorLag(0.03)}, {"flange_thermometer_time_constant_s": 0.03}),
        ({"sensor_lag": SensorLag(0.3)}, {"flange_thermometer_time_constant_s": 0.3}),
        ({"sensor_lag": SensorLag(2.0)}, {"flange_thermometer_time_constant_s": 2.0}),
    ],
    "link_dynamics": [
        ({"link_dynamics": LinkDynamics(0.03, 0.9)}, {"time_constant_s": 0.03, "gain_factor": 0.9}),
        ({"link_dynamics": LinkDynamics(0.15, 0.8)}, {"time_constant_s": 0.15, "gain_factor": 0.8}),
        ({"link_dynamics": LinkDynamics(0.6, 1.3)}, {"time_constant_s": 0.6, "gain_factor": 1.3}),
    ],
    "dead_time": [
        ({"dead_time": DeadTime(0.2)}, {"heater_to_flange_s": 0.2}),
        ({"dead_time": DeadTime(1.5)}, {"heater_to_flange_s": 1.5}),
        ({"dead_time": DeadTime(8.0)}, {"heater_to_flange_s": 8.0}),
    ],
    "heat_capacity_temperature": [
        ({"heat_capacity_temperature": HeatCapacityTemperature(-2.0, 4.23)}, {"exponent": -2.0}),
        ({"heat_capacity_temperature": HeatCapacityTemperature(1.0, 4.23)}, {"exponent": 1.0}),
        ({"heat_capacity_temperature": HeatCapacityTemperature(3.0, 4.23)}, {"exponent": 3.0}),
    ],
    "heater_nonlinearity": [
        ({"heater_nonlinearity": HeaterNonlinearity(-0.5)}, {"quadratic_coefficient_per_W": -0.5}),
        ({"heater_nonlinearity": HeaterNonlinearity(0.8)}, {"quadratic_coefficient_per_W": 0.8}),
        ({"heater_nonlinearity": HeaterNonlinearity(3.0)}, {"quadratic_coefficient_per_W": 3.0}),
    ],
    "ptc_harmonics": [
        ({"harmonics": (PtcHarmonic(2, 0.002, 1.0),)}, {"order_2_amplitude_K": 0.002}),
        ({"harmonics": (PtcHarmonic(2, 0.010, 0.4), PtcHarmonic(3, 0.005, -1.0))},
         {"order_2_amplitude_K": 0.010, "order_3_amplitude_K": 0.005}),
        ({"harmonics": (PtcHarmonic(3, 0.025, 2.5),)}, {"order_3_amplitude_K": 0.025}),
    ],
    "ptc_frequency_drift": [
        ({"ptc_frequency_drift": PtcFrequencyDrift(0.003)}, {"rate_rad_s_per_hour": 0.003}),
        ({"ptc_frequency_drift": PtcFrequencyDrift(-0.03)}, {"rate_rad_s_per_hour": -0.03}),
        ({"ptc_frequency_drift": PtcFrequencyDrift(0.0, 0.002, 700.0)},
         {"wander_amplitude_rad_s": 0.002, "wander_period_s": 700.0}),
    ],
}

#: Disturbances outside the cause list: (make_record keyword arguments), built per record length.
DISTURBANCES = {
    "heat leak step": lambda duration: {"unrecorded_heat_w": lambda t: 0.002 if t > 0.45 * duration else 0.0},
    "slow heat load drift": lambda duration: {"unrecorded_heat_w": lambda t: 0.004 * t / duration},
    "thermometer drift": lambda duration: {"flange_offset_K": lambda t: 1e-3 * t / duration},
}

DURATIONS_S = {"identification": 1200.0, "pi_only": 900.0}
SLOW_DURATIONS_S = {"identification": 3600.0, "pi_only": 1800.0}


def base_model():
    return load_model(CONFIG / "model.yaml")


def other_day(model, variant: int):
    """The same cryostat another day: PTC phase always, operating point and line for odd variants."""
    model = model.with_ptc(phase_rad=-2.8 + 1.3 * variant)
    if variant % 2:
        model = dataclasses.replace(model, operating_point=OperatingPoint(4.205, 3.318))
        model = model.with_ptc(angular_frequency_rad_s=10.71, ptc_stage_amplitude_K=0.112)
    return model


def hidden_model(cause: str, magnitude: int, variant: int = 0):
    """(model with the effect, truth) for a cause and a magnitude index."""
    changes, truth = MAGNITUDES[cause][magnitude]
    model = other_day(base_model(), variant)
    if "harmonics" in changes:
        return model.with_ptc(harmonics=changes["harmonics"]), truth
    return model.with_effects(**changes), truth


def analysed(model, protocol: str, duration_s: float, seed: int, **disturbance) -> Analysis:
    record = make_record(model, protocol, duration_s=duration_s, seed=seed, **disturbance)
    data = RecordData.from_record(Record(record.metadata, record.columns, source=f"{protocol} record"))
    return analyze(data, base_model())


@lru_cache(maxsize=None)
def analysed_case(cause: str, magnitude: int, protocol: str, duration_s: float, seed: int = 1) -> Analysis:
    if cause == "none":
        return analysed(other_day(base_model(), magnitude), protocol, duration_s, seed)
    model, _ = hidden_model(cause, magnitude, variant=magnitude + seed)
    return analysed(model, protocol, duration_s, seed)


def parameter_errors(analysis: Analysis, cause: str, truth: dict) -> dict:
    """{parameter: (fitted, true)} for the truth's parameters, from the named cause's fit."""
    fitted = analysis.fits[cause].parameters
    return {name: (fitted.get(name), true) for name, true in truth.items()}


def within(fitted, true, relative=0.2) -> bool:
    return fitted is not None and abs(fitted - true) <= relative * abs(true)
