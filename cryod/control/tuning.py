"""PI gains from the model: how a setpoint step goes with given gains, and the gains that settle fastest.

A lab's cryostat and heater decide the gains, not a rule of thumb: the step is
run on the model (the offline closed loop, :mod:`cryod.control.closed_loop`,
with the daemon's own regulator and the heater's limits) and judged as a
metrologist would:

* **rise**: from the step until T2 first comes within 1 mK of the setpoint;
* **overshoot**: how far T2, averaged over whole cooler periods, goes past it;
* **settling**: from the step until that average stays within 1 mK;
* **offset**: the mean of T2 minus the setpoint once settled (an integral held
  at a heater limit leaves one);
* **line**: T2's part synchronous with the cooler under PI alone, against the
  open line: gains that chase the line amplify it (the feedforward then has
  to undo that, and the heater hits its bounds);
* **at bounds**: how often the heater sits at 0 W or at R I_max^2 once settled;
* **margins**: the phase and gain margins of the sampled loop (PI, the heater's
  zero-order hold, the delay from reading to setting, the model's heater-to-T2
  path): how far the gains are from oscillating when the cryostat is not quite
  the model. A step on the model alone cannot show that: gains that settle
  fastest on the model may sit a few degrees from instability.

:func:`suggest_gains` searches Kp and the integral time Kp / Ki on a
logarithmic grid and refines the best with Nelder-Mead, minimising the settling
time among gains that keep the overshoot, the offset, the line and the heater's
bounds within stated tolerances and keep 45 degrees of phase margin and a gain margin of 2
(gains that miss the margins are not even run).

Examples
--------
>>> from cryod.model import load_model
>>> from cryod.control.pi import MAX_GAIN, PiGains
>>> step = step_performance(load_model(), PiGains(10.0, 0.2), setpoint_K=5.0, heater_max_w=0.5)
>>> round(step.rise_s), round(step.settle_s), round(step.line_ratio, 2)
(84, 103, 1.03)
>>> round(step.phase_margin_deg), round(step.gain_margin)
(87, 37)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from cryod.control.closed_loop import Segment, run_program
from cryod.control.feedforward.harmonic_plant import line_at_harmonics
from cryod.control.pi import MAX_GAIN, PiGains
from cryod.cooler.periodic import periodic_amplitudes
from cryod.model import CryostatModel
from cryod.model.dynamics import flange_transfer_functions

#: T2 is judged averaged over this many cooler periods (the line itself is not a settling error).
AVERAGED_PERIODS = 4
#: Tolerance band of rise and settling (K).
BAND_K = 1e-3
#: The last this many seconds of a step judge the settled state (offset, line, heater at bounds).
SETTLED_WINDOW_S = 200.0
#: From a reading to the heater setting in the daemon (s): the loop's measured 32.5 ms, rounded up.
SETTING_DELAY_S = 0.035
#: Frequencies the margins are looked for at (points from 1e-5 rad/s to half the sampling rate).
MARGIN_POINTS = 4000


class TuningError(ValueError):
    """A step the heater cannot make, or a search with nothing acceptable."""


@dataclass(frozen=True)
class StepPerformance:
    """How a setpoint step goes with given gains (times from the step, in s)."""

    gains: PiGains
    setpoint_K: float
    start_K: float
    rise_s: float               # T2 first within 1 mK of the setpoint (inf: never)
    overshoot_K: float          # largest excursion of the period-averaged T2 past the setpoint
    settle_s: float             # the period-averaged T2 within 1 mK from then on (inf: never)
    offset_K: float             # mean T2 minus the setpoint over the settled window
    line_K: float               # T2's part synchronous with the cooler over the settled window (harmonics 1-6)
    open_line_K: float          # the same with the heater constant (the model's line)
    at_bounds_fraction: float   # ticks of the settled window with the heater at 0 W or R I_max^2
    mean_heater_w: float        # over the settled window
    phase_margin_deg: float     # of the sampled loop (inf: the loop gain never reaches 1)
    gain_margin: float          # factor on the loop gain to instability (inf: the phase never reaches -180)

    @property
    def line_ratio(self) -> float:
        """The line under PI over the open line (above 1: PI amplifies it)."""
        return self.line_K / self.open_line_K if self.open_line_K > 0.0 else math.nan

    def summary(self) -> dict:
        """For ``--json``: the figures in lab units."""
        return {"proportional_W_per_K": self.gains.proportional_w_per_K,
                "integral_W_per_K_s": self.gains.integral_w_per_K_s,
                "rise_s": _finite_or_none(self.rise_s), "overshoot_mK": round(self.overshoot_K * 1e3, 3),
                "settle_to_1mK_s": _finite_or_none(self.settle_s), "offset_mK": round(self.offset_K * 1e3, 4),
                "ptc_line_mK": round(self.line_K * 1e3, 4), "line_over_open": round(self.line_ratio, 4),
                "heater_at_bounds_percent": round(100.0 * self.at_bounds_fraction, 2),
                "mean_heater_mW": round(self.mean_heater_w * 1e3, 2),
                "phase_margin_deg": _finite_or_none(self.phase_margin_deg),
                "gain_margin": _finite_or_none(self.gain_margin)}


@dataclass(frozen=True)
class Tolerances:
    """What gains must keep to be acceptable."""

    overshoot_K: float = 1e-3
    offset_K: float = 1e-4
    line_ratio: float = 1.05
    at_bounds_fraction: float = 0.01
    phase_margin_deg: float = 45.0
    gain_margin: float = 2.0

    def margin_violations(self, phase_margin_deg: float, gain_margin: float) -> list[str]:
        """What the loop's margins break, in words."""
        found = []
        if phase_margin_deg < self.phase_margin_deg:
            found.append(f"phase margin {phase_margin_deg:.0f} deg < {self.phase_margin_deg:g} deg")
        if gain_margin < self.gain_margin:
            found.append(f"gain margin {gain_margin:.2f} < {self.gain_margin:g}")
        return found

    def violations(self, step: StepPerformance) -> list[str]:
        """What ``step`` breaks, in words (empty: acceptable)."""
        found = self.margin_violations(step.phase_margin_deg, step.gain_margin)
        if not math.isfinite(step.settle_s):
            found.append("does not settle within 1 mK")
        if step.overshoot_K > self.overshoot_K:
            found.append(f"overshoot {step.overshoot_K * 1e3:.2f} mK > {self.overshoot_K * 1e3:g} mK")
        if abs(step.offset_K) > self.offset_K:
            found.append(f"offset {step.offset_K * 1e3:+.3f} mK beyond {self.offset_K * 1e3:g} mK")
        if step.line_ratio > self.line_ratio:
            found.append(f"line {step.line_ratio:.3f}x the open line > {self.line_ratio:g}x")
        if step.at_bounds_fraction > self.at_bounds_fraction:
            found.append(f"heater at its bounds {100 * step.at_bounds_fraction:.1f} % of the time")
        return found


@dataclass(frozen=True)
class Tuning:
    """The suggested gains, how their step goes, and every run the search made."""

    best: StepPerformance
    tolerances: Tolerances
    runs: tuple[StepPerformance, ...] = field(repr=False)


def loop_margins(model: CryostatModel, gains: PiGains, period_s: float = 0.08,
                 setting_delay_s: float = SETTING_DELAY_S) -> tuple[float, float]:
    """Phase margin (degrees) and gain margin (factor) of the sampled PI loop on the model.

    The loop gain at the sample instants is ``C(z) H(w)``: the PI as the
    regulator computes it (``Kp + Ki T z / (z - 1)``) and the heater-to-T2 path
    with its zero-order hold and setting delay
    (:meth:`~cryod.model.transfer_function.TransferFunction.sampled_response`).
    Margins are taken up to half the sampling rate; inf where the loop gain
    never crosses 1 or its phase never crosses -180 degrees.

    Examples
    --------
    >>> from cryod.model import load_model
    >>> phase, gain = loop_margins(load_model(), PiGains(80.0, 4.0))
    >>> round(phase), round(gain, 1)
    (64, 4.6)
    """
    omega = np.geomspace(1e-5, 0.9999 * math.pi / period_s, MARGIN_POINTS)
    z = np.exp(1j * omega * period_s)
    heater = flange_transfer_functions(model)[0]
    loop = (gains.proportional_w_per_K + gains.integral_w_per_K_s * period_s * z / (z - 1.0)) \
        * heater.sampled_response(omega, period_s, setting_delay_s)
    magnitude, angle = np.abs(loop), np.angle(loop)
    crossings = np.flatnonzero(np.diff(np.sign(magnitude - 1.0)) != 0)
    phase_margin = min((180.0 + math.degrees(angle[k]) for k in crossings), default=math.inf)
    # the phase passes -180 degrees where the loop gain's imaginary part changes sign on the negative real axis
    flips = np.flatnonzero((np.diff(np.sign(loop.imag)) != 0) & (loop.real[:-1] < 0.0))
    gain_margin = min((1.0 / magnitude[k] for k in flips), default=math.inf)
    return float(phase_margin), float(gain_margin)


def step_performance(model: CryostatModel, gains: PiGains, setpoint_K: float, heater_max_w: float, *,
                     start_heater_w: float = 0.0, duration_s: float = 900.0,
                     period_s: float = 0.08, setting_delay_s: float = SETTING_DELAY_S,
                     ramp_K_per_min: float = 0.0) -> StepPerformance:
    """Run a setpoint step on the model and measure it.

    Parameters
    ----------
    model : CryostatModel
    gains : PiGains
        Kp (W/K) and Ki (W/(K s)).
    setpoint_K : float
        The setpoint stepped to at t = 0 (K).
    heater_max_w : float
        R * I_max**2 (W).
    start_heater_w : float
        The heater power the cryostat has settled at before the step (W; 0: the model's
        operating point).
    duration_s : float
        Length of the run (s); the last ``SETTLED_WINDOW_S`` judge the settled state.
    period_s : float
        Loop period (s).
    setting_delay_s : float
        From a reading to the heater setting (s), for the margins (the step itself is run with the
        heater set at the reading).
    ramp_K_per_min : float
        The setpoint ramps to ``setpoint_K`` at this rate (0: a step); times still count from t = 0.

    Returns
    -------
    StepPerformance
    """
    if duration_s < 2.0 * SETTLED_WINDOW_S:
        raise TuningError(f"a step of {duration_s:g} s is too short: at least {2 * SETTLED_WINDOW_S:g} s")
    run = run_program(model, [Segment(0.0, setpoint_K=setpoint_K)], duration_s, gains=gains,
                      heater_max_w=heater_max_w, period_s=period_s, noise=False,
                      initial_heater_power_w=start_heater_w, ramp_K_per_min=ramp_K_per_min)
    t, flange = run.time_s, run.flange_K
    start_K = float(flange[0])
    direction = 1.0 if setpoint_K >= start_K else -1.0
    omega = model.ptc.angular_frequency_rad_s
    width = max(1, int(round(AVERAGED_PERIODS * 2.0 * math.pi / omega / period_s)))
    averaged = np.convolve(flange, np.ones(width) / width, mode="valid")
    averaged_t = t[width // 2:width // 2 + averaged.size]
    reached = np.flatnonzero(direction * (flange - setpoint_K) >= -BAND_K)
    rise = float(t[reached[0]]) if reached.size else math.inf
    past = direction * (averaged - setpoint_K)
    overshoot = float(max(past[averaged_t >= rise].max(initial=0.0), 0.0)) if reached.size else 0.0
    outside = np.flatnonzero(np.abs(averaged - setpoint_K) > BAND_K)
    if outside.size == 0:
        settle = 0.0
    elif outside[-1] >= averaged.size - 1:
        settle = math.inf
    else:
        settle = float(averaged_t[outside[-1] + 1])
    settled = t >= t[-1] - SETTLED_WINDOW_S
    harmonics = periodic_amplitudes(t, flange, t, run.ptc_stage_K, omega, window_start_s=t[-1] - SETTLED_WINDOW_S)
    heater = run.heater_w[settled]
    at_bounds = (heater <= 0.0) | (heater >= heater_max_w * (1.0 - 1e-9))
    open_line = float(np.sqrt(np.sum(np.abs(line_at_harmonics(model, harmonics.size)) ** 2)))
    return StepPerformance(gains, float(setpoint_K), start_K, rise, overshoot, settle,
                           float(np.mean(flange[settled]) - setpoint_K), float(np.sqrt(np.sum(harmonics ** 2))),
                           open_line, float(np.mean(at_bounds)), float(np.mean(heater)),
                           *loop_margins(model, gains, period_s, setting_delay_s))


def suggest_gains(model: CryostatModel, setpoint_K: float, heater_max_w: float, *,
                  tolerances: Tolerances = Tolerances(), start_heater_w: float = 0.0, duration_s: float = 900.0,
                  period_s: float = 0.08, setting_delay_s: float = SETTING_DELAY_S,
                  proportional_range_w_per_K: tuple[float, float] = (0.5, 80.0),
                  integral_time_range_s: tuple[float, float] = (10.0, 500.0), grid: tuple[int, int] = (8, 6),
                  refine_evaluations: int = 24, ramp_K_per_min: float = 0.0) -> Tuning:
    """The PI gains that settle a setpoint step fastest within ``tolerances``.

    A logarithmic grid over Kp and the integral time Kp / Ki, then Nelder-Mead
    from the best acceptable point (in the logarithms of both).

    Parameters
    ----------
    model : CryostatModel
    setpoint_K, heater_max_w : float
        The step's target (K) and R * I_max**2 (W).
    tolerances : Tolerances
        What acceptable gains keep.
    start_heater_w, duration_s, period_s, setting_delay_s : float
        As for :func:`step_performance`.
    proportional_range_w_per_K, integral_time_range_s : (float, float)
        The search ranges of Kp (W/K) and Kp / Ki (s).
    grid : (int, int)
        Grid points over Kp and over the integral time.
    refine_evaluations : int
        Steps the refinement may run (0: the grid's best).
    ramp_K_per_min : float
        As for :func:`step_performance`.

    Returns
    -------
    Tuning

    Raises
    ------
    TuningError
        No gains on the grid meet the tolerances.
    """
    runs: list[StepPerformance] = []

    def evaluate(log_kp: float, log_ti: float) -> StepPerformance | None:
        kp, ti = math.exp(log_kp), math.exp(log_ti)
        if kp > MAX_GAIN or kp / ti > MAX_GAIN:
            return None                  # beyond what a configuration takes
        gains = PiGains(kp, kp / ti)
        if tolerances.margin_violations(*loop_margins(model, gains, period_s, setting_delay_s)):
            return None                  # too close to oscillating: not worth a run
        step = step_performance(model, gains, setpoint_K, heater_max_w, start_heater_w=start_heater_w,
                                duration_s=duration_s, period_s=period_s, setting_delay_s=setting_delay_s,
                                ramp_K_per_min=ramp_K_per_min)
        runs.append(step)
        return step

    def cost(step: StepPerformance | None) -> float:
        return step.settle_s if step is not None and not tolerances.violations(step) else math.inf

    log_kp_low, log_kp_high = np.log(proportional_range_w_per_K)
    log_ti_low, log_ti_high = np.log(integral_time_range_s)
    log_kps = np.linspace(log_kp_low, log_kp_high, grid[0])
    log_tis = np.linspace(log_ti_low, log_ti_high, grid[1])
    for log_kp in log_kps:
        for log_ti in log_tis:
            evaluate(log_kp, log_ti)
    acceptable = [step for step in runs if math.isfinite(cost(step))]
    if not acceptable:
        if not runs:
            raise TuningError("no gains in the search ranges keep the stability margins "
                              f"({tolerances.phase_margin_deg:g} deg, gain {tolerances.gain_margin:g})")
        closest = min(runs, key=lambda step: (len(tolerances.violations(step)), step.settle_s))
        raise TuningError(f"no gains in Kp {proportional_range_w_per_K[0]:g}..{proportional_range_w_per_K[1]:g} W/K, "
                          f"Kp/Ki {integral_time_range_s[0]:g}..{integral_time_range_s[1]:g} s meet the tolerances; "
                          f"the closest (Kp {closest.gains.proportional_w_per_K:.3g} W/K, Ki "
                          f"{closest.gains.integral_w_per_K_s:.3g} W/(K s)): "
                          f"{'; '.join(tolerances.violations(closest))}")
    best = min(acceptable, key=cost)
    if refine_evaluations > 0:
        start = np.log([best.gains.proportional_w_per_K,
                        best.gains.proportional_w_per_K / best.gains.integral_w_per_K_s])
        steps = np.diff(log_kps[:2]).item() / 2, np.diff(log_tis[:2]).item() / 2
        simplex = np.array([start, start + [steps[0], 0.0], start + [0.0, steps[1]]])
        optimize.minimize(lambda x: cost(evaluate(*x)), start, method="Nelder-Mead",
                          options={"maxfev": refine_evaluations, "initial_simplex": simplex, "xatol": 0.02,
                                   "fatol": 1.0})
        best = min((step for step in runs if math.isfinite(cost(step))), key=cost)
    return Tuning(best, tolerances, tuple(runs))


def _finite_or_none(value: float) -> float | None:
    return round(value, 2) if math.isfinite(value) else None


__all__ = ["StepPerformance", "Tolerances", "Tuning", "TuningError", "loop_margins", "step_performance",
           "suggest_gains"]
