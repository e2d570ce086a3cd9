"""The control loop: every period, trigger, read, convert, control, set the heater, hand over the row.

The loop thread does only the cycle. Rows go to the data log through a
queue; status goes out as an immutable snapshot that other threads read;
commands (from the control socket, reloads) come in through a queue and are
applied at a tick boundary.

Deadlines are absolute (``start + k * period``) on an injected clock. A cycle
that ends after the next deadline is an overrun: the loop skips to the next
deadline still ahead and never bursts to catch up.

The heater power is the sum of control terms (:class:`ControlTerm`): PI now,
others beside it without changing the loop. The sum is held within 0 to
R * I_max**2 and every term is told what was applied (anti-windup).
"""

from __future__ import annotations

import logging
import math
import queue
import threading
from dataclasses import dataclass, field, replace
from typing import Callable, Protocol

from cryod.config import DaemonConfig
from cryod.control.pi import PiController, PiGains, SetpointRamp
from cryod.realtime import LoopGarbageCollector
from cryod.safety import EXIT_EXCEPTION, EXIT_INSTRUMENTS_LOST, EXIT_OK, Fault, ReadingChecks, fault_from_instrument_error
from cryod.timing import LoopTiming
from drivers.errors import InstrumentError

log = logging.getLogger("cryod.loop")

#: Columns of every row, in order (the first five are the cryod-log v1 contract).
ROW_COLUMNS = ("time_s", "T2_K", "T5_K", "heater_W", "setpoint_K", "T2_ohm", "T5_ohm", "trigger_skew_ms",
               "lateness_ms", "cycle_ms", "pi_proportional_W", "pi_integral_W", "state")

STATE_HOLDING = "holding"          # start-up: heater off until readings are valid and in range
STATE_CLOSED = "closed"            # regulating to the setpoint
STATE_MANUAL = "manual"            # open loop at a commanded heater power
STATE_OFF = "off"                  # heater off on request
STATE_RECOVERING = "recovering"    # after a transient fault: heater off, waiting for valid readings
STATE_STOPPED = "stopped"


# ---------------------------------------------------------------------------
# what the loop needs from the instruments
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Measurement:
    """Both thermometers' resistances at one trigger instant."""

    trigger_time_s: float
    skew_s: float
    flange_resistance_ohm: float
    ptc_stage_resistance_ohm: float


class Instruments(Protocol):
    """The two DMMs and the heater supply, as the loop sees them."""

    def measure(self) -> Measurement:
        """Trigger both DMMs at the same instant and return their readings."""

    def set_heater_power(self, power_w: float) -> None:
        """Apply a heater power (W) within the configured limits."""

    def heater_off(self) -> None:
        """Heater output to 0 A."""

    def reconnect(self) -> None:
        """Reopen connections after a transient fault."""

    def close(self) -> None:
        """Heater off and release the instruments."""


class TemperatureCurve(Protocol):
    def temperature_K(self, resistance_ohm: float) -> float: ...


# ---------------------------------------------------------------------------
# control terms
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class TickInputs:
    """What a control term sees each tick."""

    time_s: float
    dt_s: float
    flange_K: float
    ptc_stage_K: float
    setpoint_K: float


class ControlTerm(Protocol):
    """One additive part of the heater power."""

    name: str

    def start(self, tick: TickInputs, present_power_w: float) -> None:
        """The loop closes: continue from ``present_power_w`` without a bump."""

    def update(self, tick: TickInputs) -> float:
        """This term's heater power for the coming period (W)."""

    def limit(self, requested_w: float, applied_w: float) -> None:
        """The total requested and what was applied after the heater limits."""

    def columns(self) -> dict[str, float]:
        """Extra record columns (W)."""


class PiTerm:
    """PI feedback on the flange temperature as a control term."""

    name = "pi"

    def __init__(self, controller: PiController):
        self.controller = controller

    def start(self, tick: TickInputs, present_power_w: float) -> None:
        # bumpless against the present temperature; a setpoint step then acts through Kp as usual
        self.controller.set_automatic(tick.flange_K, tick.flange_K, present_power_w)

    def update(self, tick: TickInputs) -> float:
        return self.controller.update(tick.flange_K, tick.setpoint_K, tick.dt_s)

    def limit(self, requested_w: float, applied_w: float) -> None:
        self.controller.limit(requested_w, applied_w)

    def columns(self) -> dict[str, float]:
        return {"pi_proportional_W": self.controller.proportional_w, "pi_integral_W": self.controller.integral_w}


# ---------------------------------------------------------------------------
# status and commands
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Status:
    """A snapshot of the loop for the control socket and systemd STATUS."""

    time_s: float = math.nan
    state: str = STATE_HOLDING
    flange_K: float = math.nan
    ptc_stage_K: float = math.nan
    heater_w: float = 0.0
    setpoint_K: float | None = None
    target_K: float | None = None
    ramp_K_per_min: float = 0.0
    last_fault: str | None = None
    loop_timing: LoopTiming | None = None      # summarised when asked, not every tick

    @property
    def timing(self) -> dict:
        return self.loop_timing.summary() if self.loop_timing is not None else {}

    def as_dict(self) -> dict:
        return {
            "time_s": self.time_s, "state": self.state, "T2_K": self.flange_K, "T5_K": self.ptc_stage_K,
            "heater_W": self.heater_w, "setpoint_K": self.setpoint_K, "target_K": self.target_K,
            "ramp_K_per_min": self.ramp_K_per_min, "last_fault": self.last_fault, **self.timing,
        }

    def one_line(self) -> str:
        """Short text for systemd STATUS=."""
        setpoint = f"{self.setpoint_K:.4f} K" if self.setpoint_K is not None else "none"
        text = (f"{self.state}: T2 {self.flange_K:.5f} K, setpoint {setpoint}, heater {self.heater_w * 1e3:.2f} mW, "
                f"overruns {self.timing.get('overruns', 0)}")
        if self.last_fault:
            text += f"; last fault: {self.last_fault}"
        return text


@dataclass
class Command:
    """A request to the loop, answered at the next tick boundary."""

    name: str
    value: object = None
    done: threading.Event = field(default_factory=threading.Event)
    ok: bool = False
    message: str = ""

    def answer(self, ok: bool, message: str) -> None:
        self.ok, self.message = ok, message
        self.done.set()


class Clock(Protocol):
    def now(self) -> float: ...
    def sleep_until(self, deadline_s: float) -> None: ...


# ---------------------------------------------------------------------------
# the loop
# ---------------------------------------------------------------------------
class ControlLoop:
    """The periodic cycle with its safety logic.

    Parameters
    ----------
    config : DaemonConfig
    instruments : Instruments
    flange_curve, ptc_stage_curve : calibration curves (resistance to temperature)
    clock : Clock
    emit_row : callable
        Receives each row (a dict of ``ROW_COLUMNS``; ``time_s`` is the clock
        time of the trigger) and each event (a str); must not block.
    watchdog : callable, optional
        Called after every good cycle (systemd WATCHDOG=1, rate-limited by the callee).
    """

    def __init__(self, config: DaemonConfig, instruments: Instruments, flange_curve: TemperatureCurve,
                 ptc_stage_curve: TemperatureCurve, clock: Clock, emit_row: Callable[[object], None],
                 watchdog: Callable[[], None] | None = None):
        self.config = config
        self.instruments = instruments
        self.flange_curve = flange_curve
        self.ptc_stage_curve = ptc_stage_curve
        self.clock = clock
        self.emit_row = emit_row
        self.watchdog = watchdog or (lambda: None)
        self.period_s = config.loop.period_s
        self.timing = LoopTiming(self.period_s)
        control = config.control
        self.pi = PiController(PiGains(control.proportional_W_per_K, control.integral_W_per_K_s),
                               0.0, config.heater.max_power_w)
        self.terms: list[ControlTerm] = [PiTerm(self.pi)]
        self.ramp = SetpointRamp(control.setpoint_K or 0.0, control.ramp_K_per_min)
        self.checks = ReadingChecks(config.safety.flange_max_K, config.safety.ptc_stage_max_K,
                                    config.safety.max_repeated_readings)
        self.state = STATE_HOLDING
        self.mode_after_holding = STATE_CLOSED if control.setpoint_K is not None else STATE_OFF
        self.manual_power_w = 0.0
        self.heater_w = 0.0
        self.last_fault: Fault | None = None
        self.status = Status(state=STATE_HOLDING, setpoint_K=None, target_K=control.setpoint_K,
                             ramp_K_per_min=control.ramp_K_per_min)
        self.commands: queue.SimpleQueue[Command] = queue.SimpleQueue()
        self.exit_code: int | None = None
        self._stop_reason: str | None = None
        self._valid_in_a_row = 0
        self._recovering_since: float | None = None
        self._last_reconnect_s = -math.inf
        self._last_trigger_s: float | None = None
        self._tick_start_s = 0.0
        self._gc = LoopGarbageCollector()

    # -- from other threads ---------------------------------------------------
    def submit(self, command: Command) -> Command:
        """Queue a command for the next tick boundary (thread-safe)."""
        self.commands.put(command)
        return command

    def request_stop(self, reason: str) -> None:
        """Stop at the next tick with the heater at 0 W (safe from a signal handler)."""
        self._stop_reason = reason

    # -- running ----------------------------------------------------------------
    def run(self, duration_s: float | None = None, manage_gc: bool = True) -> int:
        """Run until stopped, a fatal fault, or ``duration_s`` of clock time.

        Returns
        -------
        int
            Exit code (0 after a requested stop or the end of ``duration_s``).
        """
        start = self.clock.now()
        end = start + duration_s if duration_s is not None else math.inf
        deadline = start + self.period_s
        if manage_gc:
            self._gc.start()
        try:
            while self.exit_code is None:
                if deadline > end + 1e-9:
                    self._stop(EXIT_OK, None)
                    break
                self.clock.sleep_until(deadline)
                self._tick(deadline)
                now = self.clock.now()
                missed = int((now - deadline) // self.period_s) if now > deadline + self.period_s else 0
                self.timing.record_cycle_end(missed)
                if missed:
                    self._event(f"overrun: cycle ended {(now - deadline) * 1e3:.1f} ms after its deadline "
                                f"(started {(self._tick_start_s - deadline) * 1e3:.1f} ms late); "
                                f"{missed} deadline(s) skipped")
                deadline += (missed + 1) * self.period_s
                if missed and self.timing.overrun_streak >= self.config.loop.overrun_streak_limit \
                        and self.exit_code is None:
                    self._fault(Fault("overrun_streak", f"{self.timing.overrun_streak} cycles in a row ended after "
                                                        f"the next deadline (last: {missed} period(s) late)"))
                if manage_gc and self.exit_code is None:
                    self._gc.collect_if_time(deadline - self.clock.now())
                    self.timing.gc_longest_s = self._gc.longest_s
        except BaseException as error:     # the heater must be off whatever happened
            self._heater_off_or_die()
            self._stop(EXIT_EXCEPTION, Fault("exception", f"{type(error).__name__}: {error}"))
            raise
        finally:
            if manage_gc:
                self._gc.stop()
        return self.exit_code

    # -- one tick -----------------------------------------------------------------
    def _tick(self, deadline: float) -> None:
        tick_start = self._tick_start_s = self.clock.now()
        self.timing.record_tick(tick_start - deadline)
        self._apply_commands()
        if self._stop_reason is not None:
            self._stop(EXIT_OK, Fault("stop_requested", self._stop_reason))
            return
        row = {"time_s": tick_start, "lateness_ms": (tick_start - deadline) * 1e3}
        if self.state == STATE_RECOVERING:
            self._maybe_reconnect(tick_start)
            if self.exit_code is not None:
                return
        try:
            measurement = self.instruments.measure()
        except InstrumentError as error:
            self._fault(fault_from_instrument_error(error), row)
            return
        row.update(time_s=measurement.trigger_time_s, T2_ohm=measurement.flange_resistance_ohm,
                   T5_ohm=measurement.ptc_stage_resistance_ohm, trigger_skew_ms=measurement.skew_s * 1e3)
        fault = self.checks.check_resistances(measurement.flange_resistance_ohm,
                                               measurement.ptc_stage_resistance_ohm)
        if fault is not None:
            self._fault(fault, row)
            return
        try:
            flange_K = float(self.flange_curve.temperature_K(measurement.flange_resistance_ohm))
            stage_K = float(self.ptc_stage_curve.temperature_K(measurement.ptc_stage_resistance_ohm))
        except ValueError as error:        # OutOfCalibrationRange is a ValueError
            self._fault(Fault("sensor_out_of_calibration", str(error)), row)
            return
        row.update(T2_K=flange_K, T5_K=stage_K)
        over = self.checks.check_temperatures(flange_K, stage_K)
        if self.state in (STATE_HOLDING, STATE_RECOVERING):
            self._count_valid(over is None, measurement, flange_K, stage_K, row)
            return
        if over is not None:
            self._fault(over, row)
            return
        dt = self.period_s if self._last_trigger_s is None else measurement.trigger_time_s - self._last_trigger_s
        self._last_trigger_s = measurement.trigger_time_s
        power = self._heater_power(measurement.trigger_time_s, dt, flange_K, stage_K, row)
        try:
            self.instruments.set_heater_power(power)
        except InstrumentError as error:
            self._fault(fault_from_instrument_error(error), row)
            return
        self.heater_w = power
        row["heater_W"] = power
        self._finish_row(row, flange_K, stage_K)
        self.watchdog()

    def _heater_power(self, time_s: float, dt_s: float, flange_K: float, stage_K: float, row: dict) -> float:
        if self.state == STATE_MANUAL:
            row["state"] = STATE_MANUAL
            return self.manual_power_w
        if self.state == STATE_OFF:
            row["state"] = STATE_OFF
            return 0.0
        setpoint = self.ramp.advance(dt_s)
        tick = TickInputs(time_s, dt_s, flange_K, stage_K, setpoint)
        requested = sum(term.update(tick) for term in self.terms)
        applied = min(max(requested, 0.0), self.config.heater.max_power_w)
        for term in self.terms:
            term.limit(requested, applied)
            row.update(term.columns())
        row["setpoint_K"] = setpoint
        row["state"] = STATE_CLOSED if applied == requested else f"{STATE_CLOSED}-limited"
        return applied

    def _finish_row(self, row: dict, flange_K: float, stage_K: float) -> None:
        row.setdefault("state", self.state)
        row.setdefault("heater_W", self.heater_w)
        row["cycle_ms"] = (self.clock.now() - self._tick_start_s) * 1e3
        self.emit_row(row)
        closed = self.state == STATE_CLOSED
        # one tuple per tick, assigned at once: readers in other threads see a consistent snapshot
        self._latest = (row["time_s"], self.state, flange_K, stage_K, self.heater_w,
                        self.ramp.setpoint_K if closed else None, self.ramp.target_K if closed else None,
                        self.ramp.rate_K_per_min, self.last_fault)
        self._status = None

    @property
    def status(self) -> Status:
        """The loop as of its last tick (built when asked, from the tick's snapshot)."""
        status = self._status
        if status is None:
            time_s, state, flange_K, stage_K, heater_w, setpoint_K, target_K, rate, fault = self._latest
            status = Status(time_s=time_s, state=state, flange_K=flange_K, ptc_stage_K=stage_K, heater_w=heater_w,
                            setpoint_K=setpoint_K, target_K=target_K, ramp_K_per_min=rate,
                            last_fault=str(fault) if fault else None, loop_timing=self.timing)
            self._status = status
        return status

    @status.setter
    def status(self, status: Status) -> None:
        self._status = status
        self._latest = (status.time_s, status.state, status.flange_K, status.ptc_stage_K, status.heater_w,
                        status.setpoint_K, status.target_K, status.ramp_K_per_min, self.last_fault)

    # -- start-up and recovery ----------------------------------------------------
    def _count_valid(self, in_range: bool, measurement: Measurement, flange_K: float, stage_K: float,
                     row: dict) -> None:
        """Holding or recovering: heater stays off until enough valid, in-range readings."""
        self._valid_in_a_row = self._valid_in_a_row + 1 if in_range else 0
        row.update(heater_W=0.0, state=self.state)
        waiting_for = self.config.safety.valid_readings_to_resume
        if self._valid_in_a_row >= waiting_for:
            previous = self.state
            self._last_trigger_s = measurement.trigger_time_s
            resume_to = self.mode_after_holding
            self.state = resume_to
            self._recovering_since = None
            if resume_to == STATE_CLOSED and previous == STATE_HOLDING:
                self._close_loop(TickInputs(measurement.trigger_time_s, self.period_s, flange_K, stage_K,
                                            self.ramp.setpoint_K), present_power_w=0.0)
            self._event(f"resumed: {waiting_for} valid readings after {previous}; state {resume_to}")
        self._finish_row(row, flange_K, stage_K)

    def _close_loop(self, tick: TickInputs, present_power_w: float) -> None:
        if self.ramp.rate_K_per_min > 0.0:
            self.ramp.setpoint_K = tick.flange_K
        else:
            self.ramp.setpoint_K = self.ramp.target_K
        tick = TickInputs(tick.time_s, tick.dt_s, tick.flange_K, tick.ptc_stage_K, self.ramp.setpoint_K)
        for term in self.terms:
            term.start(tick, present_power_w)

    def _maybe_reconnect(self, now: float) -> None:
        if now - self._recovering_since > self.config.safety.recovery_timeout_s:
            self._stop(EXIT_INSTRUMENTS_LOST, Fault(self.last_fault.cause,
                       f"not recovered within {self.config.safety.recovery_timeout_s:g} s: {self.last_fault.message}"))
            return
        if self.last_fault.cause in ("connection_lost", "instrument_timeout", "bad_reply") \
                and now - self._last_reconnect_s >= 1.0:
            self._last_reconnect_s = now
            try:
                self.instruments.reconnect()
                self.checks.reset()
            except InstrumentError as error:
                log.warning("reconnect failed: %s", error)

    # -- faults ---------------------------------------------------------------------
    def _fault(self, fault: Fault, row: dict | None = None) -> None:
        """Heater to 0 W now, record why, then recover or stop."""
        self._heater_off_or_die()
        self.last_fault = fault
        self._valid_in_a_row = 0
        if row is not None:
            row.update(heater_W=0.0, state=f"fault:{fault.cause}", cycle_ms=(self.clock.now() - self._tick_start_s) * 1e3)
            self.emit_row(row)
        if self.state in (STATE_RECOVERING, STATE_HOLDING) and fault.recoverable:
            self._publish_fault_state(self.state)
            return
        self._event(f"fault: {fault}")
        if fault.recoverable:
            log.warning("heater off: %s; recovering", fault)
            if self.state in (STATE_CLOSED, STATE_MANUAL, STATE_OFF):
                self.mode_after_holding = self.state      # recovery returns to what was running
            self.state = STATE_RECOVERING
            self._recovering_since = self.clock.now()
            self._last_reconnect_s = -math.inf
            self._publish_fault_state(STATE_RECOVERING)
        else:
            self._stop(fault.exit_code, fault)

    def _heater_off_or_die(self) -> None:
        self.heater_w = 0.0
        try:
            self.instruments.heater_off()
        except InstrumentError as error:
            fault = Fault("heater_fault", f"could not switch the heater off: {error}")
            self.last_fault = fault
            self._event(f"fault: {fault}")
            log.critical("%s", fault)
            self.exit_code = fault.exit_code

    def _stop(self, exit_code: int, fault: Fault | None) -> None:
        self._heater_off_or_die()
        if self.exit_code is not None and self.exit_code != EXIT_OK:
            return
        self.exit_code = exit_code
        if fault is not None:
            self.last_fault = fault
            self._event(f"stop: {fault}")
            level = logging.INFO if exit_code == EXIT_OK else logging.CRITICAL
            log.log(level, "heater off, stopping (exit %d): %s", exit_code, fault)
        self.state = STATE_STOPPED
        self._publish_fault_state(STATE_STOPPED)

    def _publish_fault_state(self, state: str) -> None:
        self.status = replace(self.status, state=state, heater_w=0.0, loop_timing=self.timing,
                              last_fault=str(self.last_fault) if self.last_fault else None)

    def _event(self, text: str) -> None:
        self.emit_row(text)

    # -- commands ----------------------------------------------------------------------
    def _apply_commands(self) -> None:
        while True:
            try:
                command = self.commands.get_nowait()
            except queue.Empty:
                return
            try:
                ok, message = self._apply(command)
            except (ValueError, TypeError) as error:
                ok, message = False, str(error)
            self._event(f"command {command.name}: {message}" if ok else f"command {command.name} refused: {message}")
            command.answer(ok, message)

    def _apply(self, command: Command) -> tuple[bool, str]:
        control = self.config.control
        if command.name == "setpoint":
            value = float(command.value)
            if not control.setpoint_min_K <= value <= control.setpoint_max_K:
                return False, (f"setpoint {value:g} K refused: outside {control.setpoint_min_K:g}.."
                               f"{control.setpoint_max_K:g} K (control.setpoint_min_K/max_K)")
            self.ramp.target_K = value
            if self.state in (STATE_HOLDING, STATE_RECOVERING):
                self.mode_after_holding = STATE_CLOSED
                return True, f"setpoint {value:g} K, applied once readings are valid"
            if self.state != STATE_CLOSED:
                status = self.status
                self.state = STATE_CLOSED
                self.mode_after_holding = STATE_CLOSED
                tick = TickInputs(status.time_s, self.period_s, status.flange_K, status.ptc_stage_K, value)
                self._close_loop(tick, present_power_w=self.heater_w)
            return True, f"setpoint {value:g} K" + (f", ramping at {self.ramp.rate_K_per_min:g} K/min"
                                                   if self.ramp.rate_K_per_min else "")
        if command.name == "ramp":
            value = float(command.value)
            if not 0.0 <= value <= control.max_ramp_K_per_min:
                return False, (f"ramp {value:g} K/min refused: outside 0..{control.max_ramp_K_per_min:g} K/min "
                               f"(control.max_ramp_K_per_min)")
            self.ramp.rate_K_per_min = value
            return True, f"ramp {value:g} K/min"
        if command.name == "heater-off":
            self.manual_power_w = 0.0
            if self.state in (STATE_HOLDING, STATE_RECOVERING):
                self.mode_after_holding = STATE_OFF
            else:
                self.state = STATE_OFF
            self._heater_off_or_die()
            return True, "heater off; give a setpoint to regulate again"
        if command.name == "manual":
            value = float(command.value)
            limit = self.config.heater.max_power_w
            if not 0.0 <= value <= limit:
                return False, f"heater power {value:g} W refused: outside 0..{limit:g} W (R * I_max^2)"
            self.manual_power_w = value
            if self.state in (STATE_HOLDING, STATE_RECOVERING):
                self.mode_after_holding = STATE_MANUAL
            else:
                self.state = STATE_MANUAL
            return True, f"open loop, heater {value:g} W"
        if command.name == "reload":
            return self._reload(command.value)
        return False, f"unknown command {command.name!r}"

    def _reload(self, new: DaemonConfig) -> tuple[bool, str]:
        """Apply a validated configuration at this tick boundary, bumplessly, or keep the old one."""
        restart = self.config.restart_needed_for(new)
        if restart:
            return False, (f"kept the running configuration: changes to {', '.join(restart)} need a restart "
                           f"(systemctl restart cryod)")
        old, control = self.config, new.control
        rate = control.ramp_K_per_min if control.ramp_K_per_min != old.control.ramp_K_per_min \
            else self.ramp.rate_K_per_min
        target = control.setpoint_K if control.setpoint_K != old.control.setpoint_K and control.setpoint_K \
            is not None else self.ramp.target_K
        if rate > control.max_ramp_K_per_min:
            return False, (f"kept the running configuration: the ramp in use, {rate:g} K/min, is above the new "
                           f"control.max_ramp_K_per_min {control.max_ramp_K_per_min:g}")
        if self.state == STATE_CLOSED and not control.setpoint_min_K <= target <= control.setpoint_max_K:
            return False, (f"kept the running configuration: the setpoint in use, {target:g} K, is outside the new "
                           f"limits {control.setpoint_min_K:g}..{control.setpoint_max_K:g} K")
        self.config = new
        self.pi.set_output_limits(0.0, new.heater.max_power_w)
        self.pi.set_gains(PiGains(control.proportional_W_per_K, control.integral_W_per_K_s))
        self.ramp.rate_K_per_min = rate
        self.ramp.target_K = target
        self.checks = ReadingChecks(new.safety.flange_max_K, new.safety.ptc_stage_max_K,
                                    new.safety.max_repeated_readings)
        return True, f"configuration reloaded from {new.source}"


def wait_for(command: Command, timeout_s: float = 5.0) -> Command:
    """Block until the loop has answered ``command`` (or time out)."""
    if not command.done.wait(timeout_s):
        command.ok, command.message = False, f"no answer from the control loop within {timeout_s:g} s"
    return command

