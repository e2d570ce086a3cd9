"""Effects hidden in simulated records, for testing and benchmarking ``cryod analyze``.

Each cause has three magnitudes (small, realistic, large) with the parameter
values the analysis must find; :data:`DISTURBANCES` are changes outside the
cause list (the analysis must say ``unexplained``). :func:`other_day` gives the
same cryostat on another day (its own PTC phase, and for odd variants its own
operating point and line), so a test cannot lean on the model's own values.

Examples
--------
>>> from cryod.model import load_model
>>> model, truth = hidden_model(load_model(), "dead_time", 1)
>>> model.effects.dead_time.heater_to_flange_s, truth
(1.5, {'heater_to_flange_s': 1.5})
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from cryod.model import (
    CoolerFrequencyDrift,
    CoolerHarmonic,
    CryostatModel,
    DeadTime,
    HeatCapacityTemperature,
    HeaterNonlinearity,
    LinkDynamics,
    OperatingPoint,
    SensorLag,
)

#: What to put in the model for a cause: effects by name (:meth:`CryostatModel.with_effects`), or the cooler's
#: ``harmonics`` (:meth:`CryostatModel.with_ptc`).
ModelChanges = dict[str, SensorLag | LinkDynamics | DeadTime | HeatCapacityTemperature | HeaterNonlinearity
                    | CoolerFrequencyDrift | tuple[CoolerHarmonic, ...]]

#: Per cause: (what to put in the model, {fitted parameter: true value}) for three magnitudes.
MAGNITUDES: dict[str, list[tuple[ModelChanges, dict[str, float]]]] = {
    "sensor_lag": [
        ({"sensor_lag": SensorLag(0.03)}, {"flange_thermometer_time_constant_s": 0.03}),
        ({"sensor_lag": SensorLag(0.3)}, {"flange_thermometer_time_constant_s": 0.3}),
        ({"sensor_lag": SensorLag(1.0, 0.4)},
         {"flange_thermometer_time_constant_s": 1.0, "ptc_stage_thermometer_time_constant_s": 0.4}),
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
        ({"harmonics": (CoolerHarmonic(2, 0.002, 1.0),)}, {"order_2_amplitude_K": 0.002}),
        ({"harmonics": (CoolerHarmonic(2, 0.010, 0.4), CoolerHarmonic(3, 0.005, -1.0))},
         {"order_2_amplitude_K": 0.010, "order_3_amplitude_K": 0.005}),
        ({"harmonics": (CoolerHarmonic(3, 0.025, 2.5),)}, {"order_3_amplitude_K": 0.025}),
    ],
    "ptc_frequency_drift": [
        ({"ptc_frequency_drift": CoolerFrequencyDrift(0.003)}, {"rate_rad_s_per_hour": 0.003}),
        ({"ptc_frequency_drift": CoolerFrequencyDrift(-0.03)}, {"rate_rad_s_per_hour": -0.03}),
        ({"ptc_frequency_drift": CoolerFrequencyDrift(0.0, 0.002, 700.0)},
         {"wander_amplitude_rad_s": 0.002, "wander_period_s": 700.0}),
    ],
}

#: Disturbances outside the cause list: (make_record keyword arguments), built per record length.
DISTURBANCES = {
    "heat leak step": lambda duration: {"unrecorded_heat_w": lambda t: 0.002 if t > 0.45 * duration else 0.0},
    "slow heat load drift": lambda duration: {"unrecorded_heat_w": lambda t: 0.004 * t / duration},
    "thermometer drift": lambda duration: {"flange_offset_K": lambda t: 1e-3 * t / duration},
}


def other_day(model: CryostatModel, variant: int) -> CryostatModel:
    """The same cryostat another day: PTC phase always, operating point and line for odd variants."""
    model = model.with_ptc(phase_rad=-2.8 + 1.3 * variant)
    if variant % 2:
        model = dataclasses.replace(model, operating_point=OperatingPoint(4.205, 3.318))
        model = model.with_ptc(angular_frequency_rad_s=10.71, ptc_stage_amplitude_K=0.112)
    return model


#: How far the truth's base parameters are moved from the shipped model's by :func:`perturbed_base`:
#: each gain and time constant by up to this fraction, the line's phase by up to this many rad.
PERTURBATION_FRACTION = 0.05
PERTURBATION_LINE_PHASE_RAD = 0.05


def perturbed_base(model: CryostatModel, seed: int, fraction: float = PERTURBATION_FRACTION,
                   line_phase_rad: float = PERTURBATION_LINE_PHASE_RAD) -> tuple[CryostatModel, dict]:
    """The same kind of cryostat with its base parameters off by a few percent, as real ones are.

    Each gain and time constant of the model's structure is multiplied by a
    factor drawn uniformly from ``1 +- fraction``: G1's static gain, its zero's
    and its pole's time constants, G2's time constant, G3's gain and time
    constant, the link's static gain. The line's phase on T2 is moved by up to
    ``line_phase_rad`` through the link's time constant. The model must have
    the shipped structure (G1 one zero and one pole, G2, G3 and the link first
    order).

    Parameters
    ----------
    model : CryostatModel
    seed : int
        Seed of the draw.
    fraction : float
        Largest relative change of a gain or a time constant.
    line_phase_rad : float
        Largest change of the line's phase on T2 (rad).

    Returns
    -------
    model : CryostatModel
    changes : dict
        The factor applied to each parameter (and the line's phase change in rad).

    Examples
    --------
    >>> from cryod.model import load_model
    >>> model, changes = perturbed_base(load_model(), seed=3)
    >>> all(abs(factor - 1.0) <= 0.05 for name, factor in changes.items() if name != "line_phase_rad")
    True
    """
    from cryod.model.transfer_function import TransferFunction

    generator = np.random.default_rng(seed)
    names = ("flange_gain", "flange_zero_time_constant", "flange_time_constant", "thermometer_time_constant",
             "stage_gain", "stage_time_constant", "link_gain")
    factors = {name: float(1.0 + generator.uniform(-fraction, fraction)) for name in names}
    shift = float(generator.uniform(-line_phase_rad, line_phase_rad))
    (zero, gain), (pole, _) = model.heater_to_flange.numerator, model.heater_to_flange.denominator
    gain_new = gain * factors["flange_gain"]
    zero_time = zero / gain * factors["flange_zero_time_constant"]
    heater_to_flange = TransferFunction((zero_time * gain_new, gain_new), (pole * factors["flange_time_constant"], 1.0))
    thermometer = TransferFunction.first_order_lag(model.flange_to_thermometer.denominator[0]
                                                   * factors["thermometer_time_constant"])
    stage = TransferFunction.first_order_lag(model.heater_to_ptc_stage.denominator[0] * factors["stage_time_constant"],
                                             model.heater_to_ptc_stage.dc_gain * factors["stage_gain"])
    omega = model.ptc.angular_frequency_rad_s
    link_time = model.ptc_to_flange.denominator[0]
    link_time = math.tan(math.atan(omega * link_time) - shift) / omega
    link = TransferFunction.first_order_lag(link_time, model.ptc_to_flange.dc_gain * factors["link_gain"])
    changed = dataclasses.replace(model, heater_to_flange=heater_to_flange, flange_to_thermometer=thermometer,
                                  heater_to_ptc_stage=stage, ptc_to_flange=link)
    return changed, {**factors, "line_phase_rad": shift}


#: Base-model parameters a cryostat can have further off than the recalibration's tolerance (:func:`far_off`).
FAR_OFF_PARAMETERS = ("heater power scale", "flange time constant", "line gain", "thermometer time constant")


def far_off(model: CryostatModel, parameter: str, factor: float, reference: CryostatModel) -> CryostatModel:
    """``model`` with one base parameter set to ``factor`` times ``reference``'s (the shipped model's).

    The parameter is set against the reference, not scaled on ``model``'s own
    (already perturbed) value, so that the cryostat is ``factor`` off the model
    the analysis is given, whatever :func:`perturbed_base` did to it:

    * ``"heater power scale"``: G1's and G3's static gains (a wrong heater
      resistance scales every heater path);
    * ``"flange time constant"``: G1's pole;
    * ``"line gain"``: the line's gain on T2, T2's line amplitude over T5's
      (``|G2 G_link|`` at the line, what the recalibration calls ``line gain on
      T2``), set through the link's static gain; the link's phase stays as it is;
    * ``"thermometer time constant"``: G2's time constant.

    Examples
    --------
    >>> from cryod.model import load_model
    >>> shipped = load_model()
    >>> model, _ = perturbed_base(shipped, seed=3)
    >>> off = far_off(model, "line gain", 1.2, shipped)
    >>> omega = shipped.ptc.angular_frequency_rad_s
    >>> line = lambda m: abs(m.flange_to_thermometer.frequency_response(omega) * m.ptc_to_flange.frequency_response(omega))
    >>> round(line(off) / line(shipped), 6)
    1.2
    """
    from cryod.model.transfer_function import TransferFunction

    if parameter == "heater power scale":
        flange = model.heater_to_flange * (factor * reference.heater_to_flange.dc_gain / model.heater_to_flange.dc_gain)
        stage = model.heater_to_ptc_stage * (factor * reference.heater_to_ptc_stage.dc_gain
                                             / model.heater_to_ptc_stage.dc_gain)
        return dataclasses.replace(model, heater_to_flange=flange, heater_to_ptc_stage=stage)
    if parameter == "flange time constant":
        (zero, gain), (_, one) = model.heater_to_flange.numerator, model.heater_to_flange.denominator
        pole = reference.heater_to_flange.denominator[0] * factor
        return dataclasses.replace(model, heater_to_flange=TransferFunction((zero, gain), (pole, one)))
    if parameter == "line gain":
        omega = model.ptc.angular_frequency_rad_s

        def line(item):
            return abs(item.flange_to_thermometer.frequency_response(omega) * item.ptc_to_flange.frequency_response(omega))

        return dataclasses.replace(model, ptc_to_flange=model.ptc_to_flange * (factor * line(reference) / line(model)))
    if parameter == "thermometer time constant":
        tau = reference.flange_to_thermometer.denominator[0] * factor
        return dataclasses.replace(model, flange_to_thermometer=TransferFunction.first_order_lag(tau))
    raise ValueError(f"unknown base parameter {parameter!r}: one of {', '.join(FAR_OFF_PARAMETERS)}")


def hidden_model(model: CryostatModel, cause: str, magnitude: int, variant: int = 0):
    """(model with the effect, truth) for a cause and a magnitude index (0, 1, 2), on day ``variant``."""
    changes, truth = MAGNITUDES[cause][magnitude]
    model = other_day(model, variant)
    if "harmonics" in changes:
        return model.with_ptc(harmonics=changes["harmonics"]), truth
    return model.with_effects(**changes), truth


#: The causes by the part of the cryostat they change; two effects from different groups are told apart.
EFFECT_GROUPS = {
    "heater path": ("dead_time", "heater_nonlinearity", "heat_capacity_temperature"),
    "link and thermometers": ("sensor_lag", "link_dynamics"),
    "cooler": ("ptc_harmonics", "ptc_frequency_drift"),
}


def combined_model(model: CryostatModel, causes: dict, variant: int = 0):
    """(model with several effects, {cause: truth}) for ``{cause: magnitude index}``, on day ``variant``."""
    model = other_day(model, variant)
    truths = {}
    for cause, magnitude in causes.items():
        changes, truth = MAGNITUDES[cause][magnitude]
        if "harmonics" in changes:
            model = model.with_ptc(harmonics=changes["harmonics"])
        else:
            model = model.with_effects(**changes)
        truths[cause] = truth
    return model, truths


def within(fitted, true, relative: float = 0.2) -> bool:
    """Fitted value within ``relative`` of the true one."""
    return fitted is not None and abs(fitted - true) <= relative * abs(true)
