"""What the model says about the cryostat: its parts, as frozen dataclasses.

A :class:`CryostatModel` holds the operating point, the four transfer
functions, the cooler's oscillation (:class:`PtcSource`), the optional
physical effects and the sensor noise. Files are read and written by
:mod:`cryod.model.model_file`; the equations behind every field are in
``docs/model.md``.

Examples
--------
>>> drift = PtcFrequencyDrift(rate_rad_s_per_hour=0.036)
>>> round(float(drift.angular_frequency_offset(1800.0)), 4)     # rad/s, half an hour in
0.018
>>> round(HeaterNonlinearity(0.5).delivered_power_w(0.1), 6)      # W
0.105
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from cryod.model.temperature_laws import TemperatureDependence
from cryod.model.transfer_function import TransferFunction
from cryod.model.uncertainty import ModelUncertainty

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

    ``omega(t) = omega_0 + rate * t / 3600 + wander_amplitude * sin(2 pi t / wander_period + wander_phase)``.
    """

    rate_rad_s_per_hour: float = 0.0
    wander_amplitude_rad_s: float = 0.0
    wander_period_s: float = 3600.0
    wander_phase_rad: float = 0.0

    def angular_frequency_offset(self, time_s):
        """omega(t) - omega_0 in rad/s."""
        return (self.rate_rad_s_per_hour * np.asarray(time_s) / 3600.0
                + self.wander_amplitude_rad_s
                * np.sin(2.0 * math.pi * np.asarray(time_s) / self.wander_period_s + self.wander_phase_rad))

    def phase_offset(self, time_s):
        """Integral of the frequency offset from 0 to t, in rad."""
        time_s = np.asarray(time_s, dtype=float)
        period = self.wander_period_s
        return (0.5 * self.rate_rad_s_per_hour * time_s ** 2 / 3600.0
                + self.wander_amplitude_rad_s * period / (2.0 * math.pi)
                * (math.cos(self.wander_phase_rad) - np.cos(2.0 * math.pi * time_s / period + self.wander_phase_rad)))


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
    #: The identified parameters' values, standard uncertainties and correlation (None: not stated).
    uncertainty: ModelUncertainty | None = None
    #: How the cryostat changes with temperature (None: the linear model holds at every temperature).
    temperature_dependence: TemperatureDependence | None = None

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
