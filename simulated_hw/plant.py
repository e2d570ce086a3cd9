"""The simulated cryostat's physics: noise-free T2 and T5 from a model and the heater history.

Two kinds of path make up the plant (equations in ``docs/model.md``):

* heater paths (G2*G1 to the flange thermometer, G3 to the PTC stage) are
  linear systems driven by a heater power held constant between writes. They
  are kept in modal form, ``z_i' = lambda_i z_i + u``, and advanced with the
  exact zero-order-hold solution ``z_i(t+h) = a z_i(t) + (a - 1)/lambda_i * u``,
  ``a = exp(lambda_i h)``, for any step length h: writes may come at any instant.
* the PTC paths carry the cooler's steady oscillation. Its response is the
  frequency response evaluated at each harmonic, ``Re(H(j k omega) Q_k exp(j theta_k(t)))``,
  computed at the exact instant asked for, so it never aliases.

Effects of the model are applied as physics: delivered heater power
(nonlinearity), a delay queue (dead time), an extra lag on the readings
(sensor lag), a changed PTC-to-flange path (link dynamics), time constants
scaled with the flange temperature (heat capacity), harmonics and frequency
drift of the cooler.

Examples
--------
>>> from cryod.model import load_model
>>> plant = CryostatPlant(load_model())
>>> plant.set_heater_power(0.0088, time_s=0.0)
>>> plant.advance_to(2000.0)
>>> round(plant.temperatures()[0] - 4.23, 3)     # step height of T2, K (plus PTC line)
0.06
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass

import numpy as np

from cryod.model import CryostatModel
from cryod.transfer_function import TransferFunction


# ---------------------------------------------------------------------------
# heater paths: modal state, exact zero-order hold
# ---------------------------------------------------------------------------
class HeaterPath:
    """A linear path driven by a piecewise-constant input, in modal form.

    Parameters
    ----------
    transfer_function : TransferFunction
        Input (W) to output (K) transfer function.
    """

    def __init__(self, transfer_function: TransferFunction):
        form = transfer_function.modal_form()
        self.transfer_function = transfer_function
        self.all_real = bool(np.all(form.poles.imag == 0.0))
        if self.all_real:
            self.poles = [float(p.real) for p in form.poles]
            self.residues = [float(r.real) for r in form.residues]
        else:
            self.poles = [complex(p) for p in form.poles]
            self.residues = [complex(r) for r in form.residues]
        self.direct = float(form.direct)
        self.state = [0.0 * p for p in self.poles]
        self.input = 0.0
        self._hold_key: tuple[float, float] | None = None
        self._hold_coefficients: list = []

    def settle(self, value: float) -> None:
        """Put the path in steady state for a constant input ``value``."""
        self.input = value
        self.state = [-value / p for p in self.poles]

    def hold(self, duration_s: float, time_scale: float = 1.0) -> None:
        """Advance by ``duration_s`` with the input held (exact).

        ``time_scale`` multiplies every time constant for this step.
        """
        if duration_s <= 0.0:
            return
        key = (duration_s, time_scale)
        if key != self._hold_key:
            exp = math.exp if self.all_real else cmath.exp
            decay = [exp(pole * duration_s / time_scale) for pole in self.poles]
            self._hold_coefficients = [(a, (a - 1.0) / pole) for a, pole in zip(decay, self.poles)]
            self._hold_key = key
        u = self.input
        state = self.state
        for i, (a, gain) in enumerate(self._hold_coefficients):
            state[i] = a * state[i] + gain * u

    def output(self) -> float:
        """Output now (the input's direct part uses the input in effect)."""
        total = self.direct * self.input
        for residue, z in zip(self.residues, self.state):
            total += residue * z
        return total.real if isinstance(total, complex) else total

    def mean_output(self, duration_s: float, time_scale: float = 1.0) -> float:
        """Mean output over the next ``duration_s`` with the input held; state unchanged."""
        if duration_s <= 0.0:
            return self.output()
        u = self.input
        exp = math.exp if self.all_real else cmath.exp
        total = self.direct * u * duration_s
        for pole, residue, z in zip(self.poles, self.residues, self.state):
            rate = pole / time_scale
            a = exp(rate * duration_s)
            integral = (a - 1.0) / rate * z + ((a - 1.0) / rate - duration_s) / pole * u
            total += residue * integral
        total = total.real if isinstance(total, complex) else total
        return total / duration_s

    def run(self, durations_s: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """Outputs at the start of each interval and after the last one (vectorised).

        Parameters
        ----------
        durations_s : numpy.ndarray
            Interval lengths h_k in s (length n).
        inputs : numpy.ndarray
            Input held over each interval (length n).

        Returns
        -------
        numpy.ndarray
            Output at the n + 1 interval boundaries. The path's state is left
            at the end of the last interval.
        """
        durations_s = np.asarray(durations_s, dtype=float)
        inputs = np.asarray(inputs, dtype=float)
        count = durations_s.size
        outputs = np.zeros(count + 1)
        previous_input = np.concatenate(([self.input], inputs))
        outputs += self.direct * previous_input
        for i, pole in enumerate(self.poles):
            a = np.exp(pole * durations_s)
            b = (a - 1.0) / pole * inputs
            states = _linear_recurrence(a, b, self.state[i])
            self.state[i] = states[-1].item()
            outputs += np.real(self.residues[i] * states)
        if count:
            self.input = float(inputs[-1])
        return outputs


def _linear_recurrence(a: np.ndarray, b: np.ndarray, initial):
    """z[0] = initial, z[k+1] = a[k] z[k] + b[k]; returns z[0..n].

    A parallel prefix scan (Hillis-Steele) over the affine maps
    ``z -> a z + b``: log2(n) whole-array passes instead of a Python loop over
    the samples. Products of the decay factors only shrink (|a| <= 1), so
    nothing overflows; the result agrees with the sequential loop to rounding.
    """
    dtype = np.result_type(a, b, np.asarray(initial))
    factor = np.empty(a.size + 1, dtype=dtype)
    offset = np.empty(a.size + 1, dtype=dtype)
    factor[0], offset[0] = 0.0, initial
    factor[1:], offset[1:] = a, b
    span = 1
    while span < factor.size:
        offset[span:] = factor[span:] * offset[:-span] + offset[span:]
        factor[span:] = factor[span:] * factor[:-span]
        span *= 2
    return offset


# ---------------------------------------------------------------------------
# PTC paths: phasors at the exact instant
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class _PtcComponent:
    order: int
    heat_phasor: complex      # q_k = Re(heat_phasor * exp(j theta)) for omega = omega_0, in W per (rad/s)
    stage_phasor: complex     # T5 oscillation = Re(stage_phasor * exp(j theta)), K
    phase_rad: float


class PtcDrive:
    """The cooler's oscillation: phase, frequency and the heat it drives into the flange."""

    def __init__(self, model: CryostatModel):
        ptc = model.ptc
        self.base_angular_frequency = ptc.angular_frequency_rad_s
        self.drift = model.effects.ptc_frequency_drift
        self.components = [
            _PtcComponent(
                order=order,
                # q = C d/dt [B sin(theta)] = Re(C k omega B exp(j theta)); omega applied later
                heat_phasor=complex(ptc.heat_capacity_J_per_K * order * amplitude),
                # B sin(theta) = Re(-j B exp(j theta))
                stage_phasor=complex(-1j * amplitude),
                phase_rad=phase,
            )
            for order, amplitude, phase in ptc.components()
        ]

    def rotor(self, elapsed_s: float) -> tuple[complex, float]:
        """``exp(j phase)`` of the fundamental and the angular frequency (rad/s), at one instant."""
        phase = self.base_angular_frequency * elapsed_s
        frequency = self.base_angular_frequency
        if self.drift is not None:
            phase += float(self.drift.phase_offset(elapsed_s))
            frequency += float(self.drift.angular_frequency_offset(elapsed_s))
        return cmath.exp(1j * phase), frequency

    def phase_and_frequency(self, elapsed_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fundamental phase (rad, without the component phases) and angular frequency (rad/s)
        at many instants."""
        elapsed_s = np.asarray(elapsed_s, dtype=float)
        phase = self.base_angular_frequency * elapsed_s
        frequency = np.full_like(phase, self.base_angular_frequency)
        if self.drift is not None:
            phase = phase + self.drift.phase_offset(elapsed_s)
            frequency = frequency + self.drift.angular_frequency_offset(elapsed_s)
        return phase, frequency


def _horner(coefficients: tuple[float, ...], s):
    value = 0.0
    for coefficient in coefficients:
        value = value * s + coefficient
    return value


class PtcPath:
    """Response of one thermometer to the PTC oscillation, evaluated as phasors.

    Parameters
    ----------
    drive : PtcDrive
    transfer_function : TransferFunction
        From the PTC heat q (W) to the thermometer (K), or from the T5
        oscillation (K) to the T5 thermometer (K).
    input_is_heat : bool
        True for the heat path to the flange, False for the stage oscillation.
    """

    def __init__(self, drive: PtcDrive, transfer_function: TransferFunction, input_is_heat: bool):
        self.drive = drive
        self.transfer_function = transfer_function
        self.input_is_heat = input_is_heat
        self._cache_key: tuple[float, float] | None = None
        self._cache: list[complex] = []

    def output_phasors(self, frequency, time_scale=1.0) -> list:
        """Complex output amplitude of each component (K), for the angular frequency given.

        ``frequency`` may be an array (one phasor per instant) or a float.
        """
        numerator = self.transfer_function.numerator
        denominator = self.transfer_function.denominator
        phasors = []
        for component in self.drive.components:
            s = 1j * component.order * frequency * time_scale
            gain = np.polyval(numerator, s) / np.polyval(denominator, s)
            if self.input_is_heat:
                phasors.append(gain * component.heat_phasor * frequency)
            else:
                phasors.append(gain * component.stage_phasor)
        return phasors

    def _rotated_phasors(self, frequency: float, time_scale: float) -> list[tuple[int, complex]]:
        """(order, phasor * exp(j component phase)) at one frequency, cached."""
        key = (frequency, time_scale)
        if key != self._cache_key:
            phasors = []
            for component in self.drive.components:
                s = 1j * component.order * frequency * time_scale
                gain = _horner(self.transfer_function.numerator, s) / _horner(self.transfer_function.denominator, s)
                source = component.heat_phasor * frequency if self.input_is_heat else component.stage_phasor
                phasors.append((component.order, gain * source * cmath.exp(1j * component.phase_rad)))
            self._cache_key, self._cache = key, phasors
        return self._cache

    def value_at(self, rotor: complex, frequency: float, time_scale: float = 1.0) -> float:
        """Output at one instant given the drive's rotor and frequency there (K)."""
        total = 0.0
        for order, phasor in self._rotated_phasors(frequency, time_scale):
            total += (phasor * (rotor if order == 1 else rotor ** order)).real
        return total

    def value(self, elapsed_s: float, time_scale: float = 1.0) -> float:
        """Output at one instant, ``elapsed_s`` after the plant started (K)."""
        rotor, frequency = self.drive.rotor(elapsed_s)
        return self.value_at(rotor, frequency, time_scale)

    def values(self, elapsed_s: np.ndarray, time_scale=1.0) -> np.ndarray:
        """Output at many instants (K).

        ``time_scale`` multiplies the path's time constants: a float, or one
        factor per instant (heat-capacity effect).
        """
        phase, frequency = self.drive.phase_and_frequency(np.asarray(elapsed_s, dtype=float))
        if self.drive.drift is None:
            frequency = float(self.drive.base_angular_frequency)
        total = np.zeros_like(phase)
        for component, phasor in zip(self.drive.components, self.output_phasors(frequency, time_scale)):
            total += np.real(phasor * np.exp(1j * (component.order * phase + component.phase_rad)))
        return total

    def mean_value(self, elapsed_s: float, duration_s: float, time_scale: float = 1.0) -> float:
        """Mean output over ``[elapsed_s, elapsed_s + duration_s]``, frequency frozen at the start."""
        if duration_s <= 0.0:
            return self.value(elapsed_s, time_scale)
        rotor, frequency = self.drive.rotor(elapsed_s)
        total = 0.0
        for order, phasor in self._rotated_phasors(frequency, time_scale):
            angular = order * frequency
            start = phasor * rotor ** order
            total += (start * (cmath.exp(1j * angular * duration_s) - 1.0) / (1j * angular)).real
        return total / duration_s


# ---------------------------------------------------------------------------
# the plant
# ---------------------------------------------------------------------------
def flange_transfer_functions(model: CryostatModel) -> tuple[TransferFunction, TransferFunction]:
    """(heater to flange thermometer, PTC heat to flange thermometer) with link and sensor effects."""
    effects = model.effects
    heater = model.flange_to_thermometer * model.heater_to_flange
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


def stage_transfer_functions(model: CryostatModel) -> tuple[TransferFunction, TransferFunction]:
    """(heater to PTC-stage thermometer, stage oscillation to PTC-stage thermometer)."""
    heater = model.heater_to_ptc_stage
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
    """

    def __init__(self, model: CryostatModel, start_time_s: float = 0.0,
                 initial_heater_power_w: float = 0.0):
        self.model = model
        self.start_time_s = float(start_time_s)
        self.time_s = float(start_time_s)
        effects = model.effects
        flange_heater, flange_ptc = flange_transfer_functions(model)
        stage_heater, stage_oscillation = stage_transfer_functions(model)
        drive = self.drive = PtcDrive(model)
        self.flange_heater = HeaterPath(flange_heater)
        self.stage_heater = HeaterPath(stage_heater)
        self.flange_ptc = PtcPath(drive, flange_ptc, input_is_heat=True)
        self.stage_ptc = PtcPath(drive, stage_oscillation, input_is_heat=False)
        self.dead_time_s = effects.dead_time.heater_to_flange_s if effects.dead_time else 0.0
        self.nonlinearity = effects.heater_nonlinearity
        self.heat_capacity = effects.heat_capacity_temperature
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
    def temperatures(self) -> tuple[float, float]:
        """(T2, T5) in K at the current instant, noise-free."""
        point = self.model.operating_point
        rotor, frequency = self.drive.rotor(self.time_s - self.start_time_s)
        heater = self.flange_heater.output()
        scale = 1.0 if self.heat_capacity is None else float(self.time_scale_at(heater))
        flange = point.flange_temperature_K + heater + self.flange_ptc.value_at(rotor, frequency, scale)
        stage = point.ptc_stage_temperature_K + self.stage_heater.output() + self.stage_ptc.value_at(rotor, frequency)
        return flange, stage

    def mean_temperatures(self, duration_s: float) -> tuple[float, float]:
        """(T2, T5) in K averaged over the next ``duration_s`` with the heater held.

        Used for a DMM's integration window; the state is not advanced.
        """
        point = self.model.operating_point
        elapsed = self.time_s - self.start_time_s
        scale = self.time_scale()
        flange = (point.flange_temperature_K + self.flange_heater.mean_output(duration_s, scale)
                  + self.flange_ptc.mean_value(elapsed, duration_s, scale))
        stage = (point.ptc_stage_temperature_K + self.stage_heater.mean_output(duration_s)
                 + self.stage_ptc.mean_value(elapsed, duration_s))
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
             noise: bool = False, seed: int | None = None) -> SimulatedRecord:
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
    plant = CryostatPlant(model, float(time_s[0]) if time_s.size else 0.0, initial_heater_power_w)
    flange, stage = _simulate_whole(plant, time_s, heater_power_w)
    if noise:
        generator = np.random.default_rng(seed)
        flange = flange + generator.normal(0.0, model.sensor_noise.flange_thermometer_rms_K, flange.size)
        stage = stage + generator.normal(0.0, model.sensor_noise.ptc_stage_thermometer_rms_K, stage.size)
    return SimulatedRecord(time_s=time_s, flange_K=flange, ptc_stage_K=stage)


#: Time-scale iteration of the heat-capacity effect: stop when no factor moves more than this.
TIME_SCALE_TOLERANCE = 1e-13
TIME_SCALE_MAX_ITERATIONS = 60


def _simulate_whole(plant: CryostatPlant, time_s: np.ndarray, heater_power_w: np.ndarray):
    """Vectorised: the same exact hold as the stepping plant, over all intervals at once.

    With the heat-capacity effect the flange path's time constants depend on
    its own output. The factor of each held interval is taken at the
    interval's start, as the stepping plant does; the whole sequence of
    factors is found as the fixed point of "run the path with these factors,
    recompute the factors from its output", which converges in a few passes
    because the factor changes slowly with temperature.
    """
    point = plant.model.operating_point
    delivered = heater_power_w if plant.nonlinearity is None \
        else plant.nonlinearity.delivered_power_w(heater_power_w)
    durations = np.diff(time_s)
    # PTC stage: input changes at the sample instants.
    stage_heater = plant.stage_heater.run(durations, delivered[:-1])
    # Flange: input changes at the sample instants plus the dead time.
    grid, inputs = _flange_input_grid(plant, time_s, delivered)
    if plant.heat_capacity is None:
        outputs = plant.flange_heater.run(np.diff(grid), inputs[:-1])
    else:
        outputs = _run_time_scaled(plant, grid, inputs)
    flange_heater = outputs[np.searchsorted(grid, time_s)] if grid.size != time_s.size else outputs
    elapsed = time_s - plant.start_time_s
    scale = 1.0 if plant.heat_capacity is None else plant.time_scale_at(flange_heater)
    flange = point.flange_temperature_K + flange_heater + plant.flange_ptc.values(elapsed, scale)
    stage = point.ptc_stage_temperature_K + stage_heater + plant.stage_ptc.values(elapsed)
    return flange, stage


def _flange_input_grid(plant: CryostatPlant, time_s: np.ndarray, delivered: np.ndarray):
    """Instants at which the flange path's input changes (sample instants, delayed changes) and
    the input held from each of them."""
    dead = plant.dead_time_s
    if dead <= 0.0:
        return time_s, delivered
    before = plant.flange_heater.input
    change_times = time_s + dead
    grid = np.union1d(time_s, change_times[change_times < time_s[-1]])
    index = np.searchsorted(change_times, grid, side="right") - 1
    inputs = np.where(index >= 0, delivered[np.clip(index, 0, None)], before)
    return grid, inputs


def _run_time_scaled(plant: CryostatPlant, grid: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    """Flange heater path at the grid instants, time constants scaled per interval (fixed point)."""
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
