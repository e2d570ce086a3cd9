"""The physical limit of the feedforward: the least cooler-synchronous oscillation any heater
waveform locked to the pulse-tube cooler can leave on the flange thermometer (T2).

The heater can only heat (P >= 0), saturates at R * I_max**2, and its mean is fixed by the thermal
balance at the setpoint. Within those bounds this module finds the waveform P(phi) of the cooler's
phase that leaves the smallest PTC-synchronous part on T2 (a convex quadratic programme, solved by
:mod:`cryod.control.feedforward.bounded_waveform`), certifies it with a lower bound that holds for
every waveform, says what limits it (the heater's authority, or the estimation noise) and what
would change it (:func:`limit_changes`), and sweeps it over setpoints and heaters
(:func:`limit_sweep`). The formulation, the certificate, the convergence and the numbers are in
docs/explanation/feedforward.md ("The physical limit").

The limit is in the daemon's measure, ``ptc_periodic_amplitude_K``: sqrt(2) times the rms of T2's
part periodic in the cooler's phase, harmonics 1-6, in the readings taken at the loop's instants
(``sqrt(sum |r_n|**2)`` for the phasors r_n of those harmonics). ``measure="sampled"`` (the
default) takes the heater's path as the loop's readings see it, with the images of the hold that
fold onto each harmonic; ``"continuous"``, the continuous-time path at the harmonics, images
ignored. In the sampled measure the limit depends on where in the period the heater changes
(``heater_delay_s``, from the reading; the model's dead time is added).

Heater power here is the power delivered to the flange; with the model's heater nonlinearity
the bounds and the mean are in delivered power and the waveform is mapped back to commanded
power. The heat-capacity effect scales the time constants as at the setpoint. A cooler
frequency drift is not modelled: the limit is at the model's base frequency.

Examples
--------
>>> from cryod.model import load_model
>>> limit = feedforward_limit(load_model(), setpoint_K=5.0, heater_resistance_ohm=50.0, max_current_A=0.1)
>>> round(limit.mean_heater_power_W, 3), round(limit.line_power_needed_W, 3)
(0.113, 0.235)
>>> round(limit.open_line_K * 1e3, 2), round(limit.best_sinusoid_K * 1e3, 2), round(limit.ptc_periodic_limit_K * 1e3, 2)
(1.73, 0.9, 0.53)
>>> limit.limited_by
'authority'
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass

import numpy as np

from cryod.control.feedforward.bounded_waveform import (
    best_bounded_waveform, largest_fundamental, residual_lower_bound, waveform_values,
)
from cryod.control.feedforward.harmonic_plant import line_at_harmonics
from cryod.model import CryostatModel, TransferFunction
from cryod.model.dynamics import flange_transfer_functions

#: Harmonics of the daemon's ``ptc_periodic_amplitude_K``, and of the limit in the same measure.
REPORTED_HARMONICS = 6
#: Degree of the waveform (its harmonics 1..N). 12 includes harmonics 7 (aliased to 0.44 Hz in the
#: readings, 28 mK/W) and 8; with 24 the limit at 5 K moves by 0.1 %.
DEFAULT_HARMONICS = 12
#: Phases at which the bounds 0 <= P <= R I_max**2 are imposed.
DEFAULT_PHASE_POINTS = 512
#: Averaging time of the estimate that drives the feedforward, s (noise-limited residual).
DEFAULT_AVERAGING_TIME_S = 60.0
#: Below this fraction of the open line the heater's bounds no longer limit: noise does.
AUTHORITY_FRACTION = 0.01
MEASURES = ("sampled", "continuous")

#: Safety margin on the smallest heater gain h used by the bound (h from a grid of frequencies).
FLOOR_GAIN_MARGIN = 0.99


class FeedforwardLimitError(ValueError):
    """Inputs for which no limit exists (setpoint out of the heater's reach, bad heater values)."""


@dataclass(frozen=True, eq=False)
class FeedforwardLimit:
    """The physical limit of the cooler-locked feedforward at one setpoint with one heater.

    Amplitudes are sqrt(2) x rms (a sinusoid's amplitude) over the harmonics named; powers are
    delivered to the flange (equal to commanded without the model's heater nonlinearity).

    Attributes
    ----------
    setpoint_K, heater_resistance_ohm, max_current_A, period_s, heater_delay_s : float
        The inputs (``heater_delay_s`` includes the model's dead time).
    measure : str
        ``"sampled"`` (harmonics of the readings, as the daemon measures) or ``"continuous"``.
    harmonics : int
        Degree N of the waveform.
    phase_points : int
        Phases at which the bounds were imposed.
    cooler_angular_frequency_rad_s : float
    mean_heater_power_W : float
        Mean power that holds the setpoint: (setpoint - T2_0) / DC gain of G.
    max_heater_power_W : float
        R * I_max**2.
    thermometer_gain_at_line_K_per_W, thermometer_phase_at_line_deg : float
        |G(j w0)| and its phase: heater power at the line to the flange thermometer.
    heater_gain_at_line_K_per_W, heater_phase_at_line_deg : float
        |H_1| and its phase: the heater samples at the line to T2, through the hold (and, in
        the sampled measure, its images).
    line_power_needed_W : float
        Heater amplitude at the line that cancels the line's fundamental: |L_1| / |H_1|.
    largest_line_power_W : float
        Largest fundamental any waveform within the bounds and with this mean can have (a
        rectangular pulse): (2 P_max / pi) sin(pi P_mean / P_max), in delivered power.
    authority : float
        largest_line_power_W / line_power_needed_W. Below 1 no waveform can even cancel the
        fundamental; above 1 it can, and what remains is the harmonics its shape brings.
    sinusoid_line_power_W : float
        Largest sinusoid within the bounds: min(P_mean, P_max - P_mean).
    open_line_K : float
        The line on T2 without feedforward (harmonics 1-6).
    best_sinusoid_K : float
        Best a sinusoid at the line frequency can do (optimal phase, amplitude capped).
    ptc_periodic_limit_K : float
        The limit: least PTC-synchronous T2 oscillation, harmonics 1-6, in the daemon's measure.
    whole_periodic_limit_K : float
        The same over all harmonics 1..N of the best waveform (what is minimised).
    lower_bound_K : float or None
        No waveform of any shape leaves less than this on all harmonics together (None when not
        certified).
    open_line_harmonics_K, limit_harmonics_K : tuple of float
        |L_n| and |r_n| for n = 1..6.
    noise_floor_K : float
        Residual left by estimating each harmonic from ``averaging_time_s`` of readings with the
        model's T2 noise sigma: 2 sigma sqrt(6 / n_readings) (see :func:`noise_floor_K`).
    averaging_time_s : float
    predicted_best_residual_K : float
        sqrt(limit**2 + noise_floor**2) over harmonics 1-6.
    authority_limited : bool
        The heater's bounds bind: the limit exceeds ``AUTHORITY_FRACTION`` of the open line.
    waveform_phase_rad : numpy.ndarray
        Cooler phase phi of the waveform's grid: T5's fundamental, as its thermometer reads it, is
        ``A cos(phi)`` (the phase the feedforward tracks). The loop sets ``P(phi_k)`` at reading k.
        A loop that evaluates the waveform at another instant (the middle of the coming hold,
        say, s later) plays the same sequence with ``a_n exp(-j n w0 s)``.
    waveform_power_w : numpy.ndarray
        Commanded heater power of the best waveform at those phases.
    waveform_harmonics_w : numpy.ndarray
        Complex amplitudes a_n (n = 1..N) of the delivered power against that phase:
        ``P(phi) = P_mean + Re sum_n a_n exp(j n phi)``.
    """

    setpoint_K: float
    heater_resistance_ohm: float
    max_current_A: float
    period_s: float
    heater_delay_s: float
    measure: str
    harmonics: int
    phase_points: int
    cooler_angular_frequency_rad_s: float
    mean_heater_power_W: float
    max_heater_power_W: float
    thermometer_gain_at_line_K_per_W: float
    thermometer_phase_at_line_deg: float
    heater_gain_at_line_K_per_W: float
    heater_phase_at_line_deg: float
    line_power_needed_W: float
    largest_line_power_W: float
    authority: float
    sinusoid_line_power_W: float
    open_line_K: float
    best_sinusoid_K: float
    ptc_periodic_limit_K: float
    whole_periodic_limit_K: float
    lower_bound_K: float | None
    open_line_harmonics_K: tuple[float, ...]
    limit_harmonics_K: tuple[float, ...]
    noise_floor_K: float
    averaging_time_s: float
    predicted_best_residual_K: float
    authority_limited: bool
    waveform_phase_rad: np.ndarray
    waveform_power_w: np.ndarray
    waveform_harmonics_w: np.ndarray

    @property
    def limited_by(self) -> str:
        """``"authority"`` (the heater's bounds) or ``"noise"`` (estimating the line)."""
        return "authority" if self.authority_limited else "noise"

    @property
    def suppression_factor(self) -> float:
        """Open line over the predicted best residual."""
        return self.open_line_K / self.predicted_best_residual_K if self.predicted_best_residual_K > 0 else math.inf

    def summary(self) -> dict:
        """Scalars and per-harmonic values as plain JSON-ready types (the waveform as lists)."""
        return {
            "setpoint_K": self.setpoint_K, "heater_resistance_ohm": self.heater_resistance_ohm,
            "max_current_A": self.max_current_A, "period_s": self.period_s,
            "heater_delay_s": self.heater_delay_s, "measure": self.measure, "harmonics": self.harmonics,
            "phase_points": self.phase_points,
            "cooler_angular_frequency_rad_s": self.cooler_angular_frequency_rad_s,
            "mean_heater_power_W": self.mean_heater_power_W, "max_heater_power_W": self.max_heater_power_W,
            "thermometer_gain_at_line_K_per_W": self.thermometer_gain_at_line_K_per_W,
            "thermometer_phase_at_line_deg": self.thermometer_phase_at_line_deg,
            "heater_gain_at_line_K_per_W": self.heater_gain_at_line_K_per_W,
            "heater_phase_at_line_deg": self.heater_phase_at_line_deg,
            "line_power_needed_W": self.line_power_needed_W, "largest_line_power_W": self.largest_line_power_W,
            "authority": self.authority, "sinusoid_line_power_W": self.sinusoid_line_power_W,
            "open_line_K": self.open_line_K, "best_sinusoid_K": self.best_sinusoid_K,
            "ptc_periodic_limit_K": self.ptc_periodic_limit_K,
            "whole_periodic_limit_K": self.whole_periodic_limit_K, "lower_bound_K": self.lower_bound_K,
            "open_line_harmonics_K": list(self.open_line_harmonics_K),
            "limit_harmonics_K": list(self.limit_harmonics_K),
            "noise_floor_K": self.noise_floor_K, "averaging_time_s": self.averaging_time_s,
            "predicted_best_residual_K": self.predicted_best_residual_K,
            "authority_limited": self.authority_limited, "limited_by": self.limited_by,
            "waveform": {
                "phase_rad": [float(v) for v in self.waveform_phase_rad],
                "heater_power_W": [float(v) for v in self.waveform_power_w],
                "harmonics_W": [[float(a.real), float(a.imag)] for a in self.waveform_harmonics_w],
            },
        }


# ---------------------------------------------------------------------------
# the plant seen by the waveform
# ---------------------------------------------------------------------------
def mean_heater_power_w(model: CryostatModel, setpoint_K: float) -> float:
    """Delivered heater power that holds the flange thermometer at ``setpoint_K`` in steady state (W).

    ``(setpoint - T2_0) / DC gain of G2 G1``, G of the base model (the PTC line has no mean).

    Examples
    --------
    >>> from cryod.model import load_model
    >>> round(mean_heater_power_w(load_model(), 6.0), 3)
    0.26
    """
    return (setpoint_K - model.operating_point.flange_temperature_K) / model.heater_to_thermometer.dc_gain


def noise_floor_K(sensor_noise_rms_K: float, averaging_time_s: float, period_s: float,
                  harmonics: int = REPORTED_HARMONICS) -> float:
    """Residual left by a feedforward driven by harmonics estimated from noisy readings (K).

    The least-squares estimate of each quadrature (sine, cosine) of one harmonic from
    ``n = averaging_time_s / period_s`` readings with white noise sigma has standard deviation
    ``sigma sqrt(2 / n)``. The feedforward inherits that error as a random phasor on each
    harmonic; over ``harmonics`` harmonics, two quadratures each, the expected amplitude
    (sqrt(2) rms, as the limit) is ``sqrt(harmonics * 2 * 2 sigma**2 / n) = 2 sigma sqrt(harmonics / n)``.

    Examples
    --------
    >>> round(noise_floor_K(20e-6, 60.0, 0.08) * 1e6, 2)
    3.58
    """
    readings = averaging_time_s / period_s
    return 2.0 * sensor_noise_rms_K * math.sqrt(harmonics / readings)


def _zero_order_hold(angular_frequency, period_s: float):
    """Hzoh(jw) = (1 - exp(-jwT)) / (jwT): the held power's content at w per unit of the samples'."""
    x = np.asarray(angular_frequency, dtype=float) * period_s
    safe = np.where(x == 0.0, 1.0, x)
    return np.where(x == 0.0, 1.0 + 0.0j, (1.0 - np.exp(-1j * safe)) / (1j * safe))


def _held_response(heater_path: TransferFunction, angular_frequency, period_s: float, delay_s: float,
                   measure: str) -> np.ndarray:
    """Heater samples (W) to T2 (K) at the angular frequencies given, through the hold and the delay.

    ``"continuous"``: G(jw) Hzoh(jw) exp(-jwd). ``"sampled"``: the response seen in readings taken
    every T, the hold's images w + 2 pi m / T folded in
    (:meth:`~cryod.model.transfer_function.TransferFunction.sampled_response`, exact).
    """
    frequency = np.atleast_1d(np.asarray(angular_frequency, dtype=float))
    if measure == "continuous":
        return (heater_path.frequency_response(frequency) * _zero_order_hold(frequency, period_s)
                * np.exp(-1j * frequency * delay_s))
    return heater_path.sampled_response(frequency, period_s, delay_s)


def _smallest_held_gain(heater_path: TransferFunction, period_s: float, delay_s: float, measure: str) -> float:
    """h <= |H| at every frequency of the readings (0 in the continuous measure, where G Hzoh -> 0).

    The least of |H| over 256 frequencies from just above 0 to half the sampling rate (|H| is
    the same at -w and the readings fold every harmonic into that range), less a 1 % margin
    for the grid.
    """
    if measure == "continuous":
        return 0.0
    frequencies = np.linspace(0.0, math.pi / period_s, 257)[1:]
    gains = _held_response(heater_path, frequencies, period_s, delay_s, measure)
    return FLOOR_GAIN_MARGIN * float(np.min(np.abs(gains)))


@dataclass(frozen=True)
class _Problem:
    """The waveform problem in one cryostat: line phasors, heater gains, bounds, mean."""

    line: np.ndarray            # L_n, n = 1..N, K, against the cooler phase phi (T5's fundamental is A cos phi)
    gain: np.ndarray            # H_n, K/W
    mean: float                 # delivered W
    low: float
    high: float
    heater_path: TransferFunction | None    # G at the setpoint, K/W (None: known only at the harmonics)


def _heat_capacity_scale(model: CryostatModel, setpoint_K: float) -> float:
    """Factor on the flange's time constants at the setpoint (model effect ``heat_capacity_temperature``)."""
    effect = model.effects.heat_capacity_temperature
    if effect is None:
        return 1.0
    return (setpoint_K / effect.reference_temperature_K) ** effect.exponent


def _delivered(model: CryostatModel, commanded_w):
    nonlinearity = model.effects.heater_nonlinearity
    return commanded_w if nonlinearity is None else nonlinearity.delivered_power_w(commanded_w)


def _highest_delivered_w(model: CryostatModel, max_power_w: float) -> float:
    """Largest delivered power for commanded powers in [0, max_power_w]."""
    nonlinearity = model.effects.heater_nonlinearity
    if nonlinearity is None:
        return max_power_w
    k = nonlinearity.quadratic_coefficient_per_W
    top = max_power_w if k >= 0.0 else min(max_power_w, -0.5 / k)
    return float(_delivered(model, top))


def _commanded(model: CryostatModel, delivered_w: np.ndarray) -> np.ndarray:
    """Commanded power giving ``delivered_w`` (the branch through 0 of P + k P**2)."""
    nonlinearity = model.effects.heater_nonlinearity
    if nonlinearity is None or nonlinearity.quadratic_coefficient_per_W == 0.0:
        return delivered_w
    k = nonlinearity.quadratic_coefficient_per_W
    return 2.0 * delivered_w / (1.0 + np.sqrt(np.maximum(1.0 + 4.0 * k * delivered_w, 0.0)))


def _problem(model: CryostatModel, setpoint_K: float, max_power_w: float, period_s: float, delay_s: float,
             measure: str, harmonics: int) -> _Problem:
    scale = _heat_capacity_scale(model, setpoint_K)
    heater_path = flange_transfer_functions(model)[0].time_scaled(scale)
    orders = np.arange(1, harmonics + 1)
    gain = _held_response(heater_path, orders * model.ptc.angular_frequency_rad_s, period_s, delay_s, measure)
    return _Problem(line=line_at_harmonics(model, harmonics, scale), gain=gain,
                    mean=mean_heater_power_w(model, setpoint_K), low=0.0,
                    high=_highest_delivered_w(model, max_power_w), heater_path=heater_path)


def _amplitude(phasors) -> float:
    return float(np.sqrt(np.sum(np.abs(np.asarray(phasors)) ** 2)))


# ---------------------------------------------------------------------------
# the public computation
# ---------------------------------------------------------------------------
def feedforward_limit(model: CryostatModel, setpoint_K: float, heater_resistance_ohm: float, max_current_A: float,
                      period_s: float = 0.08, *, heater_delay_s: float = 0.0, measure: str = "sampled",
                      harmonics: int = DEFAULT_HARMONICS, phase_points: int = DEFAULT_PHASE_POINTS,
                      averaging_time_s: float = DEFAULT_AVERAGING_TIME_S, certify: bool = True) -> FeedforwardLimit:
    """The least cooler-synchronous T2 oscillation any heater waveform locked to the cooler can leave.

    Parameters
    ----------
    model : CryostatModel
    setpoint_K : float
        Flange (T2) setpoint; fixes the mean heater power.
    heater_resistance_ohm, max_current_A : float
        The heater: its power runs from 0 to R * I_max**2.
    period_s : float
        Loop period: the heater is held for this long between ticks (80 ms).
    heater_delay_s : float
        Delay from a reading to the heater change it causes (computation latency), s. The
        model's dead time is added. See the module doc: it matters only in the sampled measure.
    measure : {"sampled", "continuous"}
        Harmonics of the readings at the loop's instants (the daemon's measure), or of the
        thermometer's continuous temperature with the hold's images ignored.
    harmonics : int
        Degree N of the waveform (its harmonics 1..N); raised to the line's highest harmonic.
    phase_points : int
        Phases at which the bounds are imposed (M).
    averaging_time_s : float
        Averaging time of the harmonics' estimate for the noise-limited residual.
    certify : bool
        Compute ``lower_bound_K`` (a fraction of a second more).

    Returns
    -------
    FeedforwardLimit

    Raises
    ------
    FeedforwardLimitError
        For a non-positive resistance, current, period or averaging time, a negative delay, an
        unknown measure, or a setpoint the heater cannot hold (below T2_0, or needing more mean
        power than R * I_max**2).
    """
    _check_inputs(heater_resistance_ohm, max_current_A, period_s, heater_delay_s, measure, averaging_time_s,
                  harmonics, phase_points)
    max_power = heater_resistance_ohm * max_current_A ** 2
    _check_reach(model, setpoint_K, max_power, heater_resistance_ohm, max_current_A)
    dead_time = model.effects.dead_time.heater_to_flange_s if model.effects.dead_time else 0.0
    delay = heater_delay_s + dead_time
    harmonics = max(harmonics, max(order for order, _, _ in model.ptc.components()))
    if 2 * harmonics + 2 > phase_points:
        raise FeedforwardLimitError(f"phase_points ({phase_points}) must exceed twice the harmonics ({harmonics})")
    problem = _problem(model, setpoint_K, max_power, period_s, delay, measure, harmonics)
    floor_gain = _smallest_held_gain(problem.heater_path, period_s, delay, measure) if certify else None
    thermometer_at_line = complex(problem.heater_path.frequency_response(model.ptc.angular_frequency_rad_s))
    return _solved(problem, thermometer_at_line, floor_gain, lambda delivered: _commanded(model, delivered),
                   model.sensor_noise.flange_thermometer_rms_K, setpoint_K=float(setpoint_K),
                   heater_resistance_ohm=float(heater_resistance_ohm), max_current_A=float(max_current_A),
                   period_s=float(period_s), heater_delay_s=float(delay), measure=measure, phase_points=phase_points,
                   cooler_angular_frequency_rad_s=model.ptc.angular_frequency_rad_s,
                   averaging_time_s=float(averaging_time_s))


def limit_for_plant(line: np.ndarray, plant: np.ndarray, mean_heater_power_w: float, max_heater_power_w: float,
                    setpoint_K: float, period_s: float, *, heater_delay_s: float, cooler_angular_frequency_rad_s: float,
                    sensor_noise_rms_K: float, averaging_time_s: float = DEFAULT_AVERAGING_TIME_S,
                    phase_points: int = DEFAULT_PHASE_POINTS) -> FeedforwardLimit:
    """The limit for a cryostat known by its line and plant at the harmonics (learned, not modelled).

    The same optimisation as :func:`feedforward_limit`, over the harmonics given,
    with the mean power that holds the setpoint as measured. Not certified (no
    transfer function, so no bound on the plant beyond those harmonics); the
    thermometer's continuous response at the line is not known (NaN).

    Parameters
    ----------
    line : numpy.ndarray
        T2's line ``L_n`` (K, complex; n = 1..N, against the cooler phase the feedforward tracks).
    plant : numpy.ndarray
        ``H_n``: a waveform coefficient to T2's readings (K/W, complex), as the loop samples it.
    mean_heater_power_w, max_heater_power_w : float
        The mean power that holds the setpoint, and R * I_max**2 (W).
    setpoint_K, period_s, heater_delay_s : float
        For the record (the plant already includes the delay).
    cooler_angular_frequency_rad_s, sensor_noise_rms_K, averaging_time_s : float
        For the noise floor.
    phase_points : int

    Raises
    ------
    FeedforwardLimitError
        When the mean power is not strictly within 0 .. R * I_max**2.

    Examples
    --------
    >>> import numpy as np
    >>> limit = limit_for_plant(np.array([1.73e-3 + 0j]), np.array([7.36e-3 * np.exp(-2.0j)]), 0.113, 0.5, 5.0,
    ...                         0.08, heater_delay_s=0.0, cooler_angular_frequency_rad_s=10.83,
    ...                         sensor_noise_rms_K=20e-6)
    >>> limit.limited_by, round(limit.authority, 2)
    ('authority', 0.88)
    """
    if not 0.0 < mean_heater_power_w < max_heater_power_w:
        raise FeedforwardLimitError(f"a mean heater power of {1e3 * mean_heater_power_w:.0f} mW leaves no room "
                                    f"within 0..{1e3 * max_heater_power_w:.0f} mW")
    line = np.asarray(line, dtype=complex)
    problem = _Problem(line=line, gain=np.asarray(plant, dtype=complex), mean=float(mean_heater_power_w), low=0.0,
                       high=float(max_heater_power_w), heater_path=None)
    return _solved(problem, complex(math.nan, math.nan), None, lambda delivered: delivered, sensor_noise_rms_K,
                   setpoint_K=float(setpoint_K), heater_resistance_ohm=float(max_heater_power_w), max_current_A=1.0,
                   period_s=float(period_s), heater_delay_s=float(heater_delay_s), measure="sampled",
                   phase_points=phase_points, cooler_angular_frequency_rad_s=cooler_angular_frequency_rad_s,
                   averaging_time_s=float(averaging_time_s))


def _solved(problem: "_Problem", thermometer_at_line: complex, floor_gain: float | None, commanded,
            sensor_noise_rms_K: float, **reported) -> FeedforwardLimit:
    """The best waveform for the problem, and the limit as reported (``floor_gain`` None: not certified;
    ``reported``: the inputs the limit is given for, by the names :class:`FeedforwardLimit` gives them)."""
    bounds = (problem.mean, problem.low, problem.high)
    phase_points = reported["phase_points"]
    amplitudes = best_bounded_waveform(problem.line, problem.gain, *bounds, phase_points=phase_points)
    residual = problem.line + problem.gain * amplitudes
    lower_bound = None
    if floor_gain is not None:
        lower_bound = math.sqrt(residual_lower_bound(problem.line, problem.gain, amplitudes, *bounds, floor_gain))

    # Harmonics 1-6 (the waveform has none above N, and N covers every harmonic of the line).
    line_shown = _first_harmonics(problem.line)
    residual_shown = _first_harmonics(residual)
    open_line = _amplitude(line_shown)
    needed = float(abs(problem.line[0]) / abs(problem.gain[0]))
    largest = largest_fundamental(*bounds)
    sinusoid = max(0.0, min(problem.mean - problem.low, problem.high - problem.mean))
    fundamental_left = max(0.0, float(abs(problem.line[0]) - abs(problem.gain[0]) * sinusoid))
    best_sinusoid = _amplitude(np.concatenate([[fundamental_left], line_shown[1:]]))
    limit = _amplitude(residual_shown)
    noise = noise_floor_K(sensor_noise_rms_K, reported["averaging_time_s"], reported["period_s"])

    waveform_harmonics = amplitudes        # against the cooler's phase phi (T5 reads A cos phi)
    waveform_delivered = waveform_values(waveform_harmonics, problem.mean, phase_points)
    waveform_delivered = np.clip(waveform_delivered, problem.low, problem.high)
    waveform_phase = 2.0 * math.pi * np.arange(phase_points) / phase_points
    gain_at_line = complex(problem.gain[0])
    return FeedforwardLimit(
        **reported, harmonics=problem.line.size, mean_heater_power_W=float(problem.mean),
        max_heater_power_W=reported["heater_resistance_ohm"] * reported["max_current_A"] ** 2,
        thermometer_gain_at_line_K_per_W=abs(thermometer_at_line),
        thermometer_phase_at_line_deg=math.degrees(cmath.phase(thermometer_at_line)),
        heater_gain_at_line_K_per_W=abs(gain_at_line),
        heater_phase_at_line_deg=math.degrees(cmath.phase(gain_at_line)),
        line_power_needed_W=needed, largest_line_power_W=largest, authority=largest / needed if needed else math.inf,
        sinusoid_line_power_W=sinusoid, open_line_K=open_line, best_sinusoid_K=best_sinusoid,
        ptc_periodic_limit_K=limit, whole_periodic_limit_K=_amplitude(residual), lower_bound_K=lower_bound,
        open_line_harmonics_K=tuple(float(v) for v in np.abs(line_shown)),
        limit_harmonics_K=tuple(float(v) for v in np.abs(residual_shown)),
        noise_floor_K=noise, predicted_best_residual_K=math.hypot(limit, noise),
        authority_limited=limit > AUTHORITY_FRACTION * open_line,
        waveform_phase_rad=_read_only(waveform_phase),
        waveform_power_w=_read_only(commanded(waveform_delivered)),
        waveform_harmonics_w=_read_only(waveform_harmonics),
    )


def limit_for_heater_power(model: CryostatModel, setpoint_K: float, max_power_w: float, period_s: float = 0.08,
                           **options) -> FeedforwardLimit:
    """:func:`feedforward_limit` when only the heater's largest power R * I_max**2 is known.

    The limit depends on the heater only through that power; the result's
    ``heater_resistance_ohm`` and ``max_current_A`` then read ``max_power_w``
    ohm and 1 A.
    """
    return feedforward_limit(model, setpoint_K, max_power_w, 1.0, period_s, **options)


def _first_harmonics(phasors: np.ndarray) -> np.ndarray:
    """Phasors of harmonics 1..REPORTED_HARMONICS (zero beyond the ones given)."""
    shown = np.zeros(REPORTED_HARMONICS, dtype=complex)
    count = min(REPORTED_HARMONICS, phasors.size)
    shown[:count] = phasors[:count]
    return shown


def _read_only(array: np.ndarray) -> np.ndarray:
    array = np.array(array)
    array.flags.writeable = False
    return array


def _check_inputs(resistance, current, period, delay, measure, averaging, harmonics, phase_points) -> None:
    for name, value, unit in (("heater resistance", resistance, "ohm"), ("current limit", current, "A"),
                              ("loop period", period, "s"), ("averaging time", averaging, "s")):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
            raise FeedforwardLimitError(f"the {name} must be a number > 0 {unit}, got {value!r}")
    if not (math.isfinite(delay) and delay >= 0.0):
        raise FeedforwardLimitError(f"the heater delay must be >= 0 s, got {delay!r}")
    if measure not in MEASURES:
        raise FeedforwardLimitError(f"measure must be one of {', '.join(MEASURES)}, got {measure!r}")
    if harmonics < 1 or phase_points < 8:
        raise FeedforwardLimitError(f"need harmonics >= 1 and phase_points >= 8, got {harmonics}, {phase_points}")


def _check_reach(model: CryostatModel, setpoint_K: float, max_power_w: float, resistance: float,
                 current: float) -> None:
    base = model.operating_point.flange_temperature_K
    mean = mean_heater_power_w(model, setpoint_K)
    if not math.isfinite(setpoint_K) or mean < 0.0:
        raise FeedforwardLimitError(
            f"setpoint {setpoint_K} K is below the flange's temperature with the heater off ({base} K): "
            "the heater cannot cool")
    highest = _highest_delivered_w(model, max_power_w)
    if mean > highest:
        reach = base + highest * model.heater_to_thermometer.dc_gain
        raise FeedforwardLimitError(
            f"setpoint {setpoint_K} K needs {mean * 1e3:.0f} mW of mean heater power, more than the heater's "
            f"{highest * 1e3:.0f} mW ({resistance:g} ohm x ({current:g} A)^2); it reaches {reach:.2f} K at most")


# ---------------------------------------------------------------------------
# what would change it
# ---------------------------------------------------------------------------
#: Default values of the sensitivity tables.
SWEEP_SETPOINTS_K = (4.5, 5.0, 5.5, 6.0, 6.5, 7.0, 7.5, 8.0)
SWEEP_RESISTANCES_OHM = (10.0, 17.0, 25.0, 35.0, 50.0, 75.0, 100.0, 150.0, 200.0)
SWEEP_MAX_CURRENTS_A = (0.05, 0.075, 0.1, 0.125, 0.15, 0.2)
SWEEP_PARAMETERS = {"setpoint": "setpoint_K", "heater_resistance": "heater_resistance_ohm",
                    "max_current": "max_current_A"}


@dataclass(frozen=True)
class SweepPoint:
    """One row of a sensitivity table: the limit, or why there is none (setpoint out of reach).

    ``mean_heater_power_W`` (what the setpoint needs) and ``max_heater_power_W`` (R I_max**2) are
    given either way.
    """

    value: float
    mean_heater_power_W: float
    max_heater_power_W: float
    limit: FeedforwardLimit | None
    problem: str = ""


def limit_sweep(model: CryostatModel, vary: str, values, *, setpoint_K: float, heater_resistance_ohm: float,
                max_current_A: float, **options) -> tuple[SweepPoint, ...]:
    """The limit as one of setpoint, heater resistance or current limit varies, the others held.

    Parameters
    ----------
    model : CryostatModel
    vary : {"setpoint", "heater_resistance", "max_current"}
    values : iterable of float
        Values of the varied quantity (K, ohm or A).
    setpoint_K, heater_resistance_ohm, max_current_A : float
        The values held.
    **options
        Passed to :func:`feedforward_limit` (``certify`` defaults to False here).

    Returns
    -------
    tuple of SweepPoint
        One per value; ``limit`` is None with ``problem`` saying why when the setpoint is out
        of the heater's reach there.

    Examples
    --------
    >>> from cryod.model import load_model
    >>> rows = limit_sweep(load_model(), "heater_resistance", [17.0, 50.0], setpoint_K=5.0,
    ...                    heater_resistance_ohm=50.0, max_current_A=0.1)
    >>> [round(row.limit.ptc_periodic_limit_K * 1e3, 2) for row in rows]
    [1.07, 0.53]
    """
    if vary not in SWEEP_PARAMETERS:
        raise FeedforwardLimitError(f"vary must be one of {', '.join(SWEEP_PARAMETERS)}, got {vary!r}")
    options.setdefault("certify", False)
    held = {"setpoint_K": setpoint_K, "heater_resistance_ohm": heater_resistance_ohm, "max_current_A": max_current_A}
    rows = []
    for value in values:
        arguments = dict(held, **{SWEEP_PARAMETERS[vary]: float(value)})
        powers = (mean_heater_power_w(model, arguments["setpoint_K"]),
                  arguments["heater_resistance_ohm"] * arguments["max_current_A"] ** 2)
        try:
            rows.append(SweepPoint(float(value), *powers, feedforward_limit(model, **arguments, **options)))
        except FeedforwardLimitError as error:
            rows.append(SweepPoint(float(value), *powers, None, str(error)))
    return tuple(rows)


@dataclass(frozen=True)
class LimitChange:
    """The limit if one thing were changed (:func:`limit_changes`)."""

    change: str                         # what, in words ("setpoint 5.5 K", "R I_max^2 x 2 (1000 mW)")
    point: SweepPoint

    def describe(self) -> str:
        """One phrase: the change and the limit it would give (or why none)."""
        limit = self.point.limit
        if limit is None:
            return f"{self.change}: out of reach"
        return f"{self.change}: {1e6 * limit.ptc_periodic_limit_K:.1f} µK ({limit.limited_by}-limited)"

    def to_dict(self) -> dict:
        """For ``--json``."""
        limit = self.point.limit
        return {"change": self.change,
                "ptc_periodic_limit_K": None if limit is None else limit.ptc_periodic_limit_K,
                "limited_by": None if limit is None else limit.limited_by,
                "problem": self.point.problem or None}


def limit_changes(model: CryostatModel, setpoint_K: float, max_power_w: float, period_s: float = 0.08, *,
                  setpoint_step_K: float = 0.5, **options) -> tuple[LimitChange, ...]:
    """What would change the limit: the setpoint a step down and up, the heater's largest power doubled.

    The heater enters the limit only through R * I_max**2: doubling it is R x 2 or I_max x sqrt(2).
    At 5 K it changes nothing (the waveform rests at 0 W: the lower bound binds), while the
    setpoint, which sets the mean power, does.

    Parameters
    ----------
    model : CryostatModel
    setpoint_K, max_power_w : float
        The setpoint and R * I_max**2 in use (K, W).
    period_s : float
        Loop period (s).
    setpoint_step_K : float
        How far the setpoint is moved each way (K).
    **options
        Passed to :func:`feedforward_limit` (``certify`` defaults to False).

    Returns
    -------
    tuple of LimitChange

    Examples
    --------
    >>> from cryod.model import load_model
    >>> for change in limit_changes(load_model(), 5.0, 0.5, heater_delay_s=0.0):
    ...     print(change.describe())
    setpoint 4.5 K: 1220.3 µK (authority-limited)
    setpoint 5.5 K: 116.5 µK (authority-limited)
    R I_max^2 x 2 (1000 mW): 526.0 µK (authority-limited)
    """
    options.setdefault("certify", False)
    held = {"setpoint_K": setpoint_K, "heater_resistance_ohm": max_power_w, "max_current_A": 1.0,
            "period_s": period_s}
    setpoints = (setpoint_K - setpoint_step_K, setpoint_K + setpoint_step_K)
    changes = [LimitChange(f"setpoint {point.value:g} K", point)
               for point in limit_sweep(model, "setpoint", setpoints, **held, **options)]
    doubled = limit_sweep(model, "heater_resistance", (2.0 * max_power_w,), **held, **options)[0]
    changes.append(LimitChange(f"R I_max^2 x 2 ({1e3 * doubled.max_heater_power_W:.0f} mW)", doubled))
    return tuple(changes)


__all__ = [
    "AUTHORITY_FRACTION", "DEFAULT_AVERAGING_TIME_S", "DEFAULT_HARMONICS", "DEFAULT_PHASE_POINTS", "MEASURES",
    "REPORTED_HARMONICS", "FeedforwardLimit", "FeedforwardLimitError", "LimitChange", "SweepPoint",
    "feedforward_limit", "limit_changes", "limit_for_plant", "limit_sweep", "mean_heater_power_w", "noise_floor_K",
]
