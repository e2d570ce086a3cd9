"""The simulated cryostat on a clock: what the simulated instruments measure and heat.

:class:`SimulatedCryostat` wraps the model's stepping plant (:func:`cryod.model.cryostat_plant`) with
an injected clock, seeded sensor noise and a lock (instrument emulators may
serve from several threads). It advances the plant to "now" whenever a reading
is taken or the heater is written.

Examples
--------
>>> from drivers.clock import VirtualClock
>>> from cryod.model import load_model
>>> clock = VirtualClock()
>>> cryostat = SimulatedCryostat(load_model(), clock, seed=1)
>>> clock.advance(10.0)
>>> flange_K, stage_K = cryostat.read_temperatures()
>>> 4.22 < flange_K < 4.24 and 3.2 < stage_K < 3.5
True
"""

from __future__ import annotations

import threading

import numpy as np

from cryod.model import CryostatModel, cryostat_plant
from drivers.clock import Clock

#: Sensor-noise draws taken from the generator at once.
NORMALS_PER_BLOCK = 1024


class SimulatedCryostat:
    """Flange and PTC-stage thermometers and the heater of a simulated cryostat.

    Parameters
    ----------
    model : CryostatModel
        The physics (``config/model.yaml`` or an extended model).
    clock : Clock
        Source of "now"; a :class:`drivers.clock.VirtualClock` in tests.
    seed : int, optional
        Seed of the sensor-noise generator (reproducible runs).
    noise : bool
        Add the model's sensor noise to readings.
    initial_heater_power_w : float
        Heater power the cryostat has settled at before the start (W).
    """

    def __init__(self, model: CryostatModel, clock: Clock, seed: int | None = None,
                 noise: bool = True, initial_heater_power_w: float = 0.0):
        self.model = model
        self.clock = clock
        self.noise = noise
        self._random = np.random.default_rng(seed)
        self._normals: list[float] = []
        self._next_normal = 0
        self._lock = threading.Lock()
        self.plant = cryostat_plant(model, clock.now(), initial_heater_power_w)
        self._last_window: tuple | None = None
        self._last_window_temperatures = (0.0, 0.0)

    @property
    def heater_power_w(self) -> float:
        """Heater power commanded now (W)."""
        return self.plant.commanded_power_w

    def _noisy(self, flange_K: float, stage_K: float) -> tuple[float, float]:
        if not self.noise:
            return flange_K, stage_K
        noise = self.model.sensor_noise
        return (flange_K + noise.flange_thermometer_rms_K * self._standard_normal(),
                stage_K + noise.ptc_stage_thermometer_rms_K * self._standard_normal())

    def _standard_normal(self) -> float:
        """The generator's next standard normal draw: drawn a block at a time, the same numbers in the same
        order as one at a time (numpy's generator fills a block draw by draw), at a fraction of the cost."""
        if self._next_normal == len(self._normals):
            self._normals = self._random.standard_normal(NORMALS_PER_BLOCK).tolist()
            self._next_normal = 0
        value = self._normals[self._next_normal]
        self._next_normal += 1
        return value

    def read_temperatures(self) -> tuple[float, float]:
        """(T2, T5) in K at the clock's now, with sensor noise."""
        with self._lock:
            self.plant.advance_to(self.clock.now())
            return self._noisy(*self.plant.temperatures())

    def true_temperatures(self) -> tuple[float, float]:
        """(T2, T5) in K at the clock's now, without noise."""
        with self._lock:
            self.plant.advance_to(self.clock.now())
            return self.plant.temperatures()

    def read_mean_temperatures(self, start_s: float, duration_s: float) -> tuple[float, float]:
        """(T2, T5) in K averaged over ``[start_s, start_s + duration_s]``, with noise.

        A DMM's integration window: the plant advances to ``start_s`` (which
        must not be in the plant's past) and the heater is taken as held. Both
        DMMs of one trigger ask for the same window: they get the same pair
        (each thermometer's own noise drawn once), computed once.
        """
        with self._lock:
            key = (start_s, duration_s, self.plant.commanded_power_w)
            if key == self._last_window:
                return self._last_window_temperatures
            self.plant.advance_to(max(start_s, self.plant.time_s))
            result = self._noisy(*self.plant.mean_temperatures(duration_s))
            self._last_window, self._last_window_temperatures = key, result
            return result

    def set_heater_power(self, power_w: float) -> None:
        """Apply a heater power (W) from the clock's now on."""
        if power_w < 0.0:
            raise ValueError(f"heater power cannot be negative, got {power_w} W")
        with self._lock:
            self.plant.set_heater_power(power_w, max(self.clock.now(), self.plant.time_s))
