"""The paper's Fig. 10 reproduced: a fixed 100 mW sinusoid locked to the cooler, at 8 phases, over PI at 5 K.

Run: PYTHONPATH=. python3 docs/figures/paper_fig10.py
Writes docs/figures/paper_fig10.png and prints the tables of docs/feedforward.md ("The paper, reproduced").

Phase convention. The sinusoid is ``amplitude * cos(psi + phase)`` with psi the cooler's phase tracked
from T5 (:class:`cryod.cooler.phase.CoolerPhaseTracker`: T5's fundamental is ``B cos(psi)``).
Written with sines, as a Simulink sine block would be: T5's oscillation ``B sin(w t)`` and the heater's
sinusoid ``amplitude * sin(w t + phase)``. ``phase`` is how far the heater's sinusoid leads T5's
oscillation; this is the paper's phase angle, assumed (docs/feedforward.md says why).

The sinusoid is a control term defined here (:class:`FixedSinusoidTerm`) and registered in
``cryod.control.terms.TERM_TYPES`` only while the runs are made (:func:`fixed_sinusoid_registered`).
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass, replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from cryod.cooler.phase import CoolerPhaseTracker
from cryod.control.feedforward import FeedforwardTerm
from cryod.control.feedforward.limit import feedforward_limit, mean_heater_power_w
from cryod.control.feedforward.harmonic_plant import line_at_harmonics, plant_at_harmonics
from cryod.control.pi import PiGains
from cryod.control.terms import TERM_TYPES, ControlTerm, TickInputs, term_type
from cryod.model import CryostatModel, load_model
from cryod.records.columns import Column
from cryod.cooler.periodic import periodic_amplitudes
from cryod.control.closed_loop import ClosedLoopRun, Segment, run_program

HERE = Path(__file__).resolve().parent
CONFIG = HERE.parent.parent / "config"
MODEL = load_model(CONFIG / "model.yaml")
PRINTED_MODEL = load_model(CONFIG / "model-paper-printed.yaml")
SETPOINT_K = 5.0
MAX_CURRENT_A = 0.1
PERIOD_S = 0.08
AMPLITUDE_W = 0.1
DURATION_S = 900.0
WINDOW_S = 300.0
SEED = 1
#: The paper's eight phases, 0, pi/4, ..., 7 pi/4, and a finer scan.
PHASES_RAD = np.arange(8) * np.pi / 4
FINE_PHASES_RAD = np.arange(32) * np.pi / 16
#: The paper's text (Sec. 4.2): the figure's values are only in its image.
PAPER_OPEN_LINE_MK = 2.75
PAPER_REDUCED_MK = 1.4
PAPER_MINIMUM_BETWEEN_RAD = (3 * np.pi / 4, np.pi)
#: The paper's experiment, PI at 5 K (Sec. 4.1, Fig. 6): about 1.5 mK of oscillation left on T2.
PAPER_PI_LINE_MK = 1.5


# ---------------------------------------------------------------------------
# the fixed sinusoid, a control term
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class FixedSinusoid:
    """Settings of :class:`FixedSinusoidTerm`: ``amplitude_w * cos(psi + phase_rad)``, psi from T5."""

    amplitude_w: float = 0.0
    phase_rad: float = 0.0
    nominal_rad_s: float = MODEL.ptc.angular_frequency_rad_s
    period_s: float = PERIOD_S


class FixedSinusoidTerm(ControlTerm):
    """A sinusoid of fixed amplitude and phase, locked to the cooler as the feedforward is.

    Each reading of T5 updates a :class:`CoolerPhaseTracker`; once it is locked the term outputs
    ``amplitude * cos(psi + phase)`` with psi the phase at the middle of the coming hold (as
    :meth:`cryod.control.feedforward.FeedforwardTerm.update` evaluates its waveform), 0 W before.
    It rides on the feedback: the regulator adds it after PI's sum has been held within
    0..R I_max**2 and told so, then holds the total again; :meth:`limit` records which bound, if
    any, that second hold met (column ``sine_clipped``).
    """

    name = "fixed_sinusoid"
    required = False
    rides_on_feedback = True
    columns = (Column("sine_W", "W", "fixed sinusoid locked to the cooler"),
               Column("sine_clipped", "", "total held at 0 W (-1), at R I_max^2 (+1), or played (0)", "{:.0f}"))

    def __init__(self, settings: FixedSinusoid, output_max: float):
        self.settings = settings
        self.tracker = CoolerPhaseTracker(settings.nominal_rad_s)
        self.phase = None
        self.output_w = 0.0
        self.clipped = 0.0

    @staticmethod
    def settings_from(section) -> FixedSinusoid:
        if section is None:
            return FixedSinusoid()
        settings = FixedSinusoid(section.number("amplitude_W", minimum=0.0, maximum=1.0),
                                 section.number("phase_rad", 0.0))
        section.finish()
        return settings

    def reconfigure(self, settings: FixedSinusoid, output_max: float) -> None:
        self.settings = settings

    def condition(self, tick: TickInputs) -> TickInputs:
        """Track the cooler from T5 in every mode; what the other terms see is unchanged."""
        self.phase = self.tracker.update(tick.ptc_stage_time_s, tick.ptc_stage_K)
        return tick

    def start(self, tick: TickInputs, present_output: float) -> None:
        pass

    def update(self, tick: TickInputs) -> float:
        if self.phase is None or not self.phase.locked:
            self.output_w = 0.0
        else:
            psi = self.phase.phase_at(tick.output_time_s + 0.5 * self.settings.period_s)   # middle of the hold
            self.output_w = self.settings.amplitude_w * math.cos(psi + self.settings.phase_rad)
        return self.output_w

    def limit(self, requested: float, applied: float) -> None:
        self.clipped = float(np.sign(requested - applied))

    def column_values(self) -> tuple[float, ...]:
        return self.output_w, self.clipped


@contextlib.contextmanager
def fixed_sinusoid_registered():
    """``fixed_sinusoid`` in the control terms' factory for the duration of the block."""
    TERM_TYPES[FixedSinusoidTerm.name] = f"{__name__}.{FixedSinusoidTerm.__name__}"
    term_type.cache_clear()
    try:
        yield
    finally:
        del TERM_TYPES[FixedSinusoidTerm.name]
        term_type.cache_clear()


# ---------------------------------------------------------------------------
# runs and measures
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Heater:
    """A heater and the PI gains used with it."""

    label: str
    resistance_ohm: float
    gains: PiGains

    @property
    def max_power_w(self) -> float:
        return self.resistance_ohm * MAX_CURRENT_A ** 2


PAPER_HEATER = Heater("17 ohm, Kp 80 W/K, Ki 4 W/(K s) (paper)", 17.0, PiGains(80.0, 4.0))
EXAMPLE_HEATER = Heater("50 ohm, Kp 10 W/K, Ki 0.2 W/(K s) (example config)", 50.0, PiGains(10.0, 0.2))


def sinusoid(phase_rad: float, model: CryostatModel = MODEL, amplitude_w: float = AMPLITUDE_W) -> tuple:
    """``more_terms`` for run_program: the fixed sinusoid at ``phase_rad`` (register it first)."""
    return ((FixedSinusoidTerm.name, FixedSinusoid(amplitude_w, float(phase_rad),
                                                   model.ptc.angular_frequency_rad_s)),)


def feedforward() -> tuple:
    """``more_terms`` for run_program: the adaptive feedforward with its defaults."""
    return ((FeedforwardTerm.name, FeedforwardTerm.settings_from(None)),)


def run(heater: Heater, more_terms: tuple = (), model: CryostatModel = MODEL, duration_s: float = DURATION_S,
        settled: bool = False) -> ClosedLoopRun:
    """PI to 5 K on the simulated cryostat with ``more_terms``: from 4.23 K (the paper's step), or
    ``settled`` at the setpoint's mean power (shorter runs)."""
    initial = min(mean_heater_power_w(model, SETPOINT_K), heater.max_power_w) if settled else 0.0
    return run_program(model, [Segment(0.0, setpoint_K=SETPOINT_K)], duration_s, gains=heater.gains,
                       heater_max_w=heater.max_power_w, period_s=PERIOD_S, seed=SEED,
                       initial_heater_power_w=initial, more_terms=more_terms)


@dataclass(frozen=True)
class Line:
    """T2's cooler line over a run's last window, and how the heater was held."""

    periodic_K: float           # harmonics 1-6, sqrt of the sum of squared amplitudes (ptc_periodic_amplitude_K)
    fundamental_K: float        # harmonic 1 alone
    at_zero: float              # fraction of the window's ticks with the heater at 0 W
    at_max: float               # ... at R I_max**2
    mean_heater_w: float
    sinusoid_cut: float         # fraction of ticks where the total with the sinusoid was held at a bound (NaN: none)


def measure(result: ClosedLoopRun, model: CryostatModel = MODEL, window_s: float = WINDOW_S,
            heater_max_w: float = math.inf) -> Line:
    """The line on T2 over the last ``window_s`` (phase tracked from T5 over the whole run), and how
    often the heater was at 0 W and at ``heater_max_w`` (R I_max**2)."""
    start = result.time_s[-1] - window_s
    harmonics = periodic_amplitudes(result.time_s, result.flange_K, result.time_s, result.ptc_stage_K,
                                    model.ptc.angular_frequency_rad_s, window_start_s=start)
    late = result.time_s >= start
    heater = result.heater_w[late]
    cut = result.control.get("sine_clipped")
    return Line(float(np.sqrt(np.sum(harmonics ** 2))), float(harmonics[0]), float(np.mean(heater <= 0.0)),
                float(np.mean(heater >= heater_max_w - 1e-12)), float(np.mean(heater)),
                float(np.mean(cut[late] != 0.0)) if cut is not None else math.nan)


def fundamentals(model: CryostatModel) -> tuple[complex, complex]:
    """The line L_1 on T2 (K) and the held heater path H_1 to T2's readings (K/W) at the cooler's fundamental,
    relative to T5's ``cos(psi)`` (:mod:`cryod.control.feedforward.harmonic_plant`)."""
    return complex(line_at_harmonics(model, 1)[0]), complex(plant_at_harmonics(model, [1], PERIOD_S)[0])


def linear_prediction_K(model: CryostatModel, phases_rad, line_K: float | None = None) -> np.ndarray:
    """T2's fundamental with the sinusoid at each phase, open loop and never clipped: ``|L_1 + H_1 a|``,
    ``a = amplitude * exp(j phase)``; ``line_K`` replaces the model's line amplitude (same phase)."""
    line, plant = fundamentals(model)
    if line_K is not None:
        line *= line_K / abs(line)
    return np.abs(line + plant * AMPLITUDE_W * np.exp(1j * np.asarray(phases_rad, dtype=float)))


def best_phase_rad(model: CryostatModel) -> float:
    """The phase at which the sinusoid opposes the line (open loop, unclipped), in 0..2 pi."""
    line, plant = fundamentals(model)
    return float(np.angle(-line / plant) % (2 * np.pi))


def line_for_ratio_K(model: CryostatModel, ratio: float, phases_rad=PHASES_RAD) -> float:
    """The line amplitude (K) that the sinusoid at the best of ``phases_rad`` would reduce by ``ratio``,
    with the model's heater path and line phase (open loop, unclipped; the larger solution)."""
    line, plant = fundamentals(model)
    reach = AMPLITUDE_W * abs(plant)
    cosine = float(np.min(np.cos(np.angle(plant * np.exp(1j * np.asarray(phases_rad)) / line))))
    # |L u + reach e^{j delta}|^2 = ratio^2 L^2:  (1 - ratio^2) L^2 + 2 reach cos(delta) L + reach^2 = 0
    a, b, c = 1.0 - ratio ** 2, 2.0 * reach * cosine, reach ** 2
    return float((-b + math.sqrt(b * b - 4 * a * c)) / (2 * a))


def phase_label(phase_rad: float) -> str:
    quarters = round(phase_rad / (np.pi / 4))
    return "0" if quarters == 0 else ("pi/4" if quarters == 1 else f"{quarters}pi/4")


# ---------------------------------------------------------------------------
# the study
# ---------------------------------------------------------------------------
def scan(heater: Heater, model: CryostatModel = MODEL, phases_rad=PHASES_RAD) -> tuple[Line, list[Line]]:
    """PI alone, then PI with the sinusoid at each phase (register the term first)."""
    alone = measure(run(heater, model=model), model, heater_max_w=heater.max_power_w)
    return alone, [measure(run(heater, sinusoid(phase, model), model=model), model,
                           heater_max_w=heater.max_power_w) for phase in phases_rad]


def with_line_scaled(model: CryostatModel, factor: float) -> CryostatModel:
    """The model with the cooler's line on T2 (and only that) scaled by ``factor`` (through C of eq. 4)."""
    return replace(model, ptc=replace(model.ptc, heat_capacity_J_per_K=model.ptc.heat_capacity_J_per_K * factor))


@dataclass
class Case:
    """One cryostat and heater: PI alone, the sinusoid at the 8 phases and in finer steps, the adaptive
    feedforward, and the computed limit."""

    label: str
    model: CryostatModel
    heater: Heater
    alone: Line | None = None
    lines: list | None = None
    fine: list | None = None
    adaptive: Line | None = None
    limit: object = None

    def study(self) -> "Case":
        self.alone, self.lines = scan(self.heater, self.model)
        self.fine = scan(self.heater, self.model, FINE_PHASES_RAD)[1]
        self.adaptive = measure(run(self.heater, feedforward(), self.model), self.model,
                                heater_max_w=self.heater.max_power_w)
        self.limit = feedforward_limit(self.model, SETPOINT_K, self.heater.resistance_ohm, MAX_CURRENT_A,
                                       period_s=PERIOD_S, heater_delay_s=0.0, certify=False)
        return self

    def print_table(self) -> None:
        alone, limit = self.alone, self.limit
        print(f"\n{self.label}: {self.heater.label}, R I_max^2 = {self.heater.max_power_w * 1e3:.0f} mW")
        print("| | line, harmonics 1-6 (mK) | fundamental (mK) | vs PI alone | heater at 0 W / at R I_max^2 "
              "(% of ticks) | sinusoid cut (% of ticks) |")
        print("|---|---|---|---|---|---|")
        rows = [("PI alone", alone)] + [(f"+ sinusoid at {phase_label(phase)}", line)
                                        for phase, line in zip(PHASES_RAD, self.lines)]
        rows.append(("+ adaptive feedforward (instead of the sinusoid)", self.adaptive))
        for name, line in rows:
            cut = "" if math.isnan(line.sinusoid_cut) else f"{line.sinusoid_cut * 100:.0f}"
            print(f"| {name} | {line.periodic_K * 1e3:.3f} | {line.fundamental_K * 1e3:.3f} | "
                  f"{line.periodic_K / alone.periodic_K:.2f} | {line.at_zero * 100:.0f} / {line.at_max * 100:.0f} "
                  f"| {cut} |")
        print(f"| limit, any waveform (computed: feedforward_limit, heater_delay_s=0) | "
              f"{limit.ptc_periodic_limit_K * 1e3:.3f} | {limit.limit_harmonics_K[0] * 1e3:.3f} | "
              f"{limit.ptc_periodic_limit_K / alone.periodic_K:.2f} | | |")
        print(f"| best sinusoid within 0..R I_max^2 (computed) | {limit.best_sinusoid_K * 1e3:.3f} | | "
              f"{limit.best_sinusoid_K / alone.periodic_K:.2f} | | |")
        fine = [line.periodic_K for line in self.fine]
        best = int(np.argmin(fine))
        paper_best = int(np.argmin(np.abs(FINE_PHASES_RAD - best_phase_rad(PRINTED_MODEL))))
        print(f"open line {limit.open_line_K * 1e3:.3f} mK (limit {limit.ptc_periodic_limit_K / limit.open_line_K:.2f} "
              f"of it); mean heater power {limit.mean_heater_power_W * 1e3:.1f} mW (runs: "
              f"{min(line.mean_heater_w for line in self.lines) * 1e3:.1f} to "
              f"{max(line.mean_heater_w for line in self.lines) * 1e3:.1f} mW); phase in pi/16 steps: least "
              f"{fine[best] * 1e3:.3f} mK ({fine[best] / alone.periodic_K:.2f}) at {FINE_PHASES_RAD[best] / np.pi:.4g} "
              f"pi; at {FINE_PHASES_RAD[paper_best] / np.pi:.4g} pi (the printed equations' best) "
              f"{fine[paper_best] * 1e3:.3f} mK ({fine[paper_best] / alone.periodic_K:.2f})")


def main() -> None:
    with fixed_sinusoid_registered():
        paper = Case("shipped model", MODEL, PAPER_HEATER).study()
        example = Case("shipped model", MODEL, EXAMPLE_HEATER).study()
        factor = PAPER_PI_LINE_MK * 1e-3 / paper.alone.periodic_K
        measured = Case(f"shipped model, line x {factor:.3f} (the paper's {PAPER_PI_LINE_MK:g} mK under PI)",
                        with_line_scaled(MODEL, factor), PAPER_HEATER).study()
        printed = Case("the paper's printed equations (config/model-paper-printed.yaml)", PRINTED_MODEL, PAPER_HEATER)
        printed.alone, printed.lines = scan(PAPER_HEATER, PRINTED_MODEL)
        trace = run(PAPER_HEATER, sinusoid(5 * np.pi / 4))
    open_loop = measure(run_program(MODEL, [Segment(0.0, heater_power_w=0.0)], 300.0, gains=PAPER_HEATER.gains,
                                    heater_max_w=1.0, seed=SEED), window_s=200.0)

    print(f"Fixed {AMPLITUDE_W * 1e3:g} mW sinusoid locked to the cooler over PI at {SETPOINT_K:g} K, "
          f"{PERIOD_S * 1e3:g} ms, seed {SEED}; line on T2 over the last {WINDOW_S:g} s of {DURATION_S:g} s "
          f"(harmonics 1-6 / fundamental, mK); phase: the heater sinusoid's lead over T5's oscillation")
    print(f"shipped model, open loop, heater off (4.23 K): {open_loop.periodic_K * 1e3:.3f} / "
          f"{open_loop.fundamental_K * 1e3:.3f} mK")
    for case in (paper, example, measured):
        case.print_table()

    print(f"\n{printed.label}, {PAPER_HEATER.label}; and the fundamental open loop with the sinusoid never "
          f"clipped, |L_1 + H_1 a|")
    print("| phase | 0 | pi/4 | pi/2 | 3pi/4 | pi | 5pi/4 | 3pi/2 | 7pi/4 | without |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    print("| printed equations, 17 ohm, Kp 80: line, harmonics 1-6 (mK) | "
          + " | ".join(f"{line.periodic_K * 1e3:.3f}" for line in printed.lines)
          + f" | {printed.alone.periodic_K * 1e3:.3f} |")
    for model, name in ((MODEL, "shipped model"), (PRINTED_MODEL, "printed equations")):
        print(f"| {name}, open loop, unclipped (mK) | "
              + " | ".join(f"{value * 1e3:.3f}" for value in linear_prediction_K(model, PHASES_RAD))
              + f" | {abs(fundamentals(model)[0]) * 1e3:.3f} |")
    for model, name in ((MODEL, "shipped model"), (PRINTED_MODEL, "printed equations")):
        line, plant = fundamentals(model)
        phase = best_phase_rad(model)
        least = float(linear_prediction_K(model, [phase])[0])
        print(f"{name}: T2 lags T5 by {-np.angle(line):.3f} rad; the sinusoid opposes the line at {phase:.3f} rad"
              f" = {phase / np.pi:.3f} pi, leaving {least * 1e3:.3f} of {abs(line) * 1e3:.3f} mK "
              f"({least / abs(line):.2f}); heater to T2 at the line {abs(plant) * 1e3:.2f} mK/W, so "
              f"{AMPLITUDE_W * 1e3:g} mW reach {AMPLITUDE_W * abs(plant) * 1e3:.3f} mK")
    ratio = PAPER_REDUCED_MK / PAPER_OPEN_LINE_MK
    half = PAPER_OPEN_LINE_MK / 2
    print(f"the paper's {PAPER_REDUCED_MK:g} / {PAPER_OPEN_LINE_MK:g} = {ratio:.2f} at the best of its 8 phases, with "
          f"the printed heater path and line phase, needs a line of "
          f"{line_for_ratio_K(PRINTED_MODEL, ratio) * 1e3:.3f} mK (amplitude); the sinusoid leaves at best "
          f"{np.min(linear_prediction_K(PRINTED_MODEL, PHASES_RAD, PAPER_OPEN_LINE_MK * 1e-3)) * 1e3:.3f} mK of a "
          f"{PAPER_OPEN_LINE_MK:g} mK line, {np.min(linear_prediction_K(PRINTED_MODEL, PHASES_RAD, half * 1e-3)) * 1e3:.3f}"
          f" mK of a {half:g} mK line ({PAPER_OPEN_LINE_MK:g} mK peak to peak)")
    plot(paper, example, measured, printed, trace)


def plot(paper: Case, example: Case, measured: Case, printed: Case, trace: ClosedLoopRun) -> None:
    figure, (absolute, relative, heater_axis) = plt.subplots(1, 3, figsize=(17, 5.2),
                                                             gridspec_kw={"width_ratios": [1.25, 1.0, 0.9]})
    for case, color in ((paper, "C1"), (example, "C0")):
        short = f"{case.heater.resistance_ohm:g} Ω, Kp {case.heater.gains.proportional_w_per_K:g}"
        absolute.plot(PHASES_RAD, [line.periodic_K * 1e3 for line in case.lines], "o", color=color,
                      label=f"{short}: + 100 mW sinusoid (dots: 8 phases, line: π/16 steps)")
        absolute.plot(FINE_PHASES_RAD, [line.periodic_K * 1e3 for line in case.fine], "-", color=color, lw=1)
        absolute.axhline(case.alone.periodic_K * 1e3, color=color, lw=1, ls="--", label=f"{short}: PI alone")
        absolute.axhline(case.adaptive.periodic_K * 1e3, color=color, lw=1.5, ls="-.",
                         label=f"{short}: adaptive feedforward")
        absolute.axhline(case.limit.ptc_periodic_limit_K * 1e3, color=color, lw=1, ls=":",
                         label=f"{short}: limit, any waveform")
    absolute.plot(PHASES_RAD, [line.periodic_K * 1e3 for line in printed.lines], "s-", color="C2", lw=0.8,
                  label="printed equations, 17 Ω, Kp 80: + sinusoid")
    for case, color, name in ((paper, "C1", "17 Ω, Kp 80"), (example, "C0", "50 Ω, Kp 10"),
                              (measured, "C3", "17 Ω, Kp 80, line to 1.5 mK under PI")):
        relative.plot(FINE_PHASES_RAD, [line.periodic_K / case.alone.periodic_K for line in case.fine], "-",
                      color=color, label=f"shipped model, {name}")
        relative.plot(PHASES_RAD, [line.periodic_K / case.alone.periodic_K for line in case.lines], "o", color=color)
    relative.plot(PHASES_RAD, [line.periodic_K / printed.alone.periodic_K for line in printed.lines], "s-",
                  color="C2", lw=0.8, label="printed equations, 17 Ω, Kp 80")
    for model, color, name in ((MODEL, "0.3", "shipped model"), (PRINTED_MODEL, "C2", "printed equations")):
        relative.plot(FINE_PHASES_RAD, linear_prediction_K(model, FINE_PHASES_RAD) / abs(fundamentals(model)[0]),
                      color=color, lw=0.8, ls="--", label=f"{name}, no PI, never clipped")
    absolute.axhline(PAPER_OPEN_LINE_MK, color="k", lw=1.0, label="paper (text): original 2.75 mK")
    for axis, value in ((absolute, PAPER_REDUCED_MK), (relative, PAPER_REDUCED_MK / PAPER_OPEN_LINE_MK)):
        axis.plot(PAPER_MINIMUM_BETWEEN_RAD, [value, value], "k-", lw=5, solid_capstyle="butt",
                  label="paper (text): 1.4 mK, between 3π/4 and π")
    relative.axhline(1.0, color="k", lw=0.6)
    absolute.set(title="Cooler line on T2 at 5 K (harmonics 1-6, last 300 s of 900 s)",
                 xlabel="phase of the 100 mW sinusoid (lead over T5's oscillation)", ylabel="amplitude (mK)",
                 ylim=(0, 4.4))
    relative.set(title="Relative to the line without the sinusoid", xlabel="phase", ylabel="ratio", ylim=(0, 2.25))
    for axis in (absolute, relative):
        axis.set_xticks(PHASES_RAD, ["0", "π/4", "π/2", "3π/4", "π", "5π/4", "3π/2", "7π/4"])
        axis.grid(alpha=0.3)
        axis.legend(fontsize=6, loc="upper center", ncol=2)

    window = (trace.time_s >= 880.0) & (trace.time_s < 882.0)
    t = trace.time_s[window] - 880.0
    pi_sum = trace.control["pi_proportional_W"][window] + trace.control["pi_integral_W"][window]
    heater_axis.step(t, pi_sum * 1e3, where="post", color="C0", lw=0.8, label="PI's sum (before the heater's bounds)")
    heater_axis.step(t, (np.clip(pi_sum, 0.0, PAPER_HEATER.max_power_w) + trace.control["sine_W"][window]) * 1e3,
                     where="post", color="C2", lw=0.8, label="PI's sum held, + sinusoid")
    heater_axis.step(t, trace.heater_w[window] * 1e3, where="post", color="k", lw=1.5, label="heater (applied)")
    heater_axis.axhline(PAPER_HEATER.max_power_w * 1e3, color="C3", ls=":", lw=1, label="R I_max² = 170 mW")
    heater_axis.axhline(0.0, color="C3", lw=0.6)
    heater_axis.set(title="17 Ω, Kp 80, sinusoid at 5π/4: 2 s at 880 s", xlabel="time (s)",
                    ylabel="heater power (mW)")
    heater_axis.grid(alpha=0.3)
    heater_axis.legend(fontsize=6.5, loc="lower right")
    figure.tight_layout()
    figure.savefig(HERE / "paper_fig10.png", dpi=110)


if __name__ == "__main__":
    main()
