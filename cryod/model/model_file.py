"""Model files (``cryod-model v1``): read and check one, write one back.

:func:`load_model` turns a YAML model file into a
:class:`~cryod.model.parameters.CryostatModel`, with an error naming file,
line and key for anything wrong; :func:`save_model` writes a file it reads
back to an equal model. The fields are described in ``docs/explanation/cryostat-model.md``.

Examples
--------
>>> model_to_dict(load_model(DEFAULT_MODEL_PATH))["operating_point"]
{'flange_temperature_K': 4.23, 'ptc_stage_temperature_K': 3.34}
>>> load_model_text("format: cryod-model v2")
Traceback (most recent call last):
    ...
cryod.yaml_source.FileFormatError: <model text>:1: format: expected 'cryod-model v1', got 'cryod-model v2'
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import yaml

from cryod.model.parameters import (
    PICKUP_THERMOMETERS, CryostatModel, DeadTime, Disturbance, Effects, HeatCapacityTemperature, HeaterNonlinearity,
    HeaterPathCorrection, LinkDynamics, OperatingPoint, Pickup, CoolerAmplitudeModulation, CoolerFrequencyDrift,
    CoolerHarmonic, CoolerSource, PtcStageDrift, SensorLag, SensorNoise, SlowProcess,
)
from cryod.model.temperature_laws import TemperatureDependence
from cryod.model.transfer_function import TransferFunction, TransferFunctionError
from cryod.model.uncertainty import ModelUncertainty, UncertaintyError, check_consistent, inconsistencies
from cryod.yaml_source import Section

MODEL_FORMAT = "cryod-model v1"
DEFAULT_MODEL_PATH = Path(__file__).resolve().parent.parent / "data" / "model.yaml"

#: Transfer-function keys of the model file, with their units and roles.
TRANSFER_FUNCTION_UNITS = {
    "heater_to_flange": "K/W",        # G1, paper eq. 9
    "flange_to_thermometer": "K/K",   # G2, paper eq. 10
    "heater_to_ptc_stage": "K/W",     # G3, paper eq. 3
    "ptc_to_flange": "K/W",           # G_link, paper eq. 11 (input: PTC heat q in W)
}


# ---------------------------------------------------------------------------
# loading
# ---------------------------------------------------------------------------
def load_model(path: str | Path = DEFAULT_MODEL_PATH) -> CryostatModel:
    """Read and validate a model file.

    Parameters
    ----------
    path : str or pathlib.Path
        The YAML model file (``config/model.yaml`` is the shipped one).

    Returns
    -------
    CryostatModel

    Raises
    ------
    cryod.yaml_source.FileFormatError
        Naming file, line and key, for a missing file, invalid YAML, a missing
        or unknown key, a wrong type, an improper or unstable transfer function,
        or a non-positive time constant.
    """
    return model_from_section(Section.from_file(path))


def load_model_text(text: str, source: str = "<model text>") -> CryostatModel:
    """Like :func:`load_model`, from YAML text."""
    return model_from_section(Section.from_text(text, source))


def model_from_section(top: Section) -> CryostatModel:
    """Build a :class:`CryostatModel` from a parsed top-level section."""
    model_format = top.text("format")
    if model_format != MODEL_FORMAT:
        raise top.error("format", f"expected '{MODEL_FORMAT}', got {model_format!r}")
    name = top.text("name", "")
    description = top.text("description", "")

    point = top.section("operating_point")
    operating_point = OperatingPoint(
        flange_temperature_K=point.number("flange_temperature_K", exclusive_minimum=True, minimum=0.0),
        ptc_stage_temperature_K=point.number("ptc_stage_temperature_K", exclusive_minimum=True, minimum=0.0),
    )
    point.finish()

    functions = top.section("transfer_functions")
    loaded = {key: _transfer_function(functions, key, units) for key, units in TRANSFER_FUNCTION_UNITS.items()}
    functions.finish()

    ptc = _ptc_source(top.section("ptc"))
    effects_section = top.section("effects", None)
    effects = _effects(effects_section) if effects_section is not None else Effects()
    noise_section = top.section("sensor_noise", None)
    noise = SensorNoise()
    if noise_section is not None:
        noise = SensorNoise(
            flange_thermometer_rms_K=noise_section.number("flange_thermometer_rms_K", 20e-6, minimum=0.0),
            ptc_stage_thermometer_rms_K=noise_section.number("ptc_stage_thermometer_rms_K", 0.3e-3, minimum=0.0),
        )
        noise_section.finish()
    uncertainty_section = top.section("uncertainty", None)
    temperature_section = top.section("temperature_dependence", None)
    temperature_dependence = None
    if temperature_section is not None:
        temperature_dependence = _temperature_dependence(temperature_section)
        if effects.present():
            raise top.error("temperature_dependence", f"the temperature-dependent cryostat takes no effects: remove "
                                                      f"effects ({', '.join(effects.present())}) or this section")
    top.finish()
    model = CryostatModel(
        operating_point=operating_point,
        ptc=ptc,
        effects=effects,
        sensor_noise=noise,
        name=name,
        description=description,
        source=top.source,
        temperature_dependence=temperature_dependence,
        **loaded,
    )
    if uncertainty_section is not None:
        model = dataclasses.replace(model, uncertainty=_uncertainty(uncertainty_section, model))
    return model


def _uncertainty(section: Section, model: CryostatModel) -> ModelUncertainty:
    """The optional ``uncertainty`` section: each fitted parameter's value, standard uncertainty and
    correlation row; the model's transfer functions must follow from the values."""
    method = section.text("method", "")
    items = section.sections("parameters")
    names, values, sigmas, rows = [], [], [], []
    for item in items:
        names.append(item.text("name"))
        values.append(item.number("value"))
        sigmas.append(item.number("standard_uncertainty", minimum=0.0))
        rows.append(item.numbers("correlation"))
        item.finish()
    section.finish()
    for index, (item, row) in enumerate(zip(items, rows)):
        if len(row) != len(items):
            raise item.error("correlation", f"needs {len(items)} coefficients, one per parameter, got {len(row)}")
    try:
        uncertainty = ModelUncertainty(tuple(names), tuple(values), tuple(sigmas), tuple(map(tuple, rows)), method)
        check_consistent(model, uncertainty)
    except UncertaintyError as error:
        raise section.error("parameters", str(error)) from None
    return uncertainty


def _temperature_dependence(section: Section) -> TemperatureDependence:
    """The optional ``temperature_dependence`` section (the laws of :mod:`cryod.model.temperature_laws`)."""
    defaults = TemperatureDependence()
    values = {
        "gamma_J_per_mol_K2": section.number("gamma_J_per_mol_K2", defaults.gamma_J_per_mol_K2, minimum=0.0),
        "beta_J_per_mol_K4": section.number("beta_J_per_mol_K4", defaults.beta_J_per_mol_K4, minimum=0.0),
        "conductance_exponent": section.number("conductance_exponent", defaults.conductance_exponent,
                                               minimum=0.0, maximum=4.0),
        "stage_line_exponent": section.number("stage_line_exponent", defaults.stage_line_exponent,
                                              minimum=-4.0, maximum=4.0),
    }
    section.finish()
    try:
        return TemperatureDependence(**values)
    except ValueError as error:
        raise section.error("gamma_J_per_mol_K2", str(error)) from None


def _transfer_function(functions: Section, key: str, units: str) -> TransferFunction:
    section = functions.section(key)
    numerator = section.numbers("numerator")
    denominator = section.numbers("denominator")
    stated_units = section.text("units", units)
    if stated_units != units:
        raise section.error("units", f"this transfer function is in {units}, not {stated_units!r}")
    section.text("note", "")
    section.finish()
    try:
        return TransferFunction(tuple(numerator), tuple(denominator))
    except TransferFunctionError as error:
        raise section.error("denominator", f"not a usable transfer function: {error}") from None


def _ptc_source(section: Section) -> CoolerSource:
    harmonics = []
    for item in section.sections("harmonics", []):
        harmonics.append(CoolerHarmonic(
            order=item.number("order", minimum=2, integer=True),
            ptc_stage_amplitude_K=item.number("ptc_stage_amplitude_K", minimum=0.0),
            phase_rad=item.number("phase_rad"),
        ))
        item.finish()
    orders = [h.order for h in harmonics]
    if len(set(orders)) != len(orders):
        raise section.error("harmonics", f"each harmonic order may appear once, got {orders}")
    source = CoolerSource(
        angular_frequency_rad_s=section.number("angular_frequency_rad_s", minimum=0.0, exclusive_minimum=True),
        ptc_stage_amplitude_K=section.number("ptc_stage_amplitude_K", minimum=0.0),
        phase_rad=section.number("phase_rad"),
        heat_capacity_J_per_K=section.number("heat_capacity_J_per_K", minimum=0.0),
        harmonics=tuple(sorted(harmonics, key=lambda h: h.order)),
    )
    section.finish()
    return source


def _sensor_lag(part: Section) -> SensorLag:
    return SensorLag(
        flange_thermometer_time_constant_s=part.number(
            "flange_thermometer_time_constant_s", minimum=0.0, exclusive_minimum=True),
        ptc_stage_thermometer_time_constant_s=part.number("ptc_stage_thermometer_time_constant_s", 0.0, minimum=0.0))


def _link_dynamics(part: Section) -> LinkDynamics:
    return LinkDynamics(time_constant_s=part.number("time_constant_s", minimum=0.0),
                        gain_factor=part.number("gain_factor", 1.0, minimum=0.0, exclusive_minimum=True))


def _dead_time(part: Section) -> DeadTime:
    return DeadTime(heater_to_flange_s=part.number("heater_to_flange_s", minimum=0.0, maximum=600.0))


def _heat_capacity_temperature(part: Section) -> HeatCapacityTemperature:
    return HeatCapacityTemperature(
        exponent=part.number("exponent", minimum=-6.0, maximum=6.0),
        reference_temperature_K=part.number("reference_temperature_K", minimum=0.0, exclusive_minimum=True))


def _heater_nonlinearity(part: Section) -> HeaterNonlinearity:
    return HeaterNonlinearity(
        quadratic_coefficient_per_W=part.number("quadratic_coefficient_per_W", minimum=-1.0, maximum=10.0))


def _ptc_frequency_drift(part: Section) -> CoolerFrequencyDrift:
    return CoolerFrequencyDrift(
        rate_rad_s_per_hour=part.number("rate_rad_s_per_hour", 0.0),
        wander_amplitude_rad_s=part.number("wander_amplitude_rad_s", 0.0, minimum=0.0),
        wander_period_s=part.number("wander_period_s", 3600.0, minimum=0.0, exclusive_minimum=True),
        wander_phase_rad=part.number("wander_phase_rad", 0.0))


def _ptc_amplitude_modulation(part: Section) -> CoolerAmplitudeModulation:
    return CoolerAmplitudeModulation(
        depth=part.number("depth", minimum=0.0, maximum=0.9),
        period_s=part.number("period_s", minimum=0.0, exclusive_minimum=True),
        phase_rad=part.number("phase_rad", 0.0))


def _ptc_stage_drift(part: Section) -> PtcStageDrift:
    return PtcStageDrift(
        rms_K=part.number("rms_K", minimum=0.0, maximum=1.0),
        correlation_time_s=part.number("correlation_time_s", minimum=0.0, exclusive_minimum=True),
        flange_coupling=part.number("flange_coupling", minimum=-10.0, maximum=10.0),
        coupling_time_constant_s=part.number("coupling_time_constant_s", minimum=0.0),
        seed=part.number("seed", 0, minimum=0.0, integer=True))


def _heater_path_correction(part: Section) -> HeaterPathCorrection:
    taus = part.numbers("time_constants_s")
    if any(tau <= 0.0 for tau in taus):
        raise part.error("time_constants_s", f"each time constant must be positive, got {taus}")
    gains = {}
    for key in ("flange_gains_K_per_W", "ptc_stage_gains_K_per_W"):
        gains[key] = part.numbers(key)
        if len(gains[key]) != len(taus):
            raise part.error(key, f"needs one gain per time constant ({len(taus)}), got {len(gains[key])}")
    return HeaterPathCorrection(tuple(taus), tuple(gains["flange_gains_K_per_W"]),
                                tuple(gains["ptc_stage_gains_K_per_W"]))


def _effects(section: Section) -> Effects:
    readers = {"sensor_lag": _sensor_lag, "link_dynamics": _link_dynamics, "dead_time": _dead_time,
               "heat_capacity_temperature": _heat_capacity_temperature, "heater_nonlinearity": _heater_nonlinearity,
               "ptc_frequency_drift": _ptc_frequency_drift, "ptc_amplitude_modulation": _ptc_amplitude_modulation,
               "ptc_stage_drift": _ptc_stage_drift, "heater_path_correction": _heater_path_correction,
               "disturbance": _disturbance}
    found = {}
    for name, read in readers.items():
        part = section.section(name, None)
        if part is not None:
            found[name] = read(part)
            part.finish()
    section.finish()
    return Effects(**found)


#: The disturbance's slow processes: (key, unit of its rms).
DISTURBANCE_PROCESSES = (("unrecorded_heat", "W"), ("flange_offset", "K"), ("ptc_stage_offset", "K"))


def _disturbance(section: Section) -> Disturbance:
    processes = {}
    for key, unit in DISTURBANCE_PROCESSES:
        process = section.section(key, None)
        if process is not None:
            processes[key] = SlowProcess(
                rms=process.number(f"rms_{unit}", minimum=0.0, maximum=1.0),
                correlation_time_s=process.number("correlation_time_s", minimum=0.0, exclusive_minimum=True),
                seed=process.number("seed", 0, minimum=0.0, integer=True))
            process.finish()
    pickups = []
    for pickup in section.sections("pickups", []):
        pickups.append(Pickup(
            thermometer=pickup.text("thermometer", choices=PICKUP_THERMOMETERS),
            frequency_hz=pickup.number("frequency_hz", minimum=0.0, exclusive_minimum=True),
            amplitude_K=pickup.number("amplitude_K", minimum=0.0, maximum=1.0),
            phase_rad=pickup.number("phase_rad", 0.0)))
        pickup.finish()
    return Disturbance(pickups=tuple(pickups), **processes)


def _disturbance_dict(disturbance: Disturbance) -> dict:
    data = {}
    for key, unit in DISTURBANCE_PROCESSES:
        process = getattr(disturbance, key)
        if process is not None:
            data[key] = {f"rms_{unit}": process.rms, "correlation_time_s": process.correlation_time_s,
                         "seed": process.seed}
    if disturbance.pickups:
        data["pickups"] = [dataclasses.asdict(pickup) for pickup in disturbance.pickups]
    return data


# ---------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------
def _plain_effect(effect) -> dict:
    """An effect's fields as a mapping (tuples as lists)."""
    return {key: list(value) if isinstance(value, tuple) else value
            for key, value in dataclasses.asdict(effect).items()}


def model_to_dict(model: CryostatModel) -> dict:
    """The model as the plain mapping written to a model file."""
    data: dict = {"format": MODEL_FORMAT}
    if model.name:
        data["name"] = model.name
    if model.description:
        data["description"] = model.description
    data["operating_point"] = dataclasses.asdict(model.operating_point)
    data["transfer_functions"] = {
        key: {**getattr(model, key).to_dict(), "units": units}
        for key, units in TRANSFER_FUNCTION_UNITS.items()
    }
    ptc = {
        "angular_frequency_rad_s": model.ptc.angular_frequency_rad_s,
        "ptc_stage_amplitude_K": model.ptc.ptc_stage_amplitude_K,
        "phase_rad": model.ptc.phase_rad,
        "heat_capacity_J_per_K": model.ptc.heat_capacity_J_per_K,
    }
    if model.ptc.harmonics:
        ptc["harmonics"] = [dataclasses.asdict(h) for h in model.ptc.harmonics]
    data["ptc"] = ptc
    effects = {name: _disturbance_dict(model.effects.disturbance) if name == "disturbance"
               else _plain_effect(getattr(model.effects, name)) for name in model.effects.present()}
    if effects:
        data["effects"] = effects
    data["sensor_noise"] = dataclasses.asdict(model.sensor_noise)
    if model.temperature_dependence is not None:
        data["temperature_dependence"] = dataclasses.asdict(model.temperature_dependence)
    if model.uncertainty is not None and not inconsistencies(model, model.uncertainty):
        # (a model changed after identification keeps no uncertainty: the stated one was of other values)
        stated = model.uncertainty
        data["uncertainty"] = {
            **({"method": stated.method} if stated.method else {}),
            "parameters": [
                {"name": name, "value": value, "standard_uncertainty": sigma,
                 "correlation": list(row)}
                for name, value, sigma, row in zip(stated.names, stated.values, stated.standard_uncertainties,
                                                   stated.correlation)
            ],
        }
    return data


def save_model(model: CryostatModel, path: str | Path, header: str = "") -> Path:
    """Write a model file that :func:`load_model` reads back to an equal model.

    Parameters
    ----------
    model : CryostatModel
    path : str or pathlib.Path
    header : str
        Comment lines (without '#') written at the top, e.g. provenance.

    Returns
    -------
    pathlib.Path
        The path written.
    """
    path = Path(path)
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    text = yaml.safe_dump(_plain(model_to_dict(model)), sort_keys=False, default_flow_style=None, width=100)
    path.write_text(("\n".join(lines) + "\n" if lines else "") + text, encoding="utf-8")
    return path


def _plain(value):
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    if isinstance(value, float):
        return float(repr(float(value)))      # numpy floats too: their repr is not a YAML number
    return value

