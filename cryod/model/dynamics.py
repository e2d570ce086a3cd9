"""The cryostat's dynamics: noise-free T2 and T5 from a model and the heater history.

How the parts combine (equations in ``docs/explanation/cryostat-model.md``):

* the heater paths (G2*G1 to the flange thermometer, G3 to the PTC stage),
  each a :class:`~cryod.model.heater_path.HeaterPath`: exact for a heater
  power held between writes at any instants;
* the PTC paths (G2*G_link to the flange thermometer, the T5 oscillation to
  its thermometer), each a :class:`~cryod.model.cooler_path.CoolerPath`: the
  cooler's steady oscillation evaluated at the exact instant asked for.

Effects of the model are applied as physics: delivered heater power
(nonlinearity), a delay queue (dead time), an extra lag on the readings
(sensor lag), a changed PTC-to-flange path (link dynamics), time constants
scaled with the flange temperature (heat capacity), harmonics and frequency
drift of the cooler, its amplitude modulated (the whole oscillation scaled by a
slow envelope), the cold end's drift (added to T5, and to T2 through its
coupling), and the generic extension: a correction of the heater paths (terms
in parallel with G1 and G3) and a disturbance (an unrecorded heat load, slow
offsets and pickups of the readings).

:class:`CryostatPlant` steps through time, an instant at a time (the
simulated cryostat on a clock, the closed-loop studies); :func:`simulate`
computes a whole record at once (analysis, identification, figures).

Examples
--------
>>> from cryod.model import load_model
>>> plant = CryostatPlant(load_model())
>>> plant.set_heater_power(0.0088, time_s=0.0)
>>> plant.advance_to(2000.0)
>>> round(plant.temperatures()[0] - 4.23, 2)     # step height of T2, K (plus PTC line)
0.06
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from cryod.model.heater_path import HeaterPath
from cryod.model.kept_results import KeptResults, digest
from cryod.model.parameters import CryostatModel
from cryod.model.cooler_path import CoolerDrive, CoolerPath
from cryod.model.transfer_function import TransferFunction


# ---------------------------------------------------------------------------
# the plant
# ---------------------------------------------------------------------------
def _kept_per_model(function):
    """Keep ``function(model)`` for the last 64 models (a model built with unhashable parts is not kept)."""
    kept = functools.lru_cache(maxsize=64)(function)

    @functools.wraps(function)
    def wrapper(model):
        try:
            hash(model)
        except TypeError:
            return function(model)
        return kept(model)
    return wrapper


@_kept_per_model
def flange_transfer_functions(model: CryostatModel) -> tuple[TransferFunction, TransferFunction]:
    """(heater to flange thermometer, PTC heat to flange thermometer) with link and sensor effects.

    Kept for the last models asked for (models and transfer functions are immutable): the analysis
    builds a plant for the same model many times.
    """
    effects = model.effects
    heater_to_flange = model.heater_to_flange
    if effects.heater_path_correction is not None and effects.heater_path_correction.paths()[0] is not None:
        heater_to_flange = heater_to_flange + effects.heater_path_correction.paths()[0]
    heater = model.flange_to_thermometer * heater_to_flange
    link = model.ptc_to_flange
    if effects.link_dynamics is not None:
        extra = TransferFunction.first_order_lag(
            effects.link_dynamics.time_constant_s, effects.link_dynamics.gain_factor)
        link = link * extra
    ptc = model.flange_to_thermometer * link
    if effects.sensor_lag is not None:
        lag = TransferFunction.first_order_lag(effects.sensor_lag.flange_thermometer_time_constant_s)
        heater = heater * lag
        ptc = ptc * lag
    return heater, ptc


@_kept_per_model
def stage_transfer_functions(model: CryostatModel) -> tuple[TransferFunction, TransferFunction]:
    """(heater to PTC-stage thermometer, stage oscillation to PTC-stage thermometer)."""
    heater = model.heater_to_ptc_stage
    correction = model.effects.heater_path_correction
    if correction is not None and correction.paths()[1] is not None:
        heater = heater + correction.paths()[1]
    oscillation = TransferFunction((1.0,), (1.0,))
    lag = model.effects.sensor_lag
    if lag is not None and lag.ptc_stage_thermometer_time_constant_s > 0.0:
        sensor = TransferFunction.first_order_lag(lag.ptc_stage_thermometer_time_constant_s)
        heater = heater * sensor
        oscillation = sensor
    return heater, oscillation


class CryostatPlant:
    """Noise-free flange (T2) and PTC-stage (T5) thermometer temperatures of a model.

    Time is explicit: every call names the instant (s), which must not go
    backwards. The heater power is held between writes.

    Parameters
    ----------
    model : CryostatModel
    start_time_s : float
        Instant at which the plant starts (PTC phase reference).
    initial_heater_power_w : float
        Heater power the plant is in steady state with at the start.
    ptc_cycle : optional
        The cooler's phase and frequency over time, instead of the model's own
        (:class:`~cryod.model.cooler_cycle.MeasuredCoolerCycle`: a record's).
    """

    def __init__(self, model: CryostatModel, start_time_s: float = 0.0,
                 initial_heater_power_w: float = 0.0, ptc_cycle=None):
        self.model = model
        self.start_time_s = float(start_time_s)
        self.time_s = float(start_time_s)
        effects = model.effects
        flange_heater, flange_ptc = flange_transfer_functions(model)
        stage_heater, stage_oscillation = stage_transfer_functions(model)
        drive = self.drive = CoolerDrive(model, ptc_cycle)
        self.flange_heater = HeaterPath(flange_heater)
        self.stage_heater = HeaterPath(stage_heater)
        self.flange_ptc = CoolerPath(drive, flange_ptc, input_is_heat=True)
        self.stage_ptc = CoolerPath(drive, stage_oscillation, input_is_heat=False)
        self.dead_time_s = effects.dead_time.heater_to_flange_s if effects.dead_time else 0.0
        self.nonlinearity = effects.heater_nonlinearity
        self.heat_capacity = effects.heat_capacity_temperature
        self.modulation = effects.ptc_amplitude_modulation
        self.stage_drift = effects.ptc_stage_drift
        self.disturbance = effects.disturbance
        self._heater_responses = (flange_heater.frequency_response, stage_heater.frequency_response)
        self.commanded_power_w = float(initial_heater_power_w)
        delivered = self.delivered_power_w(self.commanded_power_w)
        self.flange_heater.settle(delivered)
        self.stage_heater.settle(delivered)
        self._pending: list[tuple[float, float]] = []   # (instant, delivered power) for the flange path

    # -- inputs -------------------------------------------------------------
    def delivered_power_w(self, commanded_power_w: float) -> float:
        """Power reaching the cryostat for a commanded heater power (W)."""
        if self.nonlinearity is None:
            return commanded_power_w
        return float(self.nonlinearity.delivered_power_w(commanded_power_w))

    def set_heater_power(self, power_w: float, time_s: float) -> None:
        """Change the heater power at ``time_s`` (W); held until the next change."""
        self.advance_to(time_s)
        self.commanded_power_w = float(power_w)
        delivered = self.delivered_power_w(self.commanded_power_w)
        self.stage_heater.input = delivered
        if self.dead_time_s > 0.0:
            self._pending.append((self.time_s + self.dead_time_s, delivered))
        else:
            self.flange_heater.input = delivered

    # -- time ---------------------------------------------------------------
    def time_scale(self) -> float:
        """Factor on the flange time constants now (1 without the heat-capacity effect)."""
        if self.heat_capacity is None:
            return 1.0
        return float(self.time_scale_at(self.flange_heater.output()))

    def time_scale_at(self, flange_heater_output_K):
        """Factor on the flange time constants for heater-path outputs of the flange (K).

        Scalar or array in, the same out; ``(T / T_ref) ** exponent`` with
        ``T = T2_0 + output``. Requires the heat-capacity effect.
        """
        temperature = self.model.operating_point.flange_temperature_K + np.asarray(flange_heater_output_K)
        ratio = np.maximum(temperature, 1e-3) / self.heat_capacity.reference_temperature_K
        return ratio ** self.heat_capacity.exponent

    def advance_to(self, time_s: float) -> None:
        """Integrate up to ``time_s`` with the heater held (exact at pending delay instants)."""
        if time_s < self.time_s - 1e-9:
            raise ValueError(f"time went backwards: {time_s} s after {self.time_s} s")
        while self._pending and self._pending[0][0] <= time_s:
            instant, delivered = self._pending.pop(0)
            self._hold_until(instant)
            self.flange_heater.input = delivered
        self._hold_until(time_s)

    def _hold_until(self, time_s: float) -> None:
        duration = time_s - self.time_s
        if duration <= 0.0:
            return
        self.flange_heater.hold(duration, self.time_scale())
        self.stage_heater.hold(duration)
        self.time_s = time_s

    # -- outputs ------------------------------------------------------------
    def envelope(self, elapsed_s):
        """Factor on the cooler's oscillation ``elapsed_s`` after the start (1 without amplitude modulation)."""
        return 1.0 if self.modulation is None else self.modulation.envelope(elapsed_s)

    def drift_offsets_K(self, elapsed_s):
        """(flange, stage) offsets ``elapsed_s`` after the start (K; 0 without): the cold end's drift, and the
        generic disturbance (its unrecorded heat through the heater paths without their dead time)."""
        flange, stage = 0.0, 0.0
        if self.stage_drift is not None:
            flange, stage = self.stage_drift.offsets_K(elapsed_s)
        if self.disturbance is not None:
            extra_flange, extra_stage = self.disturbance.offsets_K(elapsed_s, *self._heater_responses)
            flange, stage = flange + extra_flange, stage + extra_stage
        return flange, stage

    def temperatures(self) -> tuple[float, float]:
        """(T2, T5) in K at the current instant, noise-free."""
        point = self.model.operating_point
        elapsed = self.time_s - self.start_time_s
        rotor, frequency = self.drive.cycle.rotor(elapsed)
        heater = self.flange_heater.output()
        scale = 1.0 if self.heat_capacity is None else float(self.time_scale_at(heater))
        envelope = float(self.envelope(elapsed))
        flange_drift, stage_drift = self.drift_offsets_K(elapsed)
        flange = (point.flange_temperature_K + heater + envelope * self.flange_ptc.value_at(rotor, frequency, scale)
                  + float(flange_drift))
        stage = (point.ptc_stage_temperature_K + self.stage_heater.output()
                 + envelope * self.stage_ptc.value_at(rotor, frequency) + float(stage_drift))
        return flange, stage

    def mean_temperatures(self, duration_s: float) -> tuple[float, float]:
        """(T2, T5) in K averaged over the next ``duration_s`` with the heater held.

        Used for a DMM's integration window; the state is not advanced.
        """
        point = self.model.operating_point
        elapsed = self.time_s - self.start_time_s
        scale = self.time_scale()
        envelope = float(self.envelope(elapsed))          # the modulation and the drift are slow: taken at the start
        flange_drift, stage_drift = self.drift_offsets_K(elapsed)
        flange = (point.flange_temperature_K + self.flange_heater.mean_output(duration_s, scale)
                  + envelope * self.flange_ptc.mean_value(elapsed, duration_s, scale) + float(flange_drift))
        stage = (point.ptc_stage_temperature_K + self.stage_heater.mean_output(duration_s)
                 + envelope * self.stage_ptc.mean_value(elapsed, duration_s) + float(stage_drift))
        return flange, stage


# ---------------------------------------------------------------------------
# whole records at once
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class SimulatedRecord:
    """Thermometer temperatures at the sample instants of a record (K)."""

    time_s: np.ndarray
    flange_K: np.ndarray
    ptc_stage_K: np.ndarray


def simulate(model: CryostatModel, time_s, heater_power_w, *, initial_heater_power_w: float | None = None,
             noise: bool = False, seed: int | None = None, heater_change_s=None, ptc_cycle=None) -> SimulatedRecord:
    """Simulate T2 and T5 at the instants of a record.

    Parameters
    ----------
    model : CryostatModel
    time_s : array_like
        Increasing sample instants in s; the plant starts at ``time_s[0]``.
    heater_power_w : array_like
        Heater power applied from each sample until the next (W), as in the
        ``heater_W`` column of a cryod-log record.
    initial_heater_power_w : float, optional
        Power the plant is settled at before the first sample (default:
        ``heater_power_w[0]``).
    noise : bool
        Add the model's white sensor noise.
    seed : int, optional
        Seed of the noise generator.
    heater_change_s : array_like, optional
        When each ``heater_power_w`` took effect (s), if not at its sample
        instant: the daemon sets the heater some tens of ms after the readings
        (the ``heater_set_s`` column). Each must lie between its sample and the next.
    ptc_cycle : optional
        The cooler's phase and frequency over time instead of the model's own
        (:class:`~cryod.model.cooler_cycle.MeasuredCoolerCycle`: the phase measured in a record).

    Returns
    -------
    SimulatedRecord
        Temperatures at each instant, taken before the heater change at it.

    Examples
    --------
    >>> from cryod.model import load_model
    >>> import numpy as np
    >>> t = np.arange(0.0, 2000.0, 0.08)
    >>> record = simulate(load_model(), t, np.where(t >= 0.0, 0.0088, 0.0), initial_heater_power_w=0.0)
    >>> round(float(record.flange_K[-1]) - 4.23, 2)
    0.06
    """
    time_s = np.asarray(time_s, dtype=float)
    heater_power_w = np.asarray(heater_power_w, dtype=float)
    if time_s.ndim != 1 or time_s.shape != heater_power_w.shape:
        raise ValueError("time_s and heater_power_w must be 1-D arrays of the same length")
    if time_s.size and np.any(np.diff(time_s) <= 0.0):
        raise ValueError("time_s must be strictly increasing")
    if initial_heater_power_w is None:
        initial_heater_power_w = float(heater_power_w[0]) if heater_power_w.size else 0.0
    if heater_change_s is not None:
        heater_change_s = np.asarray(heater_change_s, dtype=float)
        if heater_change_s.shape != time_s.shape or np.any(heater_change_s < time_s) \
                or np.any(heater_change_s[:-1] >= time_s[1:]):
            raise ValueError("heater_change_s must have one instant per sample, each between its sample and the next")
    if model.temperature_dependence is not None:      # no whole-array form: instant by instant
        from cryod.model.temperature_plant import simulate_stepping
        record = simulate_stepping(model, time_s, heater_power_w, initial_heater_power_w, heater_change_s, ptc_cycle)
        flange, stage = record.flange_K, record.ptc_stage_K
    else:
        plant = CryostatPlant(model, float(time_s[0]) if time_s.size else 0.0, initial_heater_power_w, ptc_cycle)
        flange, stage = _simulate_whole(plant, time_s, heater_power_w, heater_change_s)
    if noise:
        generator = np.random.default_rng(seed)
        flange = flange + generator.normal(0.0, model.sensor_noise.flange_thermometer_rms_K, flange.size)
        stage = stage + generator.normal(0.0, model.sensor_noise.ptc_stage_thermometer_rms_K, stage.size)
    return SimulatedRecord(time_s=time_s, flange_K=flange, ptc_stage_K=stage)


#: Time-scale iteration of the heat-capacity effect: stop when no factor moves more than this.
TIME_SCALE_TOLERANCE = 1e-13
TIME_SCALE_MAX_ITERATIONS = 60


def _simulate_whole(plant: CryostatPlant, time_s: np.ndarray, heater_power_w: np.ndarray,
                    heater_change_s: np.ndarray | None = None):
    """Vectorised: the same exact hold as the stepping plant, over all intervals at once.

    With the heat-capacity effect the flange path's time constants depend on
    its own output. The factor of each held interval is taken at the
    interval's start, as the stepping plant does; the whole sequence of
    factors is found as the fixed point of "run the path with these factors,
    recompute the factors from its output", which converges in a few passes
    because the factor changes slowly with temperature.

    Each heater path's response is kept for the next call with the same path,
    state and inputs (:mod:`cryod.model.kept_results`).
    """
    point = plant.model.operating_point
    delivered = heater_power_w if plant.nonlinearity is None \
        else plant.nonlinearity.delivered_power_w(heater_power_w)
    changes = time_s if heater_change_s is None else heater_change_s
    record_key = digest(time_s, delivered, None if heater_change_s is None else changes)
    # PTC stage: input changes at the heater's change instants.
    held = _held_inputs(time_s, changes, 0.0, delivered, plant.stage_heater.input, record_key)
    stage_heater = _path_at_samples(plant.stage_heater, held)
    # Flange: input changes at those instants plus the dead time.
    held = _held_inputs(time_s, changes, plant.dead_time_s, delivered, plant.flange_heater.input, record_key)
    if plant.heat_capacity is None:
        flange_heater = _path_at_samples(plant.flange_heater, held)
    else:
        outputs = _run_time_scaled(plant, held)
        flange_heater = outputs if held.sample_positions is None else outputs[held.sample_positions]
    elapsed = _ELAPSED.get_or_make(digest("elapsed", record_key, plant.start_time_s),
                                   lambda: time_s - plant.start_time_s)
    scale = 1.0 if plant.heat_capacity is None else plant.time_scale_at(flange_heater)
    envelope = plant.envelope(elapsed)
    flange_drift, stage_drift = plant.drift_offsets_K(elapsed)
    flange = point.flange_temperature_K + flange_heater + envelope * plant.flange_ptc.values(elapsed, scale) \
        + flange_drift
    stage = point.ptc_stage_temperature_K + stage_heater + envelope * plant.stage_ptc.values(elapsed) + stage_drift
    return flange, stage


@dataclass(frozen=True)
class _HeldInputs:
    """A path's input over a record: the instants it is held between and its value from each.

    Attributes
    ----------
    grid : numpy.ndarray
        The sample instants and the instants the input changes, in order.
    inputs : numpy.ndarray
        The input held from each grid instant.
    sample_positions : numpy.ndarray or None
        Where each sample instant is in ``grid`` (None: the grid is the sample instants).
    key : bytes
        A digest of everything the above depend on.
    """

    grid: np.ndarray
    inputs: np.ndarray
    sample_positions: np.ndarray | None
    key: bytes


#: Inputs of the last paths simulated, and the paths' responses to them (each an hour's record or so); the
#: instants of the last records from their start (one array per record: what the cooler's phase terms are kept by).
_HELD_INPUTS = KeptResults(8)
_ELAPSED = KeptResults(4)
_PATH_RUNS = KeptResults(16)


def _held_inputs(time_s: np.ndarray, change_times: np.ndarray, delay_s: float, delivered: np.ndarray,
                 before: float, record_key: bytes) -> _HeldInputs:
    """The input held between the sample instants and the instants it changes (``delivered[k]`` from
    ``change_times[k] + delay_s`` on, ``before`` until the first), kept by ``record_key`` (a digest of the
    instants and ``delivered``), the delay and ``before``."""
    key = digest(record_key, delay_s, before)

    def made():
        shifted = change_times + delay_s if delay_s else change_times
        grid, inputs = _input_grid(time_s, shifted, delivered, before)
        positions = np.searchsorted(grid, time_s) if grid.size != time_s.size else None
        grid, inputs = np.array(grid), np.array(inputs)        # copies: kept read-only, the caller's untouched
        for array in (grid, inputs) + ((positions,) if positions is not None else ()):
            array.setflags(write=False)
        return _HeldInputs(grid, inputs, positions, key)

    return _HELD_INPUTS.get_or_make(key, made)


def _path_at_samples(path: HeaterPath, held: _HeldInputs) -> np.ndarray:
    """A heater path's output at the sample instants for ``held`` inputs (kept); the path is left in the state
    its run ends in."""
    key = digest(held.key, path.poles, path.residues, path.direct, path.state, path.input)

    def made():
        outputs = path.run(np.diff(held.grid), held.inputs[:-1], kept_by=held.key)
        at_samples = outputs if held.sample_positions is None else outputs[held.sample_positions]
        return at_samples, tuple(path.state), path.input

    outputs, state, final_input = _PATH_RUNS.get_or_make(key, made)
    path.state, path.input = list(state), final_input
    return outputs


def _input_grid(time_s: np.ndarray, change_times: np.ndarray, delivered: np.ndarray, before: float):
    """The sample instants and the instants a path's input changes (``delivered[k]`` from
    ``change_times[k]`` on, ``before`` until the first), and the input held from each."""
    if change_times is time_s or np.array_equal(change_times, time_s):
        return time_s, delivered
    grid = _sorted_union(time_s, change_times[change_times < time_s[-1]])
    index = np.searchsorted(change_times, grid, side="right") - 1
    inputs = np.where(index >= 0, delivered[np.clip(index, 0, None)], before)
    return grid, inputs


def _sorted_union(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """The sorted distinct values of two increasing arrays (``numpy.union1d``, by a merge: both are sorted)."""
    merged = np.concatenate((first, second))
    merged.sort(kind="stable")                 # two increasing runs: merged in linear time
    keep = np.empty(merged.size, dtype=bool)
    keep[:1] = True
    np.not_equal(merged[1:], merged[:-1], out=keep[1:])
    return merged[keep]


#: The last fixed points of the heat-capacity effect, by everything they depend on. The analysis replays
#: one record many times with the flange's heater path unchanged (a thermometer's lag, the cooler's line,
#: the linear parameters), and on such a model the fixed point is most of each replay's time.
_TIME_SCALED_RUNS = KeptResults(4)


def _run_time_scaled(plant: CryostatPlant, held: _HeldInputs) -> np.ndarray:
    """Flange heater path at the grid instants, time constants scaled per interval (fixed point).

    The result is the same for the same path, state, inputs and effect; it is
    kept (read-only) for the next call that asks for it, and the path is left
    in the state the run ends in, as without the cache.
    """
    path = plant.flange_heater
    key = digest(held.key, path.poles, path.residues, path.state, path.direct, path.input,
                 plant.model.operating_point.flange_temperature_K, plant.heat_capacity.exponent,
                 plant.heat_capacity.reference_temperature_K)

    def made():
        outputs = _fixed_point(plant, held.grid, held.inputs)
        return outputs, tuple(path.state), path.input

    outputs, state, final_input = _TIME_SCALED_RUNS.get_or_make(key, made)
    path.state, path.input = list(state), final_input
    return outputs


def _fixed_point(plant: CryostatPlant, grid: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    path = plant.flange_heater
    state, held = list(path.state), path.input
    previous = np.concatenate(([held], inputs[:-2]))      # input in effect just before each interval
    durations = np.diff(grid)
    scale = np.ones(durations.size)
    for _ in range(TIME_SCALE_MAX_ITERATIONS):
        path.state, path.input = list(state), held
        outputs = path.run(durations / scale, inputs[:-1])
        starts = outputs[:-1] + path.direct * (inputs[:-1] - previous)   # output as each interval begins
        updated = plant.time_scale_at(starts)
        change = float(np.max(np.abs(updated - scale))) if updated.size else 0.0
        scale = updated
        if change <= TIME_SCALE_TOLERANCE:
            break
    return outputs
