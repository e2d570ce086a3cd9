"""The cryostat model: one definition, loaded from YAML, used everywhere.

The simulator, the feedforward design and the analysis all read the model
through :func:`load_model`. The physics and every equation behind the fields
are in ``docs/model.md``.

Signal structure (deviations from the operating point, heater power P in W)::

    T2 = T2_0 + G2 * (G1 * P + G_link * q)      flange thermometer
    T5 = T5_0 + G3 * P + ptc_oscillation(t)      PTC second-stage thermometer
    q  = C * d(ptc_oscillation)/dt               PTC heat oscillation (paper eq. 4)

Examples
--------
>>> model = load_model(DEFAULT_MODEL_PATH)
>>> model.operating_point.flange_temperature_K
4.23
>>> round(model.heater_to_thermometer.dc_gain, 3)      # K/W
6.818
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from cryod.transfer_function import TransferFunction, TransferFunctionError
from cryod.yaml_source import FileFormatError, Section

MODEL_FORMAT = "cryod-model v1"
DEFAULT_MODEL_PATH = Path(__file__).resolve().parent / "data" / "model.yaml"

#: Transfer-function keys of the model file, with their units and roles.
TRANSFER_FUNCTION_UNITS = {
    "heater_to_flange": "K/W",        # G1, paper eq. 9
    "flange_to_thermometer": "K/K",   # G2, paper eq. 10
    "heater_to_ptc_stage": "K/W",     # G3, paper eq. 3
    "ptc_to_flange": "K/W",           # G_link, paper eq. 11 (input: PTC heat q in W)
}

#: Names of the optional effects, as used in the model file and by ``cryod analyze``.
EFFECT_NAMES = (
    "sensor_lag",
    "link_dynamics",
    "dead_time",
    "heat_capacity_temperature",
    "heater_nonlinearity",
    "ptc_harmonics",
    "ptc_frequency_drift",
)


# ---------------------------------------------------------------------------
# model parts
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class OperatingPoint:
    """Temperatures with the heater off and the PTC line averaged out, in K."""

    flange_temperature_K: float
    ptc_stage_temperature_K: float


@dataclass(frozen=True)
class PtcHarmonic:
    """One harmonic of the PTC second-stage temperature oscillation.

    ``ptc_stage_amplitude_K * sin(order * phase(t) + phase_rad)``.
    """

    order: int
    ptc_stage_amplitude_K: float
    phase_rad: float


@dataclass(frozen=True)
class PtcSource:
    """The pulse-tube cooler's temperature oscillation seen at its second stage (T5).

    The oscillation is ``ptc_stage_amplitude_K * sin(phase(t) + phase_rad)`` plus
    harmonics, with ``phase(t)`` the integral of the angular frequency from
    ``t = 0``. The heat it drives into the flange is
    ``q = heat_capacity_J_per_K * d(oscillation)/dt`` (paper eq. 4).
    """

    angular_frequency_rad_s: float
    ptc_stage_amplitude_K: float
    phase_rad: float
    heat_capacity_J_per_K: float
    harmonics: tuple[PtcHarmonic, ...] = ()

    def components(self) -> list[tuple[int, float, float]]:
        """(order, amplitude in K, phase in rad) of the fundamental and each harmonic."""
        parts = [(1, self.ptc_stage_amplitude_K, self.phase_rad)]
        parts += [(h.order, h.ptc_stage_amplitude_K, h.phase_rad) for h in self.harmonics]
        return parts


@dataclass(frozen=True)
class SensorLag:
    """The thermometers' own response time: ``1 / (tau s + 1)`` on the reading."""

    flange_thermometer_time_constant_s: float
    ptc_stage_thermometer_time_constant_s: float = 0.0


@dataclass(frozen=True)
class LinkDynamics:
    """PTC-to-flange path differs: ``G_link -> gain_factor * G_link / (tau s + 1)``."""

    time_constant_s: float
    gain_factor: float = 1.0


@dataclass(frozen=True)
class DeadTime:
    """A pure delay between heater and flange thermometer, in s."""

    heater_to_flange_s: float


@dataclass(frozen=True)
class HeatCapacityTemperature:
    """Flange heat capacity varying with temperature.

    Every time constant of the flange paths (G1, G2, G_link) scales as
    ``(T / reference_temperature_K) ** exponent``, with T the flange temperature;
    static gains do not change.
    """

    exponent: float
    reference_temperature_K: float


@dataclass(frozen=True)
class HeaterNonlinearity:
    """Delivered power ``P + quadratic_coefficient_per_W * P**2`` for commanded P."""

    quadratic_coefficient_per_W: float

    def delivered_power_w(self, commanded_power_w):
        """Power reaching the flange for a commanded power (W in, W out)."""
        return commanded_power_w + self.quadratic_coefficient_per_W * commanded_power_w ** 2


@dataclass(frozen=True)
class PtcFrequencyDrift:
    """The cooler's angular frequency varies over time.

    ``omega(t) = omega_0 + rate * t / 3600 + wander_amplitude * sin(2 pi t / wander_period)``.
    """

    rate_rad_s_per_hour: float = 0.0
    wander_amplitude_rad_s: float = 0.0
    wander_period_s: float = 3600.0

    def angular_frequency_offset(self, time_s):
        """omega(t) - omega_0 in rad/s."""
        return (self.rate_rad_s_per_hour * np.asarray(time_s) / 3600.0
                + self.wander_amplitude_rad_s
                * np.sin(2.0 * math.pi * np.asarray(time_s) / self.wander_period_s))

    def phase_offset(self, time_s):
        """Integral of the frequency offset from 0 to t, in rad."""
        time_s = np.asarray(time_s, dtype=float)
        period = self.wander_period_s
        return (0.5 * self.rate_rad_s_per_hour * time_s ** 2 / 3600.0
                + self.wander_amplitude_rad_s * period / (2.0 * math.pi)
                * (1.0 - np.cos(2.0 * math.pi * time_s / period)))


@dataclass(frozen=True)
class SensorNoise:
    """White reading noise of each thermometer, rms in K."""

    flange_thermometer_rms_K: float = 20e-6
    ptc_stage_thermometer_rms_K: float = 0.3e-3


@dataclass(frozen=True)
class Effects:
    """Optional physical effects; ``None`` means absent."""

    sensor_lag: SensorLag | None = None
    link_dynamics: LinkDynamics | None = None
    dead_time: DeadTime | None = None
    heat_capacity_temperature: HeatCapacityTemperature | None = None
    heater_nonlinearity: HeaterNonlinearity | None = None
    ptc_frequency_drift: PtcFrequencyDrift | None = None

    def present(self) -> list[str]:
        """Names of the effects that are set."""
        return [f.name for f in dataclasses.fields(self) if getattr(self, f.name) is not None]


@dataclass(frozen=True)
class CryostatModel:
    """Everything the simulator, the controller design and the analysis know of the cryostat."""

    operating_point: OperatingPoint
    heater_to_flange: TransferFunction        # G1, K/W
    flange_to_thermometer: TransferFunction   # G2, K/K
    heater_to_ptc_stage: TransferFunction     # G3, K/W
    ptc_to_flange: TransferFunction           # G_link, K/W
    ptc: PtcSource
    effects: Effects = field(default_factory=Effects)
    sensor_noise: SensorNoise = field(default_factory=SensorNoise)
    name: str = ""
    description: str = ""
    source: str = ""

    # -- derived paths (the observable products) ----------------------------
    @property
    def heater_to_thermometer(self) -> TransferFunction:
        """G2 * G1: heater power to flange thermometer, K/W (no effects)."""
        return self.flange_to_thermometer * self.heater_to_flange

    @property
    def ptc_heat_to_thermometer(self) -> TransferFunction:
        """G2 * G_link: PTC heat to flange thermometer, K/W (no effects)."""
        return self.flange_to_thermometer * self.ptc_to_flange

    def with_effects(self, **effects) -> "CryostatModel":
        """A copy with the given effects set (``name=None`` removes one)."""
        return dataclasses.replace(self, effects=dataclasses.replace(self.effects, **effects))

    def with_ptc(self, **changes) -> "CryostatModel":
        """A copy with PTC source fields changed."""
        return dataclasses.replace(self, ptc=dataclasses.replace(self.ptc, **changes))

    def effect_names(self) -> list[str]:
        """Effects present, in the analysis vocabulary (harmonics included)."""
        names = self.effects.present()
        if self.ptc.harmonics:
            names.append("ptc_harmonics")
        return names


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
    top.finish()
    return CryostatModel(
        operating_point=operating_point,
        ptc=ptc,
        effects=effects,
        sensor_noise=noise,
        name=name,
        description=description,
        source=top.source,
        **loaded,
    )


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


def _ptc_source(section: Section) -> PtcSource:
    harmonics = []
    for item in section.sections("harmonics", []):
        harmonics.append(PtcHarmonic(
            order=item.number("order", minimum=2, integer=True),
            ptc_stage_amplitude_K=item.number("ptc_stage_amplitude_K", minimum=0.0),
            phase_rad=item.number("phase_rad"),
        ))
        item.finish()
    orders = [h.order for h in harmonics]
    if len(set(orders)) != len(orders):
        raise section.error("harmonics", f"each harmonic order may appear once, got {orders}")
    source = PtcSource(
        angular_frequency_rad_s=section.number("angular_frequency_rad_s", minimum=0.0, exclusive_minimum=True),
        ptc_stage_amplitude_K=section.number("ptc_stage_amplitude_K", minimum=0.0),
        phase_rad=section.number("phase_rad"),
        heat_capacity_J_per_K=section.number("heat_capacity_J_per_K", minimum=0.0),
        harmonics=tuple(sorted(harmonics, key=lambda h: h.order)),
    )
    section.finish()
    return source


def _effects(section: Section) -> Effects:
    found = {}
    lag = section.section("sensor_lag", None)
    if lag is not None:
        found["sensor_lag"] = SensorLag(
            flange_thermometer_time_constant_s=lag.number(
                "flange_thermometer_time_constant_s", minimum=0.0, exclusive_minimum=True),
            ptc_stage_thermometer_time_constant_s=lag.number(
                "ptc_stage_thermometer_time_constant_s", 0.0, minimum=0.0),
        )
        lag.finish()
    link = section.section("link_dynamics", None)
    if link is not None:
        found["link_dynamics"] = LinkDynamics(
            time_constant_s=link.number("time_constant_s", minimum=0.0),
            gain_factor=link.number("gain_factor", 1.0, minimum=0.0, exclusive_minimum=True),
        )
        link.finish()
    delay = section.section("dead_time", None)
    if delay is not None:
        found["dead_time"] = DeadTime(
            heater_to_flange_s=delay.number("heater_to_flange_s", minimum=0.0, maximum=600.0))
        delay.finish()
    capacity = section.section("heat_capacity_temperature", None)
    if capacity is not None:
        found["heat_capacity_temperature"] = HeatCapacityTemperature(
            exponent=capacity.number("exponent", minimum=-6.0, maximum=6.0),
            reference_temperature_K=capacity.number(
                "reference_temperature_K", minimum=0.0, exclusive_minimum=True),
        )
        capacity.finish()
    heater = section.section("heater_nonlinearity", None)
    if heater is not None:
        found["heater_nonlinearity"] = HeaterNonlinearity(
            quadratic_coefficient_per_W=heater.number(
                "quadratic_coefficient_per_W", minimum=-1.0, maximum=10.0))
        heater.finish()
    drift = section.section("ptc_frequency_drift", None)
    if drift is not None:
        found["ptc_frequency_drift"] = PtcFrequencyDrift(
            rate_rad_s_per_hour=drift.number("rate_rad_s_per_hour", 0.0),
            wander_amplitude_rad_s=drift.number("wander_amplitude_rad_s", 0.0, minimum=0.0),
            wander_period_s=drift.number("wander_period_s", 3600.0, minimum=0.0, exclusive_minimum=True),
        )
        drift.finish()
    section.finish()
    return Effects(**found)


# ---------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------
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
    effects = {name: dataclasses.asdict(getattr(model.effects, name)) for name in model.effects.present()}
    if effects:
        data["effects"] = effects
    data["sensor_noise"] = dataclasses.asdict(model.sensor_noise)
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


__all__ = [
    "CryostatModel", "DeadTime", "Effects", "EFFECT_NAMES", "FileFormatError", "HeatCapacityTemperature",
    "HeaterNonlinearity", "LinkDynamics", "OperatingPoint", "PtcFrequencyDrift", "PtcHarmonic", "PtcSource",
    "SensorLag", "SensorNoise", "DEFAULT_MODEL_PATH", "load_model", "load_model_text", "save_model",
    "model_to_dict",
]
