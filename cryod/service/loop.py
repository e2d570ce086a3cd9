"""The control loop: every period, trigger, read, convert, regulate, set the heater, hand over the row.

The loop thread does only the cycle. Rows and events go to the data log
through a queue; status goes out as an immutable snapshot that other threads
read; commands (from the control socket, reloads) come in through a queue and
are applied at a tick boundary (:mod:`cryod.service.commands`).

Deadlines are absolute (``start + k * period``) on an injected clock. A cycle
that ends after the next deadline is an overrun: the loop skips to the next
deadline still ahead and never bursts to catch up.

The heater power comes from the regulator (:mod:`cryod.control.regulator`):
the control law lives there; the loop schedules it, checks every reading,
handles faults (:mod:`cryod.service.faults`) and does the I/O.

On any fault the heater-off goes out first, before the loop asks any
instrument why (a failing DMM's error queue is read after it). The record
says what the supply was told and when: the fault tick's row carries the
power the supply had during that tick, and a row at the instant the supply
confirmed the off carries the 0 W (empty ``heater_W``: the off could not be
confirmed, the heater's state is unknown). A stop's heater-off is its ``stop``
event, the last thing the loop writes (and, in a tick the stop cut short, that
tick's own setting).
"""

from __future__ import annotations

import collections
import logging
import math
from concurrent.futures import Future, TimeoutError as FutureTimeout
from typing import Callable, NamedTuple, Protocol

from cryod.config import DaemonConfig, located_error
from cryod.control.regulator import HeaterPowerOutput, Regulator, RegulatorMode
from cryod.control.setpoint_reach import setpoint_warning
from cryod.control.terms import term_columns
from cryod.records.columns import TIME_DECIMALS, Event, Row, RowSchema, loop_schema
from cryod.service.answer_words import WORDS_WAIT_S, AnswerWords, SnapshotAnswer
from cryod.service.commands import Command, CommandRefused, apply_command
from cryod.service.daemon_status import LoopStatus
from cryod.service.fault_episodes import FaultEpisodes
from cryod.service.faults import ExitCode, Fault, FaultCause, ReadingChecks, fault_from_instrument_error
from cryod.service.logs import reply_for_log
from cryod.service.realtime import LoopGarbageCollector
from cryod.service.states import LoopState
from cryod.service.timing import LoopTiming
from cryod.yaml_source import FileFormatError
from drivers.clock import Clock
from drivers.errors import HeaterLimitRefused, InstrumentError
from drivers.thermometer_pair import PairReading

log = logging.getLogger("cryod.loop")

#: Commands carried out at one tick boundary at most; the rest wait, in order, for the next ticks
#: (many clients of the control socket at once cannot stretch a tick).
COMMANDS_PER_TICK = 8
#: Cycles that keep their deadlines for this long after a streak of late ones make the timing reliable again (s).
ON_TIME_AGAIN_S = 10.0
#: A heater-off's own row lies at least this long after the row before it (s): two steps of the record's
#: time, so that the two never print as one instant. An off confirmed sooner is written this much later:
#: the record may say the heater was on a fraction of a millisecond longer than it was, never shorter.
HEATER_OFF_ROW_SPACING_S = 2.0 * 10.0 ** -TIME_DECIMALS


# ---------------------------------------------------------------------------
# what the loop needs from the instruments
# ---------------------------------------------------------------------------
class Instruments(Protocol):
    """The two DMMs and the heater supply, as the loop sees them."""

    def measure(self) -> PairReading:
        """Trigger both DMMs at the same instant and return their readings."""

    def set_heater_power(self, power_w: float) -> None:
        """Apply a heater power (W) within the configured limits."""

    def heater_off(self) -> float:
        """Heater output to 0 A; the clock time the supply confirmed it (InstrumentError when it could not)."""

    def examine(self, error: InstrumentError) -> None:
        """After the heater is off: attach what the failing instrument says about ``error`` (its error queue)."""

    def reconnect(self) -> None:
        """Reopen connections after a transient fault."""

    def close(self) -> None:
        """Heater off and release the instruments."""


class TemperatureCurve(Protocol):
    def temperature_K(self, resistance_ohm: float) -> float: ...


def _given(target_K: float) -> float | None:
    """A ramp's target as a status value: None until a setpoint was given (every setpoint is above 0 K)."""
    return target_K if target_K > 0.0 else None


def _or(value: float | None, default: float) -> float:
    return default if value is None else value


def daemon_schema(config: DaemonConfig) -> RowSchema:
    """The columns of the daemon's rows for this configuration (its control terms' columns included)."""
    return loop_schema(term_columns(config.control.terms))


# ---------------------------------------------------------------------------
# status
# ---------------------------------------------------------------------------
class _Snapshot(NamedTuple):
    """What the last tick left for the status, assigned at once: readers in other threads see one tick's.

    The :class:`~cryod.service.daemon_status.LoopStatus` is built from it when asked, at most once a tick.
    """

    time_s: float
    state: LoopState | str
    flange_K: float
    ptc_stage_K: float
    heater_w: float
    setpoint_K: float | None
    target_K: float | None
    ramp_K_per_min: float
    last_fault: Fault | None
    control: dict | None
    last_target_K: float | None
    #: (the zone in use counted from 1, its upper temperature in K); None without ``control.zones``.
    zone: tuple[int, float] | None


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
    emit : callable
        Receives each :class:`~cryod.records.columns.Row` (``time_s`` is the
        clock time of the trigger) and each :class:`~cryod.records.columns.Event`,
        in order; must not block.
    watchdog : callable, optional
        Called after every good cycle (systemd WATCHDOG=1, rate-limited by the callee).
    """

    def __init__(self, config: DaemonConfig, instruments: Instruments, flange_curve: TemperatureCurve,
                 ptc_stage_curve: TemperatureCurve, clock: Clock, emit: Callable[[Row | Event], None],
                 watchdog: Callable[[], None] | None = None):
        self.config = config
        self.instruments = instruments
        self.flange_curve = flange_curve
        self.ptc_stage_curve = ptc_stage_curve
        self.clock = clock
        self.emit = emit
        self.watchdog = watchdog or (lambda: None)
        self.period_s = config.loop.period_s
        self.timing = LoopTiming(self.period_s)
        self.regulator = Regulator(config.control, HeaterPowerOutput(config.heater.max_power_w))
        #: The columns of this loop's rows.
        self.schema = daemon_schema(config)
        self.checks = ReadingChecks(config.safety.flange_max_K, config.safety.ptc_stage_max_K,
                                    config.safety.max_repeated_readings)
        self.state = LoopState.HOLDING
        self.heater_w = 0.0                 # the supply was told this last; NaN when it could not be switched off
        self.last_commanded_w = 0.0         # the last power sent to the supply
        self._heater_off_s = math.nan       # when the supply last confirmed the off (clock)
        self._heater_driven = False         # a power went to the supply since it last confirmed the off
        #: The trigger instant of the readings the heater's setting came from (clock, s): the reading watchdog
        #: switches the heater off when a setting outlives ``safety.max_reading_age_s`` (the loop did not run).
        self.heater_reading_s = math.nan
        #: The cycles keep their deadlines (:meth:`_follow_timing`).
        self.on_time = True
        self._last_row_s = -math.inf        # time of the last row emitted
        self.last_fault: Fault | None = None
        self._status: LoopStatus | None = None
        self._publish(_Snapshot(math.nan, LoopState.HOLDING, math.nan, math.nan, self.heater_w, None,
                                config.control.setpoint_K, config.control.ramp_K_per_min, None, None,
                                _given(self.regulator.ramp.target_K), self._zone()))
        # appended by any thread, taken by the loop's (deque's append and popleft are atomic)
        self.commands: collections.deque[Command] = collections.deque()
        self._answers: list[tuple[Command, bool, str]] = []
        self._words = AnswerWords()         # answers taken as a snapshot, put in words off this thread
        self._wording: list[tuple[Command, bool, Future]] = []
        self.exit_code: int | None = None
        self._stop_reason: str | None = None
        self._stop_as: tuple[int, FaultCause] = (ExitCode.OK, FaultCause.STOP_REQUESTED)
        self._outside_fault: Fault | None = None
        #: the fault episode under way and the valid readings the heater waits for
        self.episodes = FaultEpisodes(config.safety, self.period_s)
        self._last_trigger_s: float | None = None
        self._setting_time_s = 0.002       # from the regulator's step to the heater being set (learned)
        self._tick_start_s = 0.0
        self._gc = LoopGarbageCollector()
        #: Why the heater cannot hold the setpoint asked for (None: it can, or none was asked for).
        self.setpoint_warning: str | None = None
        self._setpoint_judged: tuple[tuple, str | None] | None = None
        self.warn_about_setpoint(config.control.setpoint_K)

    def warn_about_setpoint(self, setpoint_K: float | None) -> str | None:
        """Say in the journal when the heater cannot hold ``setpoint_K`` (the controller's model against
        R I_max^2), and keep it for the status; the warning, or None."""
        control, top_W = self.config.control, self.config.heater.max_power_w
        kept = self._setpoint_judged
        if kept is None or kept[0][0] is not control or kept[0][1:] != (setpoint_K, top_W):
            judged = (control, setpoint_K, top_W)
            # the model's steady state costs a third of a millisecond on the loop's thread; a client that puts
            # the same setpoint again (an EPICS or 336 client does, many a second) gets the judgement kept
            self._setpoint_judged = (judged, setpoint_warning(control, setpoint_K, top_W))
        self.setpoint_warning = self._setpoint_judged[1]
        if self.setpoint_warning:
            log.warning("%s", self.setpoint_warning)
        return self.setpoint_warning

    # -- from other threads ---------------------------------------------------
    def submit(self, command: Command) -> Command:
        """Queue a command for the next tick boundary (thread-safe)."""
        self.commands.append(command)
        return command

    def request_stop(self, reason: str, exit_code: int = ExitCode.OK,
                     cause: FaultCause = FaultCause.STOP_REQUESTED) -> None:
        """Stop at the next tick with the heater at 0 W, for ``reason``, with ``exit_code`` (safe from a
        signal handler; a tick that has its readings but not yet its heater setting stops before setting it).
        The first request is kept."""
        if self._stop_reason is None:
            self._stop_as = (exit_code, cause)
            self._stop_reason = reason

    def _stop_as_requested(self, row: Row | None = None) -> None:
        """Stop for the requested reason; ``row``, the readings of a tick cut short by it, is kept, with the
        heater as the stop left it."""
        exit_code, cause = self._stop_as
        self._stop(exit_code, Fault(cause, self._stop_reason), row=row)

    def fail(self, fault: Fault) -> None:
        """A fault found outside the loop (the data log): handled at the next tick like one found in it
        (thread-safe; the first one is kept)."""
        if self._outside_fault is None:
            self._outside_fault = fault

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
                    self._stop(ExitCode.OK, None, f"end of the requested {duration_s:g} s")
                    break
                self.clock.sleep_until(deadline)
                self._tick(deadline)
                self._answer_commands()         # after the tick: the reply's status shows the command's effect
                self.watchdog()                 # every tick that returns: a call that hangs trips it
                if self.exit_code is not None:  # stopped: the stop is the record's last word, not its timing
                    break
                now = self.clock.now()
                missed = int((now - deadline) // self.period_s) if now > deadline + self.period_s else 0
                if missed and self.state.waits_for_readings:
                    # heater off, waiting on instruments whose replies time out: late, but not an overrun
                    # (the streak is about a PC that cannot keep 80 ms while regulating)
                    self.timing.record_cycle_end(0)
                    self.timing.waiting_cycles += 1
                else:
                    self.timing.record_cycle_end(missed)
                if missed and not self.state.waits_for_readings:
                    self._event("overrun", f"cycle ended {(now - deadline) * 1e3:.1f} ms after its deadline "
                                           f"(started {(self._tick_start_s - deadline) * 1e3:.1f} ms late); "
                                           f"{missed} deadline(s) skipped")
                deadline += (missed + 1) * self.period_s
                self._follow_timing(missed)
                if manage_gc and self.exit_code is None:
                    self._gc.collect_if_time(deadline - self.clock.now())
                    self.timing.gc_longest_s = self._gc.longest_s
        except BaseException as error:     # the heater must be off whatever happened
            self._stop(ExitCode.EXCEPTION, Fault(FaultCause.EXCEPTION, f"{type(error).__name__}: {error}"))
            raise
        finally:
            self._answer_commands()
            self._words.close()
            self.regulator.close()
            if manage_gc:
                self._gc.stop()
        return self.exit_code

    def _follow_timing(self, missed: int) -> None:
        """Late cycles with fresh readings are no fault of the cryostat: the loop regulates on. After
        ``loop.overrun_streak_limit`` of them in a row the timing counts as unreliable: the control terms that
        rely on it hold back (the feedforward fades out and pauses its learning) until the cycles have kept
        their deadlines for :data:`ON_TIME_AGAIN_S`; both changes are said in the journal and the record."""
        timing = self.timing
        if self.on_time and missed and timing.overrun_streak >= self.config.loop.overrun_streak_limit:
            self.on_time = False
            self.regulator.follow_timing(False)
            message = (f"{timing.overrun_streak} cycles in a row ended after the next deadline (last: {missed} "
                       f"period(s) late; loop.overrun_streak_limit {self.config.loop.overrun_streak_limit}): "
                       f"regulating on, the feedforward fades out until the cycles keep their deadlines for "
                       f"{ON_TIME_AGAIN_S:g} s")
            log.warning("timing: %s", message)
            self._event("timing", message)
        elif not self.on_time and timing.on_time_streak * self.period_s >= ON_TIME_AGAIN_S:
            self.on_time = True
            self.regulator.follow_timing(True)
            message = f"the cycles kept their deadlines for {ON_TIME_AGAIN_S:g} s: the feedforward fades back in"
            log.info("timing: %s", message)
            self._event("timing", message)

    # -- one tick -----------------------------------------------------------------
    def _tick(self, deadline: float) -> None:
        tick_start = self._tick_start_s = self.clock.now()
        self.timing.record_tick(tick_start - deadline)
        self._apply_commands()
        # a row without a trigger stands for the instant after the commands (a heater-off among them came first)
        commands_done = self.clock.now()
        if self._outside_fault is not None:
            fault, self._outside_fault = self._outside_fault, None
            self._fault(fault, Row(time_s=commands_done, lateness_ms=(tick_start - deadline) * 1e3))
            if self.exit_code is not None:
                return
        if self._stop_reason is not None:
            self._stop_as_requested()
            return
        row = Row(time_s=commands_done, lateness_ms=(tick_start - deadline) * 1e3)
        if self.state is LoopState.RECOVERING and self._maybe_reconnect(tick_start):
            # one slow thing per tick: the readings come at the next one
            if self.exit_code is None:
                row.heater_W = 0.0
                row.state = self.state
                self._finish_row(row)
            return
        try:
            reading = self.instruments.measure()
        except InstrumentError as error:
            self._fault(error, row)
            return
        row.time_s = reading.trigger_time_s
        row.T2_ohm = reading.flange_resistance_ohm
        row.T5_ohm = reading.ptc_stage_resistance_ohm
        row.T2_sample_s = reading.flange_sample_time_s
        row.T5_sample_s = reading.ptc_stage_sample_time_s
        row.trigger_skew_ms = reading.skew_s * 1e3
        fault = self.checks.check_resistances(reading.flange_resistance_ohm, reading.ptc_stage_resistance_ohm)
        if fault is not None:
            self._fault(fault, row)
            return
        try:
            flange_K = float(self.flange_curve.temperature_K(reading.flange_resistance_ohm))
            stage_K = float(self.ptc_stage_curve.temperature_K(reading.ptc_stage_resistance_ohm))
        except ValueError as error:        # OutOfCalibrationRange is a ValueError
            self._fault(Fault(FaultCause.SENSOR_OUT_OF_CALIBRATION, str(error)), row)
            return
        row.T2_K, row.T5_K = flange_K, stage_K
        over = self.checks.check_temperatures(flange_K, stage_K)
        if self.state.waits_for_readings:
            if over is not None:
                self._report_hold(over, flange_K)
            self._count_valid(over is None, reading, row)
            return
        if over is not None:
            self._fault(over, row)
            return
        dt = self.period_s if self._last_trigger_s is None else reading.trigger_time_s - self._last_trigger_s
        self._last_trigger_s = reading.trigger_time_s
        computing_since = self.clock.now()
        step = self.regulator.step(reading.trigger_time_s, dt, flange_K, stage_K,
                                   flange_time_s=_or(reading.flange_sample_time_s, reading.trigger_time_s),
                                   ptc_stage_time_s=_or(reading.ptc_stage_sample_time_s, reading.trigger_time_s),
                                   output_time_s=computing_since + self._setting_time_s)
        if self._stop_reason is not None:        # asked to stop while this tick read: no new setting
            self._stop_as_requested(row)
            return
        age_s = self.clock.now() - reading.trigger_time_s
        if age_s > self.config.safety.max_reading_age_s:
            self._fault(Fault(FaultCause.READINGS_TOO_OLD,
                              f"the readings were {age_s:.3f} s old when the heater was to be set from them "
                              f"(safety.max_reading_age_s {self.config.safety.max_reading_age_s:g})"), row)
            return
        self.last_commanded_w = step.power_w
        self._heater_driven = True
        try:
            self.instruments.set_heater_power(step.power_w)
        except HeaterLimitRefused as error:      # refused before anything was sent: the supply kept its power
            self._fault(error, row)
            return
        except InstrumentError as error:
            if self._stop_reason is not None:    # held off from outside on the way to the stop
                self._stop_as_requested(row)
            else:
                self._fault(error, row)
            return
        row.heater_set_s = self.clock.now()
        self.heater_reading_s = reading.trigger_time_s
        # how long computing and setting take, smoothed: when the next setting will take effect
        self._setting_time_s += 0.1 * (row.heater_set_s - computing_since - self._setting_time_s)
        self.heater_w = row.heater_W = step.power_w
        row.setpoint_K = step.setpoint_K
        row.control = step.columns
        row.state = "closed-limited" if step.limited else self.state
        for name, level, text in step.events:       # what a control term found (the feedforward's learning)
            log.log(level, "%s: %s", name, text)
            self._event(name, text)
        self._finish_row(row)
        self.episodes.ran_clean(reading.trigger_time_s)

    # -- what a tick leaves: its row and the status --------------------------------
    def _emit_row(self, row: Row) -> None:
        self._last_row_s = row.time_s
        self.emit(row)

    def _close_row(self, row: Row, zone_events: bool = False) -> None:
        """The tick's row out, with the time the tick took (and before it, with ``zone_events``, what the
        regulator's zones have to say)."""
        row.cycle_ms = (self.clock.now() - self._tick_start_s) * 1e3
        if zone_events:
            for message in self.regulator.zone_events():     # before the first row the zone's settings made
                self._event("zone", message)
        self._emit_row(row)

    def _finish_row(self, row: Row) -> None:
        """The tick's row out, and the status from it: this tick's readings, heater, setpoint and control."""
        self._close_row(row, zone_events=True)
        closed = self.state is LoopState.CLOSED
        ramp = self.regulator.ramp
        # the target once a setpoint is asked for (also while holding for valid readings), the setpoint in use
        # only while regulating
        aiming = closed or self.regulator.mode is RegulatorMode.CLOSED
        # the state as the row says it (``closed-limited`` while the heater is held at a bound): one word for
        # the record, the status line, ctl status, the web page and the 336
        self._publish(_Snapshot(row.time_s, row.state or self.state, row.T2_K, row.T5_K, self.heater_w,
                                ramp.setpoint_K if closed else None, ramp.target_K if aiming else None,
                                ramp.rate_K_per_min, self.last_fault, row.control, _given(ramp.target_K),
                                self._zone()))

    def _publish_fault_state(self, state: LoopState) -> None:
        """The status after a fault or a stop: the state, the heater, the fault and the zone now; the readings,
        the setpoint and the control of the last tick that published them."""
        last = self._snapshot
        self._publish(last._replace(
            state=state, heater_w=self.heater_w, last_fault=self.last_fault,
            last_target_K=last.last_target_K if last.last_target_K is not None
            else _given(self.regulator.ramp.target_K), zone=self._zone()))

    def _publish(self, snapshot: _Snapshot) -> None:
        """The one place the status changes."""
        self._snapshot = snapshot
        self._status = None

    def _zone(self) -> tuple[int, float] | None:
        """(the zone in use counted from 1, its upper temperature in K), None without zones."""
        zone = self.regulator.zone
        return None if zone is None else (self.regulator.zone_index + 1, zone.upper_K)

    @property
    def status(self) -> LoopStatus:
        """The loop as of its last tick (built when asked, at most once a tick, from the tick's snapshot)."""
        status = self._status
        if status is None:
            snapshot = self._snapshot
            zone = snapshot.zone
            status = LoopStatus(time_s=snapshot.time_s, state=snapshot.state, flange_K=snapshot.flange_K,
                                ptc_stage_K=snapshot.ptc_stage_K, heater_w=snapshot.heater_w,
                                setpoint_K=snapshot.setpoint_K, target_K=snapshot.target_K,
                                ramp_K_per_min=snapshot.ramp_K_per_min,
                                last_fault=str(snapshot.last_fault) if snapshot.last_fault else None,
                                control=snapshot.control, last_target_K=snapshot.last_target_K,
                                zone=zone[0] if zone else None, zone_upper_K=zone[1] if zone else None,
                                timing=self.timing.figures())
            self._status = status
        return status

    # -- start-up and recovery ----------------------------------------------------
    def _count_valid(self, in_range: bool, reading: PairReading, row: Row) -> None:
        """Holding or recovering: heater stays off until enough valid, in-range readings."""
        valid_in_a_row = self.episodes.count_reading(in_range)
        row.heater_W = 0.0
        row.state = self.state
        waiting_for = self.episodes.readings_to_resume()
        if valid_in_a_row >= waiting_for:
            previous = self.state
            self._last_trigger_s = reading.trigger_time_s
            self.state = LoopState(self.regulator.mode)
            if self.state is LoopState.CLOSED and not self.regulator.regulating:
                # start-up, or a setpoint given while the heater was off or manual: close from 0 W, the ramp
                # from T2; after a fault while regulating the terms go on where they were
                self.regulator.close_loop(reading.trigger_time_s, row.T2_K, row.T5_K, present_power_w=0.0)
            note = self.episodes.resumed(reading.trigger_time_s)
            self._event("resumed", f"{waiting_for} valid readings after {previous}; state {self.state}{note}")
        self._finish_row(row)

    def _report_hold(self, over: Fault, flange_K: float) -> None:
        """Say once per hold why the heater stays off: a temperature above its limit (journal and record)."""
        if not self.episodes.hold_to_report():
            return
        key = "safety.flange_max_K" if flange_K > self.checks.flange_max_K else "safety.ptc_stage_max_K"
        message = (f"heater held off while {self.state}: {over.message} ({key}); it stays off until the "
                   f"temperature is below the limit")
        log.warning("%s", message)
        self._event("holding", message)

    def close_loop_now(self) -> None:
        """Regulate from the last readings on, continuing from the heater power now (a command)."""
        status = self.status
        self.regulator.close_loop(status.time_s, status.flange_K, status.ptc_stage_K, present_power_w=self.heater_w)
        self.follow_regulator()

    def follow_regulator(self) -> None:
        """After a command changed the regulator's mode: the loop follows it, unless it is waiting
        for valid readings (it takes the mode up when they come); heater-off acts at once."""
        if not self.state.waits_for_readings:
            self.state = LoopState(self.regulator.mode)
        if self.regulator.mode is RegulatorMode.OFF:       # the tick's own row follows, at 0 W
            failure = self._switch_heater_off()
            if failure is not None:
                self._stop(ExitCode.HEATER_FAULT, failure)

    def _maybe_reconnect(self, now: float) -> bool:
        """Stop when the recovery timed out, else reopen the connections at most once a second.

        Returns
        -------
        bool
            True when this tick stopped the loop or tried a reconnect (no reading this tick).
        """
        if self.episodes.timed_out(now):
            resumes = f" (resumed {self.episodes.resumes} times in between)" if self.episodes.resumes else ""
            self._stop(ExitCode.INSTRUMENTS_LOST, Fault(self.last_fault.cause,
                       f"not recovered within {self.config.safety.recovery_timeout_s:g} s{resumes}: "
                       f"{self.last_fault.message}"))
            return True
        if self.last_fault.cause.reconnect and self.episodes.reconnect_due(now):
            try:
                self.instruments.reconnect()
                self.checks.reset()
            except InstrumentError as error:
                log.warning("reconnect failed: %s", error)
            return True
        return False

    # -- faults ---------------------------------------------------------------------
    def _fault(self, cause: Fault | InstrumentError, row: Row | None = None) -> None:
        """Heater to 0 W first, then find out and record why, then recover or stop.

        ``cause`` is a fault, or an instrument's error: that instrument is asked about it (its
        error queue) only once the heater-off has gone out. ``row`` (the tick's) carries the
        power the supply had from its start; a row at the instant the off was confirmed follows.
        """
        applied_w, driven = self.heater_w, self._heater_driven
        off_failure = self._switch_heater_off()
        if isinstance(cause, InstrumentError):
            self.instruments.examine(cause)
            cause = fault_from_instrument_error(cause)
        fault = cause
        if off_failure is not None:             # the supply keeps what it had: nothing else matters now
            fault = Fault(FaultCause.HEATER_FAULT, f"{off_failure.message}; it happened on {fault}")
        self.episodes.reading_lost()
        state = f"fault:{fault.cause}"
        if row is not None:
            row.heater_W = applied_w
            row.state = state
            self._close_row(row)
        self._heater_off_row(driven, state)
        if self.state is LoopState.RECOVERING and fault.recoverable:
            self.last_fault = fault
            self._publish_fault_state(self.state)
            return
        self._event("fault", str(fault))
        if not fault.recoverable:
            self._stop(fault.exit_code, fault, heater_done=True)
            return
        self.last_fault = fault
        left_s = self.episodes.recovering_from_fault(self.clock.now())
        log.warning("heater off: %s; recovering (%.0f s left of safety.recovery_timeout_s)", fault, left_s)
        self.state = LoopState.RECOVERING
        self._publish_fault_state(LoopState.RECOVERING)

    def _switch_heater_off(self) -> Fault | None:
        """Heater output to 0 A, confirmed by the supply; the heater fault when that failed (a supply out of
        reach keeps its last current)."""
        try:
            self._heater_off_s = self.instruments.heater_off()
        except InstrumentError as error:
            self._heater_off_s = math.nan
            self.heater_w = math.nan
            self._heater_driven = True          # for all that is known
            return Fault(FaultCause.HEATER_FAULT,
                         f"could not switch the heater off ({error}); its state is UNKNOWN: the supply may still "
                         f"deliver the last commanded {self.last_commanded_w:.4g} W: check it at the supply")
        self.heater_w = 0.0
        self._heater_driven = False
        return None

    def _heater_off_row(self, driven: bool, state: str) -> None:
        """After a heater-off of a supply that had been ``driven`` (a power sent since its last confirmed off):
        a row from the instant the supply confirmed the off, with 0 W; not confirmed, from now with an empty
        (unknown) power."""
        confirmed = not math.isnan(self.heater_w)
        if confirmed and not driven:
            return
        at_s = max(self._heater_off_s if confirmed else self.clock.now(), self._last_row_s + HEATER_OFF_ROW_SPACING_S)
        self._emit_row(Row(time_s=at_s, lateness_ms=math.nan, state=state, heater_W=0.0 if confirmed else math.nan,
                           heater_set_s=self._heater_off_s))

    def _stop(self, exit_code: int, fault: Fault | None, reason: str = "", row: Row | None = None,
              heater_done: bool = False) -> None:
        """Heater off, then stop with ``exit_code`` because of ``fault`` (or for ``reason``, no fault);
        ``row``, the readings of a tick the stop cut short before it set the heater, is kept with the setting
        the stop made instead (0 W, set when the supply confirmed the off, as a tick's own setting).

        ``heater_done``: the caller switched the heater off and recorded it already (a fault).
        The first fatal cause is kept: a stop after one changes nothing.
        """
        off_failure = None
        if not heater_done:
            off_failure = self._switch_heater_off()
        if row is not None:
            row.heater_W = self.heater_w
            row.heater_set_s = self._heater_off_s
            row.state = LoopState.STOPPED
            self._close_row(row)
        elif off_failure is not None:           # a row says so; a stop's off is said by its event, the last line
            self._heater_off_row(True, "fault:heater_fault")
        if off_failure is not None and exit_code != ExitCode.HEATER_FAULT:
            exit_code, fault = ExitCode.HEATER_FAULT, Fault(
                FaultCause.HEATER_FAULT, f"{off_failure.message}; on stopping after {fault or reason}")
        if self.exit_code is not None and self.exit_code != ExitCode.OK:
            return
        self.exit_code = exit_code
        if fault is not None:
            self.last_fault = fault
        self._event("stop", f"{fault or reason} (exit {int(exit_code)})")
        level = logging.INFO if exit_code == ExitCode.OK else logging.CRITICAL
        log.log(level, "%s, stopping (exit %d): %s", "heater UNKNOWN" if math.isnan(self.heater_w) else "heater off",
                exit_code, fault or reason)
        self.state = LoopState.STOPPED
        self._publish_fault_state(LoopState.STOPPED)

    def _event(self, kind: str, message: str) -> None:
        self.emit(Event(kind, message))

    # -- commands ----------------------------------------------------------------------
    def _apply_commands(self) -> None:
        """Carry out up to :data:`COMMANDS_PER_TICK` queued commands, in order. A ``heater-off``
        never waits behind others: when one is queued, the commands sent before it are refused as
        superseded (none of them may turn the heater back on after it) and it is carried out now.
        Each command is taken from its client first (:meth:`Command.take`): one its client withdrew
        (it stopped waiting) is journaled as withdrawn and never carried out."""
        commands = self.commands
        if not commands:
            return
        if len(commands) > COMMANDS_PER_TICK:
            last_off = max((index for index, command in enumerate(list(commands)) if command.name == "heater-off"),
                           default=None)
            for _ in range(last_off or 0):
                superseded = commands.popleft()
                if superseded.take():
                    self._record_command(superseded, False, "superseded by a heater-off sent after it")
                else:
                    self._record_withdrawn(superseded)
        carried_out = 0
        while carried_out < COMMANDS_PER_TICK:
            try:
                command = commands.popleft()
            except IndexError:
                return
            if not command.take():
                self._record_withdrawn(command)
                continue
            carried_out += 1
            self._record_command(command, *apply_command(self, command))

    def _record_withdrawn(self, command: Command) -> None:
        """A command whose client stopped waiting before the loop came to it: said, never carried out."""
        sender = f" (by {command.sender})" if command.sender else ""
        message = f"{command.name} withdrawn: its client stopped waiting before the loop came to it; not carried out"
        self._event("command", message + sender)
        log.warning("command %s%s", message, sender)

    def _record_command(self, command: Command, ok: bool, message: str | SnapshotAnswer) -> None:
        """The command's event, journal line and answer (sent after the tick); an answer taken as a snapshot is
        put in words off this thread first (:mod:`cryod.service.answer_words`), and recorded after the tick."""
        if isinstance(message, SnapshotAnswer):
            self._wording.append((command, ok, self._words.put(message)))
            return
        sender = f" (by {command.sender})" if command.sender else ""
        self._event("command", f"{command.name} {'accepted' if ok else 'refused'}: {message}{sender}")
        if command.name != "reload":              # the daemon's reload says it in the journal itself
            log.log(logging.INFO if ok else logging.WARNING, "command %s %s: %s%s", command.name,
                    "accepted" if ok else "refused", reply_for_log(message), sender)
        self._answers.append((command, ok, message))

    def _answer_commands(self) -> None:
        """Answer the commands applied this tick, now that its status is published (those taken as a snapshot
        once in words: recorded now, or refused when the words are not there within :data:`WORDS_WAIT_S`)."""
        wording, self._wording = self._wording, []
        for command, ok, words in wording:
            try:
                text = words.result(WORDS_WAIT_S)
            except FutureTimeout:
                ok, text = False, (f"{command.name} not answered: its words were not ready within "
                                   f"{1e3 * WORDS_WAIT_S:g} ms of the tick (the machine is overloaded); ask again")
            self._record_command(command, ok, text)
        answers, self._answers = self._answers, []
        for command, ok, message in answers:
            command.answer(ok, message)

    def reload_refusal(self, new: DaemonConfig) -> FileFormatError | None:
        """Why ``new`` cannot take over now, at the key of ``new`` it concerns (file, line, key), or None.

        Refused: a change that needs a restart; a setpoint or ramp in use outside the new control
        limits (:meth:`cryod.control.regulator.Regulator.refusal`); and, while the loop reads and acts
        on its readings (closed, manual, off), an over-temperature limit below the temperature now,
        which would stop the daemon at the next reading (exit 3). While it holds the heater off
        waiting for valid readings, such a limit only holds it off longer, as it would at a start.
        """
        restart = self.config.restart_needed_for(new)
        if restart:
            ioc = "; the IOC reads ioc at its own start: systemctl restart cryod-ioc" if "ioc" in restart else ""
            return located_error(new, restart[0], f"changes to {', '.join(restart)} need a restart "
                                                  f"(systemctl restart cryod{ioc})")
        refusal = self.regulator.refusal(new.control)
        if refusal is not None:
            return located_error(new, *refusal)
        if self.state.waits_for_readings or self.state is LoopState.STOPPED:
            return None
        status = self.status
        for key, limit_K, name, now_K in (("safety.flange_max_K", new.safety.flange_max_K, "T2", status.flange_K),
                                          ("safety.ptc_stage_max_K", new.safety.ptc_stage_max_K, "T5",
                                           status.ptc_stage_K)):
            if now_K > limit_K:                 # as ReadingChecks.check_temperatures will see it
                return located_error(new, key, f"{limit_K:g} K is below {name} now, {now_K:.4f} K ({self.state}): "
                                               f"the next reading would stop the daemon (over_temperature, exit 3); "
                                               f"lower the limit once the temperature is below it")
        return None

    def reload(self, new: DaemonConfig) -> str:
        """Apply a validated configuration at this tick boundary, bumplessly, or refuse it (the ``reload`` command).

        Raises
        ------
        CommandRefused
            Sections that need a restart changed, or the values in use would
            break a new limit; the running configuration stays.
        """
        refusal = self.reload_refusal(new)
        if refusal is not None:
            raise CommandRefused(f"kept the running configuration: {refusal}")
        self.regulator.reconfigure(new.control)
        self.config = new
        self.episodes.configure(new.safety)
        self.checks = ReadingChecks(new.safety.flange_max_K, new.safety.ptc_stage_max_K,
                                    new.safety.max_repeated_readings)
        return f"configuration reloaded from {new.source}"
