"""What the model says about the cryostat: its parts, as frozen dataclasses.

A :class:`CryostatModel` holds the operating point, the four transfer
functions, the cooler's oscillation (:class:`CoolerSource`), the optional
physical effects and the sensor noise. Files are read and written by
:mod:`cryod.model.model_file`; the equations behind every field are in
``docs/explanation/cryostat-model.md``.

Examples
--------
>>> drift = CoolerFrequencyDrift(rate_rad_s_per_hour=0.036)
>>> round(float(drift.angular_frequency_offset(1800.0)), 4)     # rad/s, half an hour in
0.018
>>> round(HeaterNonlinearity(0.5).delivered_power_w(0.1), 6)      # W
0.105
"""

from __future__ import annotations

import dataclasses
import functools
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
    "ptc_amplitude_modulation",
    "ptc_stage_drift",
)
#: The generic, data-driven extension ``cryod analyze`` adds where no cause of :data:`EFFECT_NAMES` explains
#: the record: an effect of the model file, but no cause.
GENERIC_EFFECT_NAMES = ("heater_path_correction", "disturbance")


@dataclass(frozen=True)
class OperatingPoint:
    """Temperatures with the heater off and the PTC line averaged out, in K."""

    flange_temperature_K: float
    ptc_stage_temperature_K: float


@dataclass(frozen=True)
class CoolerHarmonic:
    """One harmonic of the PTC second-stage temperature oscillation.

    ``ptc_stage_amplitude_K * sin(order * phase(t) + phase_rad)``.
    """

    order: int
    ptc_stage_amplitude_K: float
    phase_rad: float


@dataclass(frozen=True)
class CoolerSource:
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
    harmonics: tuple[CoolerHarmonic, ...] = ()

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
class CoolerFrequencyDrift:
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
class CoolerAmplitudeModulation:
    """The cooler's stroke breathing: the whole oscillation (T5's line and the heat it drives) scaled by
    ``1 + depth * sin(2 pi t / period_s + phase_rad)``, t from the phase reference."""

    depth: float
    period_s: float
    phase_rad: float = 0.0

    def envelope(self, time_s):
        """Factor on the oscillation at ``time_s`` (dimensionless)."""
        return 1.0 + self.depth * np.sin(2.0 * math.pi * np.asarray(time_s, dtype=float) / self.period_s
                                         + self.phase_rad)


#: Components of a slow random process's realisation (:func:`slow_process_components`).
STAGE_DRIFT_COMPONENTS = 48


@functools.lru_cache(maxsize=64)
def slow_process_components(rms: float, correlation_time_s: float, seed: int
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(angular frequencies in rad/s, amplitudes, phases in rad) of a slow random process realised as a sum of
    sinusoids: a Lorentzian spectrum of correlation time ``correlation_time_s`` (a random walk above
    ``1 / (2 pi correlation_time_s)``, flat below) and rms ``rms``, its phases drawn from ``seed``.

    Frequencies log-spaced from a hundredth to ten times the corner (faster changes are smoothed by the
    cryostat's own heat capacities), each amplitude the square root of the Lorentzian's power in its band,
    scaled to ``rms`` in all. Remembered: the stepping plant asks at every instant (do not change the arrays).
    """
    corner = 1.0 / correlation_time_s
    edges = np.geomspace(0.01 * corner, 10.0 * corner, STAGE_DRIFT_COMPONENTS + 1)
    power = np.diff(np.arctan(edges / corner))          # integral of 1 / (1 + (w / corner)^2) per band
    frequencies = np.sqrt(edges[:-1] * edges[1:])
    amplitudes = np.sqrt(2.0 * power / power.sum()) * rms
    phases = np.random.default_rng(seed).uniform(-math.pi, math.pi, frequencies.size)
    return frequencies, amplitudes, phases


def realised(components, time_s, response=None) -> np.ndarray:
    """A sum of sinusoids ``components`` (:func:`slow_process_components`) at ``time_s``, each through
    ``response(angular frequency) -> complex gain`` when given."""
    frequencies, amplitudes, phases = components
    time_s = np.asarray(time_s, dtype=float)
    if response is not None:
        gains = np.asarray(response(frequencies), dtype=complex)
        amplitudes, phases = amplitudes * np.abs(gains), phases + np.angle(gains)
    return np.cos(np.multiply.outer(time_s, frequencies) + phases) @ amplitudes


@dataclass(frozen=True)
class PtcStageDrift:
    """The cold end's base temperature wandering (cooling water, compressor): d(t) added to T5, reaching the
    flange through ``flange_coupling / (coupling_time_constant_s s + 1)``.

    d(t) is a random process of rms ``rms_K`` whose spectrum is a Lorentzian of correlation time
    ``correlation_time_s``, realised deterministically from ``seed`` (:func:`slow_process_components`).
    """

    rms_K: float
    correlation_time_s: float
    flange_coupling: float
    coupling_time_constant_s: float
    seed: int = 0

    def components(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(angular frequencies in rad/s, amplitudes in K, phases in rad) of the realisation."""
        return slow_process_components(self.rms_K, self.correlation_time_s, self.seed)

    def offsets_K(self, time_s) -> tuple[np.ndarray, np.ndarray]:
        """(flange, stage) temperature offsets (K) at ``time_s``: the drift and its response through the coupling."""
        components = self.components()
        coupling = lambda w: self.flange_coupling / (1j * w * self.coupling_time_constant_s + 1.0)  # noqa: E731
        return realised(components, time_s, coupling), realised(components, time_s)


@dataclass(frozen=True)
class SlowProcess:
    """A slow random process of rms ``rms`` (in its quantity's unit) and correlation time ``correlation_time_s``,
    realised deterministically from ``seed`` (:func:`slow_process_components`)."""

    rms: float
    correlation_time_s: float
    seed: int = 0

    def values(self, time_s, response=None) -> np.ndarray:
        """The realisation at ``time_s`` (through ``response(angular frequency)`` when given)."""
        return realised(slow_process_components(self.rms, self.correlation_time_s, self.seed), time_s, response)


#: Thermometers a pickup can be on.
PICKUP_THERMOMETERS = ("flange", "ptc_stage")


@dataclass(frozen=True)
class Pickup:
    """A sinusoid on one thermometer's reading that no heat makes (vibration, mains, a ground loop)."""

    thermometer: str
    frequency_hz: float
    amplitude_K: float
    phase_rad: float = 0.0

    def values(self, time_s) -> np.ndarray:
        return self.amplitude_K * np.sin(2.0 * math.pi * self.frequency_hz * np.asarray(time_s, dtype=float)
                                         + self.phase_rad)


@dataclass(frozen=True)
class Disturbance:
    """Generic, data-driven extension: what a record shows that neither the heater nor the cooler makes.

    ``unrecorded_heat`` (W) reaches the thermometers as the heater's power does (through the model's heater
    paths, G2 G1 to T2 and G3 to T5: a heat load nobody recorded); ``flange_offset`` and ``ptc_stage_offset``
    (K) are added to the readings (a thermometer's drift); ``pickups`` are sinusoids on a reading. Not a
    physical cause: ``cryod analyze`` fits it where no cause explains the record; the processes' statistics
    are what a record gives, realised from their seeds (:class:`SlowProcess`).
    """

    unrecorded_heat: SlowProcess | None = None
    flange_offset: SlowProcess | None = None
    ptc_stage_offset: SlowProcess | None = None
    pickups: tuple = ()

    def offsets_K(self, time_s, heat_to_flange=None, heat_to_stage=None) -> tuple[np.ndarray, np.ndarray]:
        """(flange, stage) offsets (K) at ``time_s``; ``heat_to_flange(w)`` and ``heat_to_stage(w)`` give the
        heater paths' complex gains (K/W) at angular frequency w (rad/s)."""
        time_s = np.asarray(time_s, dtype=float)
        flange, stage = np.zeros(time_s.shape), np.zeros(time_s.shape)
        if self.unrecorded_heat is not None:
            flange = flange + self.unrecorded_heat.values(time_s, heat_to_flange)
            stage = stage + self.unrecorded_heat.values(time_s, heat_to_stage)
        if self.flange_offset is not None:
            flange = flange + self.flange_offset.values(time_s)
        if self.ptc_stage_offset is not None:
            stage = stage + self.ptc_stage_offset.values(time_s)
        for pickup in self.pickups:
            if pickup.thermometer == "flange":
                flange = flange + pickup.values(time_s)
            else:
                stage = stage + pickup.values(time_s)
        return flange, stage


@dataclass(frozen=True)
class HeaterPathCorrection:
    """Generic, data-driven extension: first-order terms added in parallel to the heater's paths.

    ``G1 -> G1 + sum(flange_gains_K_per_W[i] / (time_constants_s[i] s + 1))`` and the same on G3 with
    ``ptc_stage_gains_K_per_W``. Not a physical cause: ``cryod analyze`` fits it where no cause explains the
    record, to model what is left.
    """

    time_constants_s: tuple
    flange_gains_K_per_W: tuple
    ptc_stage_gains_K_per_W: tuple

    def paths(self) -> tuple:
        """(added to G1, added to G3) as transfer functions (None where every gain is 0)."""
        found = []
        for gains in (self.flange_gains_K_per_W, self.ptc_stage_gains_K_per_W):
            total = None
            for tau, gain in zip(self.time_constants_s, gains):
                if gain == 0.0:
                    continue
                term = TransferFunction.first_order_lag(tau, gain)
                total = term if total is None else total + term
            found.append(total)
        return tuple(found)


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
    ptc_frequency_drift: CoolerFrequencyDrift | None = None
    ptc_amplitude_modulation: CoolerAmplitudeModulation | None = None
    #: A :class:`PtcStageDrift`, or any object with its ``offsets_K(time_s)`` (a drift measured in a record).
    ptc_stage_drift: PtcStageDrift | None = None
    heater_path_correction: HeaterPathCorrection | None = None
    #: A :class:`Disturbance`, or any object with its ``offsets_K(time_s, heat_to_flange, heat_to_stage)``.
    disturbance: Disturbance | None = None

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
    ptc: CoolerSource
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
