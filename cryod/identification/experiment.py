"""The identification experiment: its plan, its phases, and when the flange counts as settled.

The experiment runs on the daemon's own loop, open loop (the regulator's
manual mode), phase after phase:

1. ``approach`` (only with a base power above 0 W): the heater at the base
   power until T2 has settled;
2. ``line``: the heater held at the base power for ``line_hold_s``: the
   cooler's line, the noise and the starting level;
3. ``step``: the heater raised by ``step_power_w`` and held until T2 has
   settled (at least ``min_settle_s``, at most ``max_settle_s``);
4. ``modulation`` (optional): the heater modulated about the stepped power,
   ``step_power_w`` plus ``modulation_amplitude_w * sin(w t)``, for
   ``modulation_s``;

then the heater goes to 0 W and the daemon stops.

About a setpoint (``setpoint_K``, one zone's identification) the same phases run in closed loop:
``regulate``, the daemon regulating at the setpoint until the heater power has settled (the
criterion below, on the heater power; its time counts from when a configured ramp has reached the
setpoint); ``line``, held there; ``step``, the setpoint stepped by
``setpoint_step_K``, until the heater power has settled again. The fit takes the heater as the input
and T2 as the output, as in open loop; the approach across the range stays out of it.

Settled, the stated criterion: over the last ``settle_window_s`` the
straight line fitted to T2 changes by less than ``settle_fraction`` of T2's
change since the phase began (the mean of that window less the mean of the
previous phase's last window; for the first phase, of its first 10 s), or by
less than ``settle_floor_K`` (a flange that was already settled). A straight line over many cooler periods is blind to the
cooler's line, and its slope is measured to about 2 µK per window at 20 µK
noise. The line's slope is that at the window's middle, so for a single
exponential of time constant tau the default (0.5 %, 120 s) is met at
``t = 60 s + tau ln(120 s / (0.005 tau))``: 880 s for the shipped model's 165 s,
when T2 is within 0.5 % of its final change.

:class:`ExperimentRunner` takes each row the loop emits (it is one of the
daemon's row taps, so it runs on the loop's thread: it appends the reading and
judges the settling once a second of data, about 0.1 ms) and hands the loop
its next command (:mod:`cryod.service.commands`) at a phase's start.

Examples
--------
>>> plan = ExperimentPlan(step_power_w=0.010)
>>> plan.check(heater_max_power_w=0.5)
>>> ExperimentPlan(step_power_w=0.6).check(heater_max_power_w=0.5)
Traceback (most recent call last):
...
ValueError: the step to 0.6 W (base 0 W + step 0.6 W) is above the heater's R * I_max^2 = 0.5 W: give a smaller --step-power
"""

from __future__ import annotations

import collections
import dataclasses
import math
import threading
from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np

#: Without a previous phase, T2's change in a phase is counted from its mean over the phase's first seconds.
REFERENCE_S = 10.0
#: Names of the phases, in order.
PHASES = ("approach", "line", "step", "modulation")


@dataclass(frozen=True)
class ExperimentPlan:
    """What the experiment does (powers in W, times in s).

    Attributes
    ----------
    step_power_w : float
        Size of the heater step (> 0).
    base_power_w : float
        Heater power before the step (0: the zero-heater operating point).
    line_hold_s : float
        Length of the open-loop hold before the step.
    settle_fraction : float
        Settled when T2 changes by less than this fraction of its change in the
        phase over the last ``settle_window_s``.
    settle_window_s : float
    settle_floor_K : float
        ... or by less than this (K).
    min_settle_s, max_settle_s : float
        A settling phase lasts at least / at most this long; at the most it
        ends unsettled, and the experiment says so.
    modulation_amplitude_w : float
        0: no modulation phase.
    modulation_rad_s : float
        Angular frequency of the modulation.
    modulation_s : float
        Length of the modulation phase.
    setpoint_K : float, optional
        Identify about this flange temperature, in closed loop: a first phase, ``regulate``, holds T2
        there under the daemon's control until the heater power has settled; ``line`` holds it on;
        ``step`` steps the setpoint by ``setpoint_step_K`` (the heater's answer is what is fitted).
        Instead of ``base_power_w`` and ``step_power_w``.
    setpoint_step_K : float
        The setpoint step about ``setpoint_K`` (K).
    """

    step_power_w: float = 0.010
    base_power_w: float = 0.0
    line_hold_s: float = 120.0
    settle_fraction: float = 0.005
    settle_window_s: float = 120.0
    settle_floor_K: float = 20e-6
    min_settle_s: float = 300.0
    max_settle_s: float = 3600.0
    modulation_amplitude_w: float = 0.0
    modulation_rad_s: float = 2.5
    modulation_s: float = 240.0
    setpoint_K: float | None = None
    setpoint_step_K: float = 0.05

    @property
    def stepped_power_w(self) -> float:
        return self.base_power_w + self.step_power_w

    @property
    def phases(self) -> tuple[str, ...]:
        """The phases this plan runs, in order."""
        names = ["regulate"] if self.setpoint_K is not None else ["approach"] if self.base_power_w > 0.0 else []
        names += ["line", "step"]
        if self.modulation_amplitude_w > 0.0:
            names.append("modulation")
        return tuple(names)

    def check(self, heater_max_power_w: float) -> None:
        """Raise ValueError, naming the option, when the plan cannot run on this heater."""
        finite = {name: value for name, value in asdict(self).items() if value is not None and not math.isfinite(value)}
        if finite:
            raise ValueError(f"not finite: {', '.join(finite)}")
        if not self.step_power_w > 0.0:
            raise ValueError(f"the heater step must be above 0 W, got {self.step_power_w:g} W (--step-power)")
        if self.base_power_w < 0.0:
            raise ValueError(f"the base power cannot be negative, got {self.base_power_w:g} W (--base-power)")
        if self.setpoint_K is not None:
            if self.base_power_w > 0.0 or self.modulation_amplitude_w > 0.0:
                raise ValueError("about a setpoint the experiment runs in closed loop, with a setpoint step: give "
                                 "no --base-power or --modulation-amplitude with --setpoints")
            if not (math.isfinite(self.setpoint_step_K) and self.setpoint_step_K != 0.0):
                raise ValueError(f"the setpoint step must be a number other than 0 K, got {self.setpoint_step_K!r}")
        if self.stepped_power_w > heater_max_power_w:
            raise ValueError(f"the step to {self.stepped_power_w:g} W (base {self.base_power_w:g} W + step "
                             f"{self.step_power_w:g} W) is above the heater's R * I_max^2 = {heater_max_power_w:g} W: "
                             f"give a smaller --step-power")
        if self.modulation_amplitude_w > 0.0:
            low = self.stepped_power_w - self.modulation_amplitude_w
            high = self.stepped_power_w + self.modulation_amplitude_w
            if low < 0.0 or high > heater_max_power_w:
                raise ValueError(f"the modulation {self.stepped_power_w:g} +- {self.modulation_amplitude_w:g} W "
                                 f"leaves the heater's range 0..{heater_max_power_w:g} W (--modulation-amplitude)")
            if not (self.modulation_rad_s > 0.0 and self.modulation_s > 0.0):
                raise ValueError("the modulation needs an angular frequency and a duration above 0 "
                                 "(--modulation-frequency, --modulation-time)")
        if not 0.0 < self.settle_fraction < 1.0:
            raise ValueError(f"--settle-fraction must lie between 0 and 1, got {self.settle_fraction:g}")
        if not self.settle_window_s >= 10.0:
            raise ValueError(f"--settle-window must be at least 10 s, got {self.settle_window_s:g} s")
        if not (self.line_hold_s >= 10.0):
            raise ValueError(f"--line-hold must be at least 10 s (the line and the noise), got {self.line_hold_s:g} s")
        if not (0.0 <= self.min_settle_s <= self.max_settle_s):
            raise ValueError(f"need 0 <= --min-settle <= --max-settle, got {self.min_settle_s:g} s and "
                             f"{self.max_settle_s:g} s")
        if self.max_settle_s < 2.0 * self.settle_window_s:
            raise ValueError(f"--max-settle ({self.max_settle_s:g} s) must allow two settle windows "
                             f"({2.0 * self.settle_window_s:g} s)")

    def criterion(self) -> str:
        """The settling criterion in words (for the record's header and the report)."""
        return (f"settled when the straight line fitted to T2 over the last {self.settle_window_s:g} s changes by "
                f"less than {100 * self.settle_fraction:g} % of T2's change since the phase began, or by less than "
                f"{self.settle_floor_K * 1e6:g} µK; at least {self.min_settle_s:g} s, at most {self.max_settle_s:g} s")

    def metadata(self) -> dict:
        """Header lines of the record."""
        return {"identify_plan": ", ".join(f"{key} {value:g}" for key, value in asdict(self).items()
                                          if value is not None),
                "identify_phases": " -> ".join(self.phases),
                "identify_settle_criterion": self.criterion()}


class SettleJudge:
    """Whether T2 has settled in a phase (the plan's criterion), and how long it may still take.

    Parameters
    ----------
    plan : ExperimentPlan
    expected_s : float
        A first guess of the settling time (s), until the data give their own.
    """

    def __init__(self, plan: ExperimentPlan, expected_s: float, reference_K: float | None = None):
        self.plan = plan
        self.expected_s = expected_s
        self.reference_K = reference_K
        self.recent: collections.deque[tuple[float, float]] = collections.deque()   # the last window
        self.start_s: float | None = None
        self._first_sum, self._first_count = 0.0, 0
        self.change_K = 0.0
        self.drift_K = math.inf
        self.history: list[tuple[float, float]] = []        # (time, drift over a window / allowed)

    def add(self, time_s: float, flange_K: float) -> None:
        if self.start_s is None:
            self.start_s = time_s
        if not math.isfinite(flange_K):
            return
        if time_s <= self.start_s + REFERENCE_S:
            self._first_sum += flange_K
            self._first_count += 1
        self.recent.append((time_s, flange_K))
        while self.recent and self.recent[0][0] < time_s - self.plan.settle_window_s:
            self.recent.popleft()

    def elapsed_s(self, now_s: float) -> float:
        return 0.0 if self.start_s is None else now_s - self.start_s

    def judge(self, now_s: float) -> bool:
        """Whether the phase has settled by now (call about once a second of data)."""
        plan = self.plan
        elapsed = self.elapsed_s(now_s)
        if elapsed < plan.settle_window_s or len(self.recent) < 20 or not self._first_count:
            return False
        times, values = np.array(self.recent).T
        slope = np.polyfit(times - now_s, values, 1)[0]
        self.drift_K = abs(float(slope)) * plan.settle_window_s
        reference = self.reference_K if self.reference_K is not None else self._first_sum / self._first_count
        self.change_K = abs(float(np.mean(values)) - reference)
        allowed = max(plan.settle_fraction * self.change_K, plan.settle_floor_K)
        self.history.append((now_s, self.drift_K / allowed))
        del self.history[:-200]
        return elapsed >= plan.min_settle_s and self.drift_K <= allowed

    def time_left_s(self, now_s: float) -> float:
        """Estimated time until settled (s): from the decay of the drift over the last two minutes (not less
        than the guess until half of it has passed), else the guess."""
        plan = self.plan
        elapsed = self.elapsed_s(now_s)
        guess = max(self.expected_s - elapsed, plan.min_settle_s - elapsed, 0.0)
        recent = [(t, r) for t, r in self.history if t >= now_s - 120.0 and r > 0.0]
        if len(recent) >= 10:
            times, ratios = np.array(recent).T
            rate = -np.polyfit(times, np.log(ratios), 1)[0]
            # early on the fastest term dominates the drift's decay and the data promise too much:
            # until half the guess has passed, the guess is the least
            floor = guess if elapsed < 0.5 * self.expected_s else 0.0
            if rate > 0.0 and ratios[-1] > 1.0:
                guess = max(math.log(ratios[-1]) / rate, plan.min_settle_s - elapsed, floor)
            elif ratios[-1] <= 1.0:
                guess = max(plan.min_settle_s - elapsed, 0.0)
        return float(min(guess, max(plan.max_settle_s - elapsed, 0.0)))


@dataclass
class Progress:
    """A snapshot for the progress display (read from another thread)."""

    phase: str = "waiting for the instruments"
    phase_index: int = 0
    phase_count: int = 0
    elapsed_s: float = 0.0
    time_left_s: float = math.nan
    flange_K: float = math.nan
    heater_w: float = 0.0
    note: str = ""


class ExperimentRunner:
    """Drives the plan through the loop: a row tap of the daemon.

    Parameters
    ----------
    plan : ExperimentPlan
    submit : callable
        ``submit(name, value)``: hand the loop a command (``manual``, ``modulate``).
    stop : callable
        ``stop(reason)``: the loop stops at its next tick, heater at 0 W.
    note : callable
        ``note(text)``: an event line in the record.
    expected_settle_s : float
        First guess of a settling phase's length (s): five of the base model's longest time constant.

    Attributes
    ----------
    outcome : str or None
        ``finished`` when the plan ran to its end, ``fault`` when a fault
        ended it (``fault`` then holds the row's state), else None.
    unsettled : list of str
        Phases that ended at ``max_settle_s`` without settling.
    """

    def __init__(self, plan: ExperimentPlan, submit: Callable[[str, object], None], stop: Callable[[str], None],
                 note: Callable[[str], None], expected_settle_s: float = 900.0):
        self.plan = plan
        self.closed_loop = plan.setpoint_K is not None
        self._at_setpoint = False       # the regulate phase's ramp has reached the setpoint
        self.submit = submit
        self.stop = stop
        self.note = note
        self.expected_settle_s = expected_settle_s
        self.phases = plan.phases
        self.index = -1
        self.phase_start_s = math.nan
        self.judge: SettleJudge | None = None
        self.outcome: str | None = None
        self.fault: str | None = None
        self.unsettled: list[str] = []
        self.phase_log: list[tuple[str, float, float]] = []     # (phase, start, end) in the loop's clock
        self.started_s: float | None = None
        self._next_judgement_s = -math.inf
        self._recent: collections.deque[tuple[float, float]] = collections.deque()    # T2 over the last window
        self._lock = threading.Lock()
        self._progress = Progress(phase_count=len(self.phases))

    @property
    def phase(self) -> str | None:
        return self.phases[self.index] if 0 <= self.index < len(self.phases) else None

    @property
    def progress(self) -> Progress:
        with self._lock:
            return Progress(**self._progress.__dict__)

    # -- the loop's rows ---------------------------------------------------------
    def __call__(self, item) -> None:
        """A row or event from the loop (events are ignored)."""
        state = getattr(item, "state", None)
        if state is None or not hasattr(item, "T2_K"):
            return
        if self.outcome is not None:
            return
        state = str(state)
        time_s = float(item.time_s)
        if state.startswith("fault:"):
            self.outcome, self.fault = "fault", state[len("fault:"):]
            self._end_phase(time_s)
            self.note(f"identification stopped in phase {self.phase}: fault {self.fault}; heater at 0 W")
            self.stop(f"identification experiment stopped by the fault {self.fault}")
            return
        if state in ("holding", "recovering"):
            return                      # waiting for valid readings: the heater is off, the plan waits
        if self.index < 0:
            self.started_s = time_s
            self._start_phase(0, time_s)
        flange = float(item.T2_K) if item.T2_K is not None else math.nan
        if self.phase == "regulate" and not self._at_setpoint:
            setpoint = getattr(item, "setpoint_K", None)
            if setpoint is None or setpoint != self.plan.setpoint_K:
                self._update_progress(time_s, flange, float(item.heater_W or 0.0))
                return                  # still ramping there: the phase's time counts from the ramp's end
            self._at_setpoint = True
            self.phase_start_s = time_s
            self.note(f"the setpoint reached {self.plan.setpoint_K:g} K: the regulation settles from here")
        if self.judge is not None:       # about a setpoint, the heater settles (T2 is held)
            self.judge.add(time_s, float(item.heater_W if item.heater_W is not None else math.nan)
                           if self.closed_loop else flange)
        if math.isfinite(flange):
            self._recent.append((time_s, flange))
            while self._recent[0][0] < time_s - self.plan.settle_window_s:
                self._recent.popleft()
        done = self._phase_done(time_s)
        if done:
            self._advance(time_s)
        self._update_progress(time_s, flange, float(item.heater_W or 0.0))

    def _phase_done(self, time_s: float) -> bool:
        phase, plan = self.phase, self.plan
        if phase is None:                   # none under way
            return False
        elapsed = time_s - self.phase_start_s
        if phase == "line":
            return elapsed >= plan.line_hold_s
        if phase == "modulation":
            return elapsed >= plan.modulation_s
        # settling phases: judged once a second of data
        if time_s < self._next_judgement_s:
            return False
        self._next_judgement_s = time_s + 1.0
        judge = self.judge
        assert judge is not None            # every settling phase has one (_start_phase)
        if judge.judge(time_s):
            if self.closed_loop:
                self.note(f"phase {phase} settled after {elapsed:.0f} s: the heater moved "
                          f"{judge.drift_K * 1e3:.3f} mW over the last {plan.settle_window_s:g} s, change in "
                          f"the phase {judge.change_K * 1e3:.3f} mW")
            else:
                self.note(f"phase {phase} settled after {elapsed:.0f} s: T2 moved {judge.drift_K * 1e6:.1f} µK "
                          f"over the last {plan.settle_window_s:g} s, change in the phase "
                          f"{judge.change_K * 1e3:.3f} mK")
            return True
        if elapsed >= plan.max_settle_s:
            self.unsettled.append(phase)
            self.note(f"phase {phase} NOT settled after {plan.max_settle_s:g} s (--max-settle): T2 still moved "
                      f"{judge.drift_K * 1e6:.1f} µK over the last {plan.settle_window_s:g} s")
            return True
        return False

    def _advance(self, time_s: float) -> None:
        self._end_phase(time_s)
        if self.index + 1 >= len(self.phases):
            self.outcome = "finished"
            self.note("identification experiment finished: heater to 0 W")
            self.stop("identification experiment finished")
            return
        self._start_phase(self.index + 1, time_s)

    def _end_phase(self, time_s: float) -> None:
        if self.phase is not None and math.isfinite(self.phase_start_s):
            self.phase_log.append((self.phase, self.phase_start_s, time_s))

    def _start_phase(self, index: int, time_s: float) -> None:
        from cryod.control.regulator import HeaterModulation

        self.index = index
        self.phase_start_s = time_s
        phase, plan = self.phases[index], self.plan
        reference = float(np.mean([v for _, v in self._recent])) if self._recent and index > 0 else None
        self.judge = SettleJudge(plan, self.expected_settle_s, reference) if phase in ("approach", "step") else None
        if self.closed_loop:             # the heater power settles: within 1 uW a window at least
            self.judge = SettleJudge(dataclasses.replace(plan, settle_floor_K=1e-6), self.expected_settle_s) \
                if phase in ("regulate", "step") else None
        self._next_judgement_s = -math.inf
        if phase == "regulate":
            self.submit("setpoint", plan.setpoint_K)
            power = f"regulating at {plan.setpoint_K:g} K"
        elif phase == "line" and self.closed_loop:
            power = f"held at {plan.setpoint_K:g} K"
        elif phase == "step" and plan.setpoint_K is not None:      # closed loop
            self.submit("setpoint", plan.setpoint_K + plan.setpoint_step_K)
            power = f"setpoint {plan.setpoint_K + plan.setpoint_step_K:g} K (step of {plan.setpoint_step_K * 1e3:g} mK)"
        elif phase in ("approach", "line"):
            self.submit("manual", plan.base_power_w)
            power = f"heater {plan.base_power_w * 1e3:g} mW"
        elif phase == "step":
            self.submit("manual", plan.stepped_power_w)
            power = f"heater {plan.stepped_power_w * 1e3:g} mW (step of {plan.step_power_w * 1e3:g} mW)"
        else:
            self.submit("modulate", HeaterModulation(plan.stepped_power_w, plan.modulation_amplitude_w,
                                                      plan.modulation_rad_s))
            power = (f"heater {plan.stepped_power_w * 1e3:g} +- {plan.modulation_amplitude_w * 1e3:g} mW at "
                     f"{plan.modulation_rad_s:g} rad/s")
        self.note(f"identification phase {phase} ({index + 1}/{len(self.phases)}): {power}")

    # -- progress ---------------------------------------------------------------------
    def phase_time_left_s(self, time_s: float) -> float:
        phase, plan = self.phase, self.plan
        elapsed = time_s - self.phase_start_s
        if phase == "line":
            return max(plan.line_hold_s - elapsed, 0.0)
        if phase == "modulation":
            return max(plan.modulation_s - elapsed, 0.0)
        return self.judge.time_left_s(time_s) if self.judge is not None else math.nan

    def time_left_s(self, time_s: float) -> float:
        """Estimated time to the end of the plan (s)."""
        if self.phase is None:
            return 0.0
        left = self.phase_time_left_s(time_s)
        for phase in self.phases[self.index + 1:]:
            left += {"line": self.plan.line_hold_s, "modulation": self.plan.modulation_s}.get(
                phase, max(self.expected_settle_s, self.plan.min_settle_s))
        return left

    def _update_progress(self, time_s: float, flange_K: float, heater_w: float) -> None:
        progress = Progress(phase=self.phase or "done", phase_index=self.index + 1, phase_count=len(self.phases),
                            elapsed_s=time_s - (self.started_s or time_s),
                            time_left_s=self.time_left_s(time_s) if self.outcome is None else 0.0,
                            flange_K=flange_K, heater_w=heater_w)
        with self._lock:
            self._progress = progress


__all__ = ["ExperimentPlan", "ExperimentRunner", "Progress", "SettleJudge", "PHASES"]
