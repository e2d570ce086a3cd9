"""A simulated Keithley 2002 reading one Cernox of the simulated cryostat in 4-wire ohms.

It accepts the Model 2002's SCPI for what cryod uses (the table in
``docs/explanation/instruments.md``): 4-wire resistance configuration, autozero, line
sync, the filter, the trigger model (arm layers, trigger layer with BUS,
EXTernal, TLINk, IMMediate, TIMer, HOLD and MANual sources, counts, delay),
``:INITiate``, ``:ABORt``, ``:FETCh?`` and ``:FORMat:ELEMents``. Any other
header is answered as an unknown one is: ``-113,"Undefined header"`` in the
error queue. Parameters outside the manual's ranges give ``-222``; a
function other than 4-wire ohms (which is all this DMM is wired to) gives
``-224``.

Readings (Model 2002 User's Manual, trigger model pp. 2-12 and 3-21, and section
3.22 "TRIGger subsystem"): each trigger event starts one device action; the
reading is the Cernox resistance (through the calibration curve) at the
trigger instant, averaged over the span of the A/D conversions the settings
ask for (see :mod:`drivers.keithley2002_timing`), and becomes available to
``:FETCh?`` only when the real instrument would have it. Until then
``:FETCh?`` returns the previous reading, as the manual describes (it "does
not trigger a measurement ... continues to return the old reading");
before any reading it reports ``-230,"Data corrupt or stale"`` and sends
nothing. A trigger during a device action is ignored with ``-211,"Trigger
ignored"`` ("Any triggers received while the instrument is processing a
reading will be ignored", ``:NPLCycles``, p. 3-94).

Averaging note: the simulated cryostat gives the mean temperature over the
window; the reading is R(mean T). The difference to mean R(T) is
R''(T) var(T) / 2, below 1e-5 relative for the PTC stage's 0.12 K line over
one power-line cycle, far under the sensor noise.

Output format (``:FORMat:ELEMents``, p. 3-81 and Figure 3-18): elements in
the order reading (with status N/O/R and unit ``OHM4W`` attached), time
stamp, reading number, channel, separated by commas; an overflow reads
+9.9E37 with status O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple, Protocol

from drivers.keithley2002_timing import NORMAL_AUTOZERO_INTERVAL_S, ReadingTiming
from simulated_hw.cryostat import SimulatedCryostat
from simulated_hw.instrument import EmulatedInstrument, boolean_setting, on_off
from simulated_hw.scpi import (DATA_CORRUPT_OR_STALE, ILLEGAL_PARAMETER_VALUE, INIT_IGNORED,
                               SETTINGS_CONFLICT, TRIGGER_IGNORED, parse_choice, parse_number,
                               scpi_error, short_form, single_argument)

#: 4-wire ranges of the 2002 (ohm); each reads up to 105 % of full scale.
FOUR_WIRE_RANGES_OHM = (20.0, 200.0, 2e3, 2e4, 2e5, 2e6)
OVERRANGE_FACTOR = 1.05
#: Instants this close count as equal (rounding of sums of times).
TIME_TOLERANCE_S = 1e-9

TRIGGER_SOURCES = ("IMMediate", "BUS", "EXTernal", "TLINk", "TIMer", "HOLD", "MANual")
ARM_SOURCES = ("IMMediate", "BUS", "EXTernal", "TLINk", "HOLD", "MANual", "RTClock")
SCAN_SOURCES = ("IMMediate", "BUS", "EXTernal", "TLINk", "TIMer", "HOLD", "MANual")
ELEMENTS = ("READing", "CHANnel", "RNUMber", "UNITs", "TIMEstamp", "STATus")
THERMOMETERS = ("flange", "ptc_stage")
#: Trigger sources that start device actions without an event (:meth:`Keithley2002Emulator.update`).
FREE_RUNNING_SOURCES = ("IMMEDIATE", "TIMER")


class ResistanceCurve(Protocol):
    """What the simulated DMM needs of a calibration: R(T) (cryod.thermometry's curves fit)."""

    def resistance_ohm(self, temperature_K: float) -> float: ...


class _Reading(NamedTuple):
    value_ohm: float
    overflow: bool
    number: int
    timestamp_s: float


@dataclass(slots=True)
class _PendingAction:
    trigger_time_s: float
    start_s: float
    ready_time_s: float
    value_ohm: float | None = None


class Keithley2002Emulator(EmulatedInstrument):
    """A Model 2002 whose 4-wire input is one thermometer of a simulated cryostat.

    Parameters
    ----------
    cryostat : SimulatedCryostat
        The cryostat (and, through it, the clock).
    thermometer : {'flange', 'ptc_stage'}
        Which Cernox this DMM is wired to (T2 or T5).
    calibration : object with ``resistance_ohm(temperature_K)``
        The sensor's R(T).
    line_frequency_hz : float
        Mains frequency (sets the integration time of an NPLC).
    serial_number : str
        Serial number in the ``*IDN?`` reply.
    processing_time_s : float
        Time from the end of the conversions to an available reading.
    """

    def __init__(self, cryostat: SimulatedCryostat, thermometer: str, calibration: ResistanceCurve, *,
                 line_frequency_hz: float = 50.0, serial_number: str = "0000001",
                 processing_time_s: float | None = None):
        if thermometer not in THERMOMETERS:
            raise ValueError(f"thermometer must be one of {THERMOMETERS}, got {thermometer!r}")
        super().__init__(cryostat.clock, f"KEITHLEY INSTRUMENTS INC.,MODEL 2002,{serial_number},B02  /A02")
        self.cryostat = cryostat
        self.thermometer = thermometer
        self.calibration = calibration
        self.line_frequency_hz = float(line_frequency_hz)
        self.processing_time_s = processing_time_s
        self.overflow_readings = 0
        self._register_commands()
        self.reset()
        self._reading_counter = 0
        self._last_autozero_s = -math.inf
        self._timing_key: tuple | None = None
        self._timing: ReadingTiming | None = None
        self._fixed_range_format_key: tuple | None = None
        self._fixed_range_format = None

    # -- faults ------------------------------------------------------------------
    def inject_overflow(self, count: int = 1) -> None:
        """Fault: the next ``count`` readings overflow (+9.9E37), as an open sensor lead would."""
        with self._lock:
            self.overflow_readings += count

    # -- settings ------------------------------------------------------------------
    def reset(self) -> None:
        """``*RST`` defaults that matter here (``*RST`` column of the manual's command tables)."""
        self.function = "FRESISTANCE"
        self.range_ohm = FOUR_WIRE_RANGES_OHM[-1]
        self.autorange = True
        self.nplc = 1.0
        self.digits = 8
        self.filter_enabled = False
        self.filter_type = "MOVING"
        self.filter_count = 10
        self.offset_compensation = False
        self.autozero = True
        self.autozero_type = "NORMAL"
        self.line_sync = False
        self.arm_source = "IMMEDIATE"
        self.arm_count = 1.0
        self.scan_source = "IMMEDIATE"
        self.scan_count = 1.0
        self.trigger_source = "IMMEDIATE"
        self.trigger_count = 1.0
        self.trigger_delay_s = 0.0
        self.trigger_timer_s = 0.1
        self.link_protocol = "ASYNCHRONOUS"
        self.link_input_line = 2
        self.link_output_line = 1
        self.continuous = False
        self.elements = ("READING",)
        self._abort()
        self._readings: list[_Reading] = []
        self._moving: list[float] = []

    def _abort(self) -> None:
        self.initiated = False
        self._actions_done = 0
        self._pending: _PendingAction | None = None
        self._layer_entered_s = self._timer_due_s = self.clock.now()

    def _register_commands(self) -> None:
        add = self.commands.add
        sense = "[:SENSe[1]]:FRESistance"
        add("[:SENSe[1]]:FUNCtion", write=self._set_function,
            query=lambda args: '"FRES"')
        add(sense + ":RANGe[:UPPer]", write=self._set_range, query=lambda args: f"{self.range_ohm:g}")
        self._add_boolean(sense + ":RANGe:AUTO", "autorange")
        add(sense + ":NPLCycles", write=self._setter("nplc", 0.01, 10.0, 1.0),
            query=lambda args: f"{self.nplc:g}")
        add(sense + ":DIGits", write=self._set_digits, query=lambda args: f"{self.digits:g}")
        self._add_boolean(sense + ":AVERage[:STATe]", "filter_enabled")
        add(sense + ":AVERage:TCONtrol",
            write=lambda args: setattr(self, "filter_type", parse_choice(args, ("REPeat", "MOVing"))),
            query=lambda args: self.filter_type[:3])
        add(sense + ":AVERage:COUNt", write=self._setter("filter_count", 1, 100, 10, integer=True),
            query=lambda args: f"{self.filter_count:d}")
        self._add_boolean(sense + ":OCOMpensated", "offset_compensation")
        self._add_boolean(":SYSTem:AZERo[:STATe]", "autozero")
        add(":SYSTem:AZERo:TYPE",
            write=lambda args: setattr(self, "autozero_type", parse_choice(args, ("NORMal", "SYNChronous"))),
            query=lambda args: short_form({"NORMAL": "NORMal", "SYNCHRONOUS": "SYNChronous"}[self.autozero_type]))
        self._add_boolean(":SYSTem:LSYNc[:STATe]", "line_sync")
        add(":SYSTem:RNUMber:RESet", write=lambda args: setattr(self, "_reading_counter", 0))
        # trigger model (manual section 3.22)
        self._add_layer(":ARM[:SEQuence[1]][:LAYer[1]]", "arm", ARM_SOURCES)
        self._add_layer(":ARM[:SEQuence[1]]:LAYer2", "scan", SCAN_SOURCES)
        self._add_layer(":TRIGger[:SEQuence[1]]", "trigger", TRIGGER_SOURCES)
        add(":TRIGger[:SEQuence[1]]:DELay", write=self._setter("trigger_delay_s", 0.0, 999999.999, 0.0),
            query=lambda args: f"{self.trigger_delay_s:g}")
        add(":TRIGger[:SEQuence[1]]:TIMer", write=self._setter("trigger_timer_s", 0.001, 999999.999, 0.1),
            query=lambda args: f"{self.trigger_timer_s:g}")
        add(":TRIGger[:SEQuence[1]]:TCONfigure:PROTocol",
            write=lambda args: setattr(self, "link_protocol", parse_choice(args, ("ASYNchronous",))),
            query=lambda args: "ASYN")
        add(":TRIGger[:SEQuence[1]]:TCONfigure:ASYNchronous:ILINe",
            write=self._setter("link_input_line", 1, 6, 2, integer=True),
            query=lambda args: f"{self.link_input_line:d}")
        add(":TRIGger[:SEQuence[1]]:TCONfigure:ASYNchronous:OLINe",
            write=self._setter("link_output_line", 1, 6, 1, integer=True),
            query=lambda args: f"{self.link_output_line:d}")
        add(":INITiate[:IMMediate]", write=self._initiate)
        add(":INITiate:CONTinuous", write=self._set_continuous, query=lambda args: on_off(self.continuous))
        add(":ABORt", write=lambda args: self._abort_and_rearm())
        add(":FETCh", query=self._fetch)
        add(":FORMat[:DATA]", write=lambda args: parse_choice(args, ("ASCii",)), query=lambda args: "ASC")
        add(":FORMat:ELEMents", write=self._set_elements, query=lambda args: ",".join(
            short_form(next(e for e in ELEMENTS if e.upper() == element)) for element in self.elements))

    def _add_boolean(self, pattern: str, attribute: str) -> None:
        write, query = boolean_setting(self, attribute)
        self.commands.add(pattern, write=write, query=query)

    def _add_layer(self, prefix: str, layer: str, sources: tuple[str, ...]) -> None:
        def set_source(args: list[str]) -> None:
            setattr(self, f"{layer}_source", parse_choice(args, sources))

        def get_source(args: list[str]) -> str:
            value = getattr(self, f"{layer}_source")
            return short_form(next(s for s in sources if s.upper() == value))

        def get_count(args: list[str]) -> str:
            count = getattr(self, f"{layer}_count")
            return "INF" if math.isinf(count) else f"{count:g}"

        self.commands.add(prefix + ":SOURce", write=set_source, query=get_source)
        self.commands.add(prefix + ":COUNt", write=self._setter(f"{layer}_count", 1, 99999, 1, integer=True,
                                                                allow_infinity=True), query=get_count)

    def _setter(self, attribute: str, low: float, high: float, default: float, *,
                integer: bool = False, allow_infinity: bool = False):
        def write(args: list[str]) -> None:
            value = parse_number(args, low, high, default=default, allow_infinity=allow_infinity)
            if integer and not math.isinf(value):
                value = int(round(value))
            setattr(self, attribute, value)
        return write

    def _set_function(self, args: list[str]) -> None:
        text = single_argument(args).strip().strip("'\"").upper()
        if text not in ("FRES", "FRESISTANCE"):
            raise scpi_error(ILLEGAL_PARAMETER_VALUE)
        self.function = "FRESISTANCE"

    def _set_range(self, args: list[str]) -> None:
        expected = parse_number(args, 0.0, FOUR_WIRE_RANGES_OHM[-1] * OVERRANGE_FACTOR,
                                default=FOUR_WIRE_RANGES_OHM[-1])
        self.range_ohm = next(r for r in FOUR_WIRE_RANGES_OHM if expected <= r * OVERRANGE_FACTOR)
        self.autorange = False

    def _set_digits(self, args: list[str]) -> None:
        self.digits = int(round(parse_number(args, 4, 9, default=8)))

    def _set_elements(self, args: list[str]) -> None:
        if not args:
            raise scpi_error(ILLEGAL_PARAMETER_VALUE)
        chosen = {parse_choice([arg], ELEMENTS) for arg in args}
        self.elements = tuple(e.upper() for e in ELEMENTS if e.upper() in chosen)

    def _set_continuous(self, args: list[str]) -> None:
        write, _ = boolean_setting(self, "continuous")
        write(args)
        if self.continuous and not self.initiated:
            self._enter_trigger_layer()

    # -- timing ---------------------------------------------------------------------
    @property
    def timing(self) -> ReadingTiming:
        """The timing the present settings imply (kept until a setting changes)."""
        key = (self.nplc, self.line_frequency_hz, self.offset_compensation, self.autozero, self.autozero_type,
               self.line_sync, self.filter_enabled, self.filter_type, self.filter_count, self.trigger_delay_s,
               self.processing_time_s)
        if key != self._timing_key:
            repeat = self.filter_count if (self.filter_enabled and self.filter_type == "REPEAT") else 1
            extra = {} if self.processing_time_s is None else {"processing_time_s": self.processing_time_s}
            self._timing = ReadingTiming(nplc=self.nplc, line_frequency_hz=self.line_frequency_hz,
                                         offset_compensation=self.offset_compensation, autozero=self.autozero,
                                         autozero_synchronous=self.autozero_type == "SYNCHRONOUS",
                                         line_sync=self.line_sync, conversions_per_reading=repeat,
                                         trigger_delay_s=self.trigger_delay_s, **extra)
            self._timing_key = key
        return self._timing

    # -- the trigger model -------------------------------------------------------------
    def _initiate(self, args: list[str]) -> None:
        if self.initiated or self.continuous:
            raise scpi_error(INIT_IGNORED)
        self._enter_trigger_layer()

    def _abort_and_rearm(self) -> None:
        self._abort()
        if self.continuous:
            self._enter_trigger_layer()

    def _enter_trigger_layer(self) -> None:
        """Out of idle through the arm layers (emulated: IMMediate arm sources only)."""
        self._abort()
        if self.arm_source != "IMMEDIATE" or self.scan_source != "IMMEDIATE":
            # Arm events other than IMMediate are not emulated: operation holds in the arm layer.
            self.errors.push(*SETTINGS_CONFLICT)
            return
        self.initiated = True
        self._layer_entered_s = self._timer_due_s = self.clock.now()

    def _start_action(self, trigger_time_s: float) -> None:
        timing = self.timing
        needs_zero = trigger_time_s - self._last_autozero_s >= NORMAL_AUTOZERO_INTERVAL_S
        start = timing.integration_start_s(trigger_time_s, needs_zero)
        if self.autozero and needs_zero:
            self._last_autozero_s = trigger_time_s
        self._pending = _PendingAction(trigger_time_s, start, timing.ready_time_s(start))
        self._timer_due_s = trigger_time_s + self.trigger_timer_s
        if start <= self.clock.now() + TIME_TOLERANCE_S:
            self._measure(self._pending, timing)     # taken at the trigger instant, not when fetched

    def _event(self, kind: str, line: int | None = None, time_s: float | None = None) -> None:
        """A trigger event of ``kind`` ('BUS', 'EXTERNAL', 'TLINK') arriving at ``time_s`` (default now)."""
        self.update()
        now = self.clock.now() if time_s is None else min(time_s, self.clock.now())
        matches = (self.trigger_source == kind
                   and (kind != "TLINK" or line == self.link_input_line))
        if not self.initiated or not matches:
            if kind == "BUS":
                self.errors.push(*TRIGGER_IGNORED)
            return
        if self._pending is not None:
            self.errors.push(*TRIGGER_IGNORED)
            return
        self._start_action(now)

    def bus_trigger(self, time_s: float | None = None) -> None:
        self._event("BUS", time_s=time_s)

    def group_execute_trigger(self, time_s: float | None = None) -> None:
        """The GPIB GET addressed to this DMM: a BUS trigger event (which brings the DMM to now first)."""
        with self._lock:
            self._event("BUS", time_s=time_s)

    def external_trigger(self, time_s: float | None = None) -> None:
        """A falling TTL edge on the rear EXTERNAL TRIGGER input (manual section 2.7.6)."""
        with self._lock:
            self._event("EXTERNAL", time_s=time_s)

    def trigger_link_pulse(self, line: int, time_s: float | None = None) -> None:
        """An input trigger pulse on Trigger Link line ``line`` (1 to 6, "Trigger Link", p. 2-53)."""
        with self._lock:
            self._event("TLINK", line, time_s)

    def update(self) -> None:
        """Complete device actions whose time has come; start free-running ones (IMM, TIM)."""
        if not self.initiated or (self._pending is None and self.trigger_source not in FREE_RUNNING_SOURCES):
            return                           # idle, or waiting for a trigger event: nothing happens by itself
        now = self.clock.now()
        while self.initiated:
            if self._pending is None:
                next_start = self._free_running_trigger_time()
                if next_start is None or next_start > now + TIME_TOLERANCE_S:
                    return
                self._start_action(next_start)
            if self._pending.start_s > now + TIME_TOLERANCE_S:
                return
            self._measure(self._pending)
            if self._pending.ready_time_s > now + TIME_TOLERANCE_S:
                return
            self._complete(self._pending)

    def _free_running_trigger_time(self) -> float | None:
        """Next trigger of a free-running source: IMMediate back to back, TIMer on its interval."""
        if self.trigger_source == "IMMEDIATE":
            return self._layer_entered_s
        if self.trigger_source == "TIMER":
            due = self._timer_due_s
            while due < self._layer_entered_s:   # timer events during a device action are lost
                due += self.trigger_timer_s
            return due
        return None

    def _measure(self, action: _PendingAction, timing: ReadingTiming | None = None) -> None:
        """Take the reading of ``action`` (once), averaged over its conversions (``timing``: the settings', if known)."""
        if action.value_ohm is not None:
            return
        span_s = (timing or self.timing).signal_span_s
        flange_K, stage_K = self.cryostat.read_mean_temperatures(action.start_s, span_s)
        temperature_K = flange_K if self.thermometer == "flange" else stage_K
        resistance = float(self.calibration.resistance_ohm(temperature_K))
        if self.filter_enabled and self.filter_type == "MOVING":
            self._moving = (self._moving + [resistance])[-self.filter_count:]
            resistance = sum(self._moving) / len(self._moving)
        action.value_ohm = resistance

    def _complete(self, action: _PendingAction) -> None:
        value = action.value_ohm
        full_scale = self._active_range(value) * OVERRANGE_FACTOR
        overflow = value > full_scale or self.overflow_readings > 0
        if self.overflow_readings > 0:
            self.overflow_readings -= 1
        self._readings = [_Reading(value, overflow, self._reading_counter, action.trigger_time_s)]
        self._reading_counter += 1
        self._pending = None
        self._actions_done += 1
        self._layer_entered_s = action.ready_time_s
        if self._actions_done >= self.trigger_count:
            # trigger count done: back up through the arm layers (count 1) to idle
            self.initiated = False
            if self.continuous:
                self.initiated = True
                self._actions_done = 0
                self._timer_due_s = action.ready_time_s

    def _active_range(self, value_ohm: float) -> float:
        if not self.autorange:
            return self.range_ohm
        return next((r for r in FOUR_WIRE_RANGES_OHM if value_ohm <= r), FOUR_WIRE_RANGES_OHM[-1])

    # -- output ------------------------------------------------------------------
    def _fetch(self, args: list[str]) -> str | None:
        if not self._readings:
            raise scpi_error(DATA_CORRUPT_OR_STALE)
        return self._format(self._readings[-1])

    def _format(self, reading: _Reading) -> str:
        if not self.autorange and "READING" in self.elements and not reading.overflow:
            key = (self.elements, self.digits, self.range_ohm)
            if key != self._fixed_range_format_key:
                self._fixed_range_format = self._fixed_range_formatter()
                self._fixed_range_format_key = key
            return self._fixed_range_format(reading)
        units = "UNITS" in self.elements
        fields = []
        if "READING" in self.elements:
            if reading.overflow:
                text = "+9.9E37"
            else:
                resolution = self._active_range(reading.value_ohm) / (2 * 10 ** (self.digits - 1))
                value = round(reading.value_ohm / resolution) * resolution
                text = f"{value:+.{self.digits - 1}E}"
            if "STATUS" in self.elements:
                text += "O" if reading.overflow else "N"
            fields.append(text + ("OHM4W" if units else ""))
        if "TIMESTAMP" in self.elements:
            fields.append(f"{reading.timestamp_s:+012.6f}" + ("SECS" if units else ""))
        if "RNUMBER" in self.elements:
            fields.append(f"{reading.number:+06d}" + ("RDNG#" if units else ""))
        if "CHANNEL" in self.elements:
            fields.append("00" + ("INTCHAN" if units else ""))
        return ",".join(fields)

    def _fixed_range_formatter(self):
        """:meth:`_format` of a reading that is not an overflow on a fixed range, for the present elements and
        resolution: the same text, the choices made once (every reading of a configured DMM goes through it)."""
        units = "UNITS" in self.elements
        resolution = self.range_ohm / (2 * 10 ** (self.digits - 1))
        # one printf-style pattern for the whole reply (the same conversions as the format specs of _format): the
        # value, then the time stamp and the reading number where they are among the elements
        with_time, with_number = "TIMESTAMP" in self.elements, "RNUMBER" in self.elements
        fields = [f"%+.{self.digits - 1}E" + ("N" if "STATUS" in self.elements else "") + ("OHM4W" if units else "")]
        if with_time:
            fields.append("%+012.6f" + ("SECS" if units else ""))
        if with_number:
            fields.append("%+06d" + ("RDNG#" if units else ""))
        if "CHANNEL" in self.elements:
            fields.append("00" + ("INTCHAN" if units else ""))
        pattern = ",".join(fields)

        def format_reading(reading: _Reading) -> str:
            value = round(reading.value_ohm / resolution) * resolution
            if with_number:
                if with_time:
                    return pattern % (value, reading.timestamp_s, reading.number)
                return pattern % (value, reading.number)
            return pattern % ((value, reading.timestamp_s) if with_time else (value,))
        return format_reading

