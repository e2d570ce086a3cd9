"""Keithley 2002 8½-digit multimeter: 4-wire resistance of a Cernox, triggered, fetched.

Every command below is in the Model 2002 User's Manual (document 2002-900-01),
section 3 "IEEE-488 Reference" (sections and pages cited with each setting).
``docs/explanation/instruments.md`` lists them all with the exact strings sent.

The measurement cycle cryod runs every 80 ms:

1. ``:INITiate`` takes the DMM out of idle into the trigger layer (3.22, trigger model pp. 2-12, 3-21);
2. a trigger (GET, ``*TRG``, an EXTernal edge or a Trigger Link pulse) starts
   one device action: one 4-wire resistance reading;
3. after the time the reading takes (:mod:`drivers.keithley2002_timing`)
   ``:FETCh?`` returns it. ``:FETCh?`` does not wait for a new reading:
   it "continues to return the old reading" until there is a new one, so the
   reading number element (``RNUMber``, ``:FORMat:ELEMents``, pp. 3-81, 3-82) is part of
   every reply and a reading whose number has not advanced is refused as stale.

An overflow reads +9.9E37 (status ``O``): :class:`~drivers.errors.OverflowReading`,
never a temperature. ``*IDN?`` is checked at construction; the error queue is
read after configuration and attached to any fault.

Examples
--------
>>> import math
>>> from drivers.clock import VirtualClock
>>> from cryod.model import load_model
>>> from drivers.transports import InProcessTransport
>>> from simulated_hw.cryostat import SimulatedCryostat
>>> from simulated_hw.keithley2002 import Keithley2002Emulator
>>> class Curve:                                   # any R(T) will do here
...     def resistance_ohm(self, temperature_K): return 100 * math.exp(5 / temperature_K ** 0.5)
>>> clock = VirtualClock()
>>> emulator = Keithley2002Emulator(SimulatedCryostat(load_model(), clock, seed=1), "flange", Curve())
>>> dmm = Keithley2002(InProcessTransport(emulator), clock, name="flange DMM")
>>> dmm.configure_four_wire_resistance(FourWireSettings(range_ohm=20e3, nplc=1))
>>> dmm.configure_trigger(TriggerSource.BUS)
>>> dmm.initiate(); dmm.transport.trigger(); trigger_time_s = clock.now()
>>> reading = dmm.fetch_new_reading(trigger_time_s)
>>> 1e3 < reading.resistance_ohm < 1e4, reading.reading_number
(True, 0)
"""

from __future__ import annotations


import enum
import math
import re
from dataclasses import dataclass
from typing import NamedTuple

from drivers.clock import Clock
from drivers.errors import BadReply, InstrumentError, InstrumentTimeout, OverflowReading
from drivers.keithley2002_timing import NORMAL_AUTOZERO_INTERVAL_S, ReadingTiming

#: How much earlier the lower bound of a learned reading time moves after a fetch that got the reading
#: at once (s): small against the 2 ms poll, so a drift of the mains phase is followed.
LINE_SYNC_LEARNING_STEP_S = 0.00025
from drivers.scpi import (Control, ScpiInstrument, count_or_infinite, integer, number, on_off, one_of,
                          parse_bool, parse_count, parse_token)
from drivers.transports.base import Transport

#: Largest reading the 2002 sends for a real value; +9.9E37 is its overflow marker.
OVERFLOW_MARKER = 9.9e37
#: Highest 4-wire range (2 MOhm) and its 5 % over-range (manual 2.4.3: 4-wire up to 2.1 MOhm).
MAXIMUM_FOUR_WIRE_OHM = 2.1e6


class TriggerSource(enum.Enum):
    """Control sources of the trigger (measure) layer (manual 3.22 TRIGger subsystem, ``:SOURce``)."""

    IMMEDIATE = "IMMediate"
    BUS = "BUS"                 # GPIB GET or *TRG
    EXTERNAL = "EXTernal"       # rear EXTERNAL TRIGGER input, falling TTL edge
    TRIGGER_LINK = "TLINk"      # Trigger Link input line (asynchronous)
    TIMER = "TIMer"
    HOLD = "HOLD"
    MANUAL = "MANual"


class FilterType(enum.Enum):
    """Digital filter types (manual 3.18, ``:AVERage:TCONtrol``, p. 3-103)."""

    REPEATING = "REPeat"
    MOVING = "MOVing"


class DataElement(enum.Enum):
    """Elements of a reading string (``:FORMat:ELEMents``, p. 3-81), in the order they are sent."""

    READING = "READing"
    STATUS = "STATus"
    UNITS = "UNITs"
    TIMESTAMP = "TIMEstamp"
    READING_NUMBER = "RNUMber"
    CHANNEL = "CHANnel"


#: What cryod asks for: value, its status (N/O/R) and the reading number (staleness check).
DEFAULT_ELEMENTS = (DataElement.READING, DataElement.STATUS, DataElement.READING_NUMBER)

_SOURCE_TOKENS = {source: source.value for source in TriggerSource}
_ARM_SOURCE_TOKENS = {source: source.value for source in TriggerSource if source is not TriggerSource.TIMER}
#: The fields of a reading string in the exact form the 2002 sends them (:func:`_exact_reply_pattern`).
_EXACT_FIELDS = {
    DataElement.READING: r"(?P<reading>[+-]?(?:\d+\.?\d*|\.\d+)(?:[Ee][+-]?\d+)?)(?P<status>[NR])?(?:OHM4W)?",
    DataElement.TIMESTAMP: r"(?P<timestamp>[+-]?\d+(?:\.\d*)?)(?:SECS)?",
    DataElement.READING_NUMBER: r"(?P<number>[+-]?\d+)(?:RDNG#)?",
    DataElement.CHANNEL: r"[^,]*",
}
_READING_FIELD = re.compile(r"^([+-]?(?:\d+\.?\d*|\.\d+)(?:[Ee][+-]?\d+)?)([NOR])?(OHM4W)?$", re.IGNORECASE)
_INTEGER_FIELD = re.compile(r"^([+-]?\d+)")
_DECIMAL_FIELD = re.compile(r"^([+-]?\d+(?:\.\d*)?)")


def _exact_reply_pattern(order: list[DataElement]) -> re.Pattern | None:
    """One pattern for a whole reading string with the elements in ``order`` as the 2002 sends them: every
    reply it matches, the field by field reading accepts with the same values (an overflow aside, which the
    caller leaves to it); None without a READing element."""
    if DataElement.READING not in order:
        return None
    return re.compile(",".join(_EXACT_FIELDS[element] for element in order))


@dataclass(frozen=True)
class FourWireSettings:
    """How to measure a Cernox: 4-wire resistance settings.

    Parameters
    ----------
    range_ohm : float or None
        Expected largest resistance; the DMM picks the smallest range that holds it.
        None: autorange (not recommended for triggered, timed readings).
    nplc : float
        Integration time in power-line cycles (0.01 to 10).
    digits : int
        Display resolution, 4 to 9 (3½ to 8½ digits); readings carry this resolution.
    filter_count : int
        Readings averaged by the digital filter (1: filter off).
    filter_type : FilterType
        REPEATING (N conversions per triggered reading) or MOVING.
    autozero : bool
        Autozero on.
    autozero_synchronous : bool
        A zero with every reading (SYNChronous) instead of every 200 ms (NORMal).
    offset_compensation : bool
        Offset-compensated ohms (removes thermal EMFs; doubles the conversion time).
    line_sync : bool
        Start every integration at a positive-going zero crossing of the mains.
    """

    range_ohm: float | None = 20e3
    nplc: float = 1.0
    digits: int = 8
    filter_count: int = 1
    filter_type: FilterType = FilterType.REPEATING
    autozero: bool = True
    autozero_synchronous: bool = False
    offset_compensation: bool = False
    line_sync: bool = False


class DmmReading(NamedTuple):
    """One reading as the 2002 sent it.

    A named tuple: immutable, and made many times a second (a frozen dataclass costs four times as much to make).

    Attributes
    ----------
    resistance_ohm : float
        The reading (ohm).
    reading_number : int or None
        The DMM's reading counter (None unless ``RNUMber`` is among the elements).
    status : str or None
        ``N`` normal, ``R`` relative (None unless ``STATus`` is among the elements).
    timestamp_s : float or None
        The DMM's own time stamp (None unless ``TIMEstamp`` is among the elements).
    reply : str
        The reply verbatim.
    sample_time_s : float or None
        Clock time of the middle of the reading's A/D conversions: the instant the
        reading stands for (set by :meth:`Keithley2002.fetch_new_reading`, which
        knows the trigger and whether an autozero came first; None otherwise).
    """

    resistance_ohm: float
    reading_number: int | None
    status: str | None
    timestamp_s: float | None
    reply: str
    sample_time_s: float | None = None


class Keithley2002(ScpiInstrument):
    """Driver of a Keithley 2002 reading one 4-wire resistance.

    Parameters
    ----------
    transport : Transport
        How to reach the DMM.
    clock : Clock
        The injected clock: waits for readings are ``clock.sleep_until`` (free on a VirtualClock).
    name : str
        Its role, e.g. "flange DMM", used in every error.
    line_frequency_hz : float
        Mains frequency in the lab (sets the integration time of one PLC).
    check_identity : bool
        Ask ``*IDN?`` now and refuse another model (:class:`~drivers.errors.IdentityMismatch`).
    fetch_poll_interval_s : float
        Wait between two ``:FETCh?`` while the new reading is not there yet.
    fetch_margin_s : float
        Added to the expected reading time before the first ``:FETCh?``.
    first_reading_margin_s : float
        The first reading after configuration is fetched this long after the longest time
        it can take (:attr:`~drivers.keithley2002_timing.ReadingTiming.worst_case_delay_s`):
        then there is no older reading to tell a too-early ``:FETCh?`` by, the 2002 answers
        it with ``-230`` and nothing, and the controller would wait out its whole timeout.
    """

    expected_model = "MODEL 2002"

    # -- 4-wire resistance (manual 3.18, [SENSe[1]] subsystem) ----------------------
    function = Control(":SENSe:FUNCtion {}", ":SENSe:FUNCtion?",
                       "Measurement function (3.18, :FUNCtion); cryod uses 4-wire ohms only.",
                       one_of({"4-wire resistance": "'FRESistance'"}),
                       parse_token({"4-wire resistance": "FRESistance"}))
    range_ohm = Control(":SENSe:FRESistance:RANGe {}", ":SENSe:FRESistance:RANGe?",
                        "Expected reading in ohm (3.18, :RANGe[:UPPer]); picks the smallest range holding it.",
                        number(0.0, MAXIMUM_FOUR_WIRE_OHM, "ohm"), float)
    autorange = Control(":SENSe:FRESistance:RANGe:AUTO {}", ":SENSe:FRESistance:RANGe:AUTO?",
                        "Autorange on/off (3.18, :RANGe:AUTO).", on_off, parse_bool)
    nplc = Control(":SENSe:FRESistance:NPLCycles {}", ":SENSe:FRESistance:NPLCycles?",
                   "Integration time in power-line cycles (3.18, :NPLCycles, pp. 3-94, 3-95).",
                   number(0.01, 10.0, "PLC"), float)
    digits = Control(":SENSe:FRESistance:DIGits {}", ":SENSe:FRESistance:DIGits?",
                     "Resolution: 4 to 9 for 3½ to 8½ digits (3.18, :DIGits).", integer(4, 9),
                     lambda reply: int(float(reply)))
    filter_enabled = Control(":SENSe:FRESistance:AVERage:STATe {}", ":SENSe:FRESistance:AVERage:STATe?",
                             "Digital filter on/off (3.18, :AVERage[:STATe], p. 3-103).", on_off, parse_bool)
    filter_type = Control(":SENSe:FRESistance:AVERage:TCONtrol {}", ":SENSe:FRESistance:AVERage:TCONtrol?",
                          "Filter type, repeating or moving (3.18, :AVERage:TCONtrol, p. 3-103).",
                          one_of({kind: kind.value for kind in FilterType}),
                          parse_token({kind: kind.value for kind in FilterType}))
    filter_count = Control(":SENSe:FRESistance:AVERage:COUNt {}", ":SENSe:FRESistance:AVERage:COUNt?",
                           "Readings in the filter, 1 to 100 (3.18, :AVERage:COUNt, p. 3-103).", integer(1, 100),
                           lambda reply: int(float(reply)))
    offset_compensation = Control(":SENSe:FRESistance:OCOMpensated {}", ":SENSe:FRESistance:OCOMpensated?",
                                  "Offset-compensated ohms on/off (3.18, :FRESistance:OCOMpensated; "
                                  "resistance configuration, p. 2-28).",
                                  on_off, parse_bool)
    # -- system (manual 3.21) ------------------------------------------------------
    autozero = Control(":SYSTem:AZERo:STATe {}", ":SYSTem:AZERo:STATe?",
                       "Autozero on/off (3.21 SYSTem, :AZERo, p. 3-138).", on_off, parse_bool)
    autozero_synchronous = Control(":SYSTem:AZERo:TYPE {}", ":SYSTem:AZERo:TYPE?",
                                   "Autozero with every reading (SYNChronous) or every 200 ms (NORMal); "
                                   "3.21, :AZERo:TYPE, p. 3-138.",
                                   one_of({True: "SYNChronous", False: "NORMal"}),
                                   parse_token({True: "SYNChronous", False: "NORMal"}))
    line_sync = Control(":SYSTem:LSYNc:STATe {}", ":SYSTem:LSYNc:STATe?",
                        "Line-cycle synchronisation of the integration on/off (3.21 SYSTem, :LSYNc).",
                        on_off, parse_bool)
    # -- trigger model (manual 3.22) -----------------------------------------------------
    arm_source = Control(":ARM:SOURce {}", ":ARM:SOURce?", "Arm layer 1 control source (3.22).",
                         one_of(_ARM_SOURCE_TOKENS), parse_token(_ARM_SOURCE_TOKENS))
    arm_count = Control(":ARM:COUNt {}", ":ARM:COUNt?", "Arm layer 1 count.",
                        count_or_infinite(99999), parse_count)
    scan_source = Control(":ARM:LAYer2:SOURce {}", ":ARM:LAYer2:SOURce?",
                          "Arm layer 2 (scan layer) control source (3.22).",
                          one_of(_SOURCE_TOKENS), parse_token(_SOURCE_TOKENS))
    scan_count = Control(":ARM:LAYer2:COUNt {}", ":ARM:LAYer2:COUNt?", "Arm layer 2 count.",
                         count_or_infinite(99999), parse_count)
    trigger_source = Control(":TRIGger:SOURce {}", ":TRIGger:SOURce?",
                             "Trigger (measure) layer control source (3.22 :SOURce).",
                             one_of(_SOURCE_TOKENS), parse_token(_SOURCE_TOKENS))
    trigger_count = Control(":TRIGger:COUNt {}", ":TRIGger:COUNt?",
                            "Device actions per pass through the trigger layer (3.22 :COUNt).",
                            count_or_infinite(99999), parse_count)
    trigger_delay_s = Control(":TRIGger:DELay {}", ":TRIGger:DELay?",
                              "Delay between trigger and device action in s (3.22 :DELay).",
                              number(0.0, 999999.999, "s"), float)
    trigger_link_protocol = Control(":TRIGger:TCONfigure:PROTocol {}", ":TRIGger:TCONfigure:PROTocol?",
                                    "Trigger Link protocol (3.22 :TCONfigure:PROTocol); cryod uses asynchronous.",
                                    one_of({"asynchronous": "ASYNchronous"}),
                                    parse_token({"asynchronous": "ASYNchronous"}))
    trigger_link_input_line = Control(":TRIGger:TCONfigure:ASYNchronous:ILINe {}",
                                      ":TRIGger:TCONfigure:ASYNchronous:ILINe?",
                                      "Trigger Link input line, 1 to 6 (3.22, :ASYNchronous:ILINe, p. 3-156).",
                                      integer(1, 6), lambda reply: int(float(reply)))
    trigger_link_output_line = Control(":TRIGger:TCONfigure:ASYNchronous:OLINe {}",
                                       ":TRIGger:TCONfigure:ASYNchronous:OLINe?",
                                       "Trigger Link output line, 1 to 6, not the input line "
                                       "(3.22, :ASYNchronous:OLINe, p. 3-156).",
                                       integer(1, 6), lambda reply: int(float(reply)))
    continuous_initiation = Control(":INITiate:CONTinuous {}", ":INITiate:CONTinuous?",
                                    "Continuous initiation on/off (3.22, :INITiate:CONTinuous).", on_off, parse_bool)
    # -- data format (FORMat subsystem, p. 3-81) ---------------------------------------------------------
    data_elements = Control(":FORMat:ELEMents {}", ":FORMat:ELEMents?",
                            "Elements of each reading string (:FORMat:ELEMents, p. 3-81).",
                            lambda elements: ",".join(DataElement(e).value for e in elements),
                            lambda reply: tuple(parse_token({e: e.value for e in DataElement})(part)
                                                for part in reply.split(",")))

    def __init__(self, transport: Transport, clock: Clock, name: str = "Keithley 2002", *,
                 line_frequency_hz: float = 50.0, check_identity: bool = True,
                 fetch_poll_interval_s: float = 0.002, fetch_margin_s: float = 0.0005,
                 first_reading_margin_s: float = 0.005):
        super().__init__(transport, clock, name)
        if line_frequency_hz not in (50.0, 60.0):
            raise ValueError(f"{name}: line frequency must be 50 or 60 Hz, got {line_frequency_hz}")
        self.line_frequency_hz = float(line_frequency_hz)
        self.fetch_poll_interval_s = float(fetch_poll_interval_s)
        self.fetch_margin_s = float(fetch_margin_s)
        self.first_reading_margin_s = float(first_reading_margin_s)
        self.settings = FourWireSettings()
        self.elements: tuple[DataElement, ...] = DEFAULT_ELEMENTS
        self._trigger_delay_s = 0.0
        self._timing_key: tuple | None = None
        self._timing: ReadingTiming | None = None
        self._exact_reply: re.Pattern | None = None
        self._layout_key: tuple | None = None          # reading-string layout, kept until elements change
        self._layout: tuple = ()
        self.last_reading_number: int | None = None
        #: Trigger time of the reading at which the DMM was last seen to take its NORMal autozero.
        self.last_autozero_trigger_s: float | None = None
        #: Bounds (s after the trigger) of when the last reading was ready, for readings without (False)
        #: and with (True) an autozero.
        self._learned_delay_s: dict[bool, tuple[float, float]] = {}
        if check_identity:
            with self.reporting_faults():
                self.check_identity()

    # -- configuration ----------------------------------------------------------------
    def configure_four_wire_resistance(self, settings: FourWireSettings = FourWireSettings(), *,
                                       elements: tuple[DataElement, ...] = DEFAULT_ELEMENTS) -> None:
        """Set up 4-wire resistance readings; reads the error queue afterwards.

        Refuses (``ValueError``, nothing sent) a setting outside the manual's limits.
        """
        cls, label = type(self), self.label
        commands = ["*CLS", cls.function.command("4-wire resistance", label)]
        if settings.range_ohm is None:
            commands.append(cls.autorange.command(True, label))
        else:
            commands += [cls.autorange.command(False, label), cls.range_ohm.command(settings.range_ohm, label)]
        commands += [cls.nplc.command(settings.nplc, label), cls.digits.command(settings.digits, label)]
        filtered = settings.filter_count > 1
        commands.append(cls.filter_enabled.command(filtered, label))
        if filtered:
            commands += [cls.filter_type.command(settings.filter_type, label),
                         cls.filter_count.command(settings.filter_count, label)]
        commands += [cls.offset_compensation.command(settings.offset_compensation, label),
                     cls.autozero.command(settings.autozero, label)]
        if settings.autozero:
            commands.append(cls.autozero_synchronous.command(settings.autozero_synchronous, label))
        commands += [cls.line_sync.command(settings.line_sync, label), ":FORMat:DATA ASCii",
                     cls.data_elements.command(elements, label), ":SYSTem:RNUMber:RESet"]
        with self.reporting_faults():
            for command in commands:
                self.write(command)
            self.check_error_queue("4-wire resistance configuration")
        self.settings = settings
        self.elements = tuple(elements)
        self.last_reading_number = None
        self._learned_delay_s.clear()          # new settings, new timing

    def configure_trigger(self, source: TriggerSource, *, delay_s: float = 0.0,
                          link_input_line: int = 2, link_output_line: int = 1) -> None:
        """One reading per trigger from ``source``, re-armed by :meth:`initiate` each cycle.

        Arm layers pass immediately (count 1); the trigger layer waits for ``source`` (count 1)
        and returns to idle after the reading, so ``:FETCh?`` always finds a finished one.
        For ``TRIGGER_LINK`` the asynchronous protocol with ``link_input_line`` is used.
        """
        if source is TriggerSource.TRIGGER_LINK and link_input_line == link_output_line:
            raise ValueError(f"{self.label}: Trigger Link input and output lines must differ")
        cls, label = type(self), self.label
        commands = [":ABORt", cls.continuous_initiation.command(False, label),
                    cls.arm_source.command(TriggerSource.IMMEDIATE, label), cls.arm_count.command(1, label),
                    cls.scan_source.command(TriggerSource.IMMEDIATE, label), cls.scan_count.command(1, label),
                    cls.trigger_source.command(source, label), cls.trigger_count.command(1, label),
                    cls.trigger_delay_s.command(delay_s, label)]
        if source is TriggerSource.TRIGGER_LINK:
            commands += [cls.trigger_link_protocol.command("asynchronous", label),
                         cls.trigger_link_input_line.command(link_input_line, label),
                         cls.trigger_link_output_line.command(link_output_line, label)]
        with self.reporting_faults():
            for command in commands:
                self.write(command)
            self.check_error_queue("trigger configuration")
        self._trigger_delay_s = float(delay_s)

    @property
    def timing(self) -> ReadingTiming:
        """Timing of a triggered reading with the present configuration (kept until it changes)."""
        s = self.settings
        key = (s, self.line_frequency_hz, self._trigger_delay_s)
        if key != self._timing_key:
            repeat = s.filter_count if (s.filter_count > 1 and s.filter_type is FilterType.REPEATING) else 1
            self._timing = ReadingTiming(nplc=s.nplc, line_frequency_hz=self.line_frequency_hz,
                                         offset_compensation=s.offset_compensation, autozero=s.autozero,
                                         autozero_synchronous=s.autozero_synchronous, line_sync=s.line_sync,
                                         conversions_per_reading=repeat, trigger_delay_s=self._trigger_delay_s)
            self._timing_key = key
        return self._timing

    @property
    def reading_delay_s(self) -> float:
        """Longest time from a trigger to the reading being available (s)."""
        return self.timing.worst_case_delay_s

    @property
    def earliest_reading_delay_s(self) -> float:
        """Shortest time from a trigger to the reading (s): when the first ``:FETCh?`` goes out."""
        return self.timing.earliest_delay_s

    # -- the cycle -----------------------------------------------------------------------
    def initiate(self, confirm: bool = False) -> None:
        """``:INITiate``: out of idle, waiting for the trigger (3.22).

        ``confirm``: follow it with ``:INITiate:CONTinuous?``, whose reply shows
        the DMM has parsed the ``:INITiate`` before it (commands are executed
        in order). Needed before a trigger that does not travel in the
        command stream (a hardware edge), which would otherwise reach a DMM
        that is still parsing and be ignored. A bus trigger (GET, ``*TRG``)
        is queued in order with the commands and needs no confirmation.
        """
        with self.reporting_faults():
            self.write(":INITiate")
            if confirm:
                self.query(":INITiate:CONTinuous?")

    def trigger(self) -> None:
        """A bus trigger to this DMM alone: GPIB GET, or ``*TRG`` where there is none (3.10.13, p. 3-39)."""
        with self.reporting_faults():
            try:
                self.transport.trigger()
            except InstrumentError as error:
                error.relabelled(self.label)
                raise

    def abort(self) -> None:
        """``:ABORt``: back to idle (3.22)."""
        with self.reporting_faults():
            self.write(":ABORt")

    def fetch(self) -> DmmReading:
        """``:FETCh?``: the latest reading, parsed (it may be an old one; see :meth:`fetch_new_reading`)."""
        with self.reporting_faults():
            return self.parse_reading(self.query(":FETCh?"))

    def fetch_new_reading(self, trigger_time_s: float, *, timeout_s: float | None = None) -> DmmReading:
        """The reading of the trigger at ``trigger_time_s``, waiting on the clock until it is there.

        The first ``:FETCh?`` goes out at the earliest time the reading can exist
        (``earliest_reading_delay_s`` after the trigger plus ``fetch_margin_s``; plus
        ``first_reading_margin_s`` for the first reading after configuration), or
        later when the DMM's own timing is known to delay it:

        * a NORMal autozero falls due every 200 ms: the trigger at which a reading
          came one integration late is remembered, and the next reading due for a
          zero is expected one integration later;
        * with line sync the integration waits for the next mains zero crossing,
          a phase the driver cannot know but which changes slowly: each reading's
          delay is remembered (for readings with and without a zero apart) and the
          next first fetch goes one poll interval before it, so a slow drift is
          followed without polling every time.

        A reading whose number has not advanced is the previous one: it is
        fetched again every ``fetch_poll_interval_s`` until ``timeout_s`` (default:
        the transport's timeout) after the latest time the reading could take,
        then :class:`~drivers.errors.InstrumentTimeout`.
        """
        timing = self.timing
        earliest = trigger_time_s + timing.earliest_delay_s + self.fetch_margin_s
        normal_autozero = timing.autozero and not timing.autozero_synchronous
        zero_expected = (normal_autozero and self.last_autozero_trigger_s is not None
                         and trigger_time_s - self.last_autozero_trigger_s >= NORMAL_AUTOZERO_INTERVAL_S)
        first = earliest + (timing.integration_time_s if zero_expected else 0.0)
        learned = self._learned_delay_s.get(zero_expected)
        if timing.line_sync and learned is not None:
            low, high = learned
            first = max(first, trigger_time_s + 0.5 * (low + high))
        first_after_configuration = self.last_reading_number is None
        if first_after_configuration:         # after the longest the reading can take, whatever the DMM did
            first = max(first, trigger_time_s + timing.worst_case_delay_s + self.fetch_margin_s) \
                + self.first_reading_margin_s
        self.clock.sleep_until(first)
        last_miss_s = limit = None
        with self.reporting_faults():
            while True:
                reply = self.query(":FETCh?")
                resistance, reading_number, status, timestamp = self._parsed_reading(reply)
                if reading_number is None or reading_number != self.last_reading_number:
                    self.last_reading_number = reading_number
                    # the first reading after configuration is taken to start a NORMal autozero's 200 ms
                    # (its fetch was late on purpose, so its timing tells nothing)
                    if first_after_configuration:
                        zero_seen = normal_autozero
                        if zero_seen:
                            self.last_autozero_trigger_s = trigger_time_s
                    else:
                        zero_seen = self._learn_timing(trigger_time_s, earliest, zero_expected, normal_autozero,
                                                       timing, last_miss_s)
                    return DmmReading(resistance, reading_number, status, timestamp, reply,
                                      self._sample_time_s(trigger_time_s, zero_seen, timing))
                last_miss_s = self.clock.now()
                if limit is None:            # the reading was not there at once: how long it may still take
                    limit = (trigger_time_s + self.reading_delay_s + self.fetch_margin_s
                             + (self.transport.timeout_s if timeout_s is None else timeout_s))
                if self.clock.now() >= limit:
                    raise InstrumentTimeout(self.label, f"no new reading (number {reading_number} "
                                                        f"again) {self.clock.now() - trigger_time_s:.3f} s "
                                                        f"after the trigger", reply=reply)
                self.clock.sleep_until(self.clock.now() + self.fetch_poll_interval_s)

    def _sample_time_s(self, trigger_time_s: float, zero_seen: bool, timing: ReadingTiming) -> float:
        """The middle of the conversions of the reading triggered at ``trigger_time_s``.

        From the timing model: after the trigger delay and, when a NORMal
        autozero came first, one more integration. With line sync the wait for
        the mains phase is not known in advance: the start is then taken back
        from the learned ready time (the middle of its bounds), less the
        conversions and the processing allowance.
        """
        start = timing.integration_start_s(trigger_time_s, zero_seen)
        learned = self._learned_delay_s.get(zero_seen)
        if timing.line_sync and learned is not None:
            ready = trigger_time_s + 0.5 * (learned[0] + learned[1])
            start = max(start, ready - timing.measurement_span_s - timing.processing_time_s)
        return timing.sample_time_s(start)

    def _learn_timing(self, trigger_time_s: float, earliest: float, zero_expected: bool, normal_autozero: bool,
                      timing: ReadingTiming, last_miss_s: float | None) -> bool:
        """After a reading came: was there an autozero (returned), and when was it ready.

        The reading was ready after the last fetch that missed it and no later
        than the one that got it: those bounds (relative to the trigger) are
        kept, and the next first fetch goes between them (a bisection from
        reading to reading). A first fetch that got it at once lowers the lower
        bound a little, so that a phase drifting earlier is found again.
        """
        now = self.clock.now()
        typical = self._learned_delay_s.get(False)
        plain_ready = trigger_time_s + typical[1] if typical is not None else earliest
        zero_seen = normal_autozero and (zero_expected or now - plain_ready > 0.5 * timing.integration_time_s)
        if zero_seen:
            self.last_autozero_trigger_s = trigger_time_s
        high = now - trigger_time_s
        if last_miss_s is not None:
            low = last_miss_s - trigger_time_s
        else:
            previous = self._learned_delay_s.get(zero_seen)
            low = min(previous[0], high) if previous is not None else high - self.fetch_poll_interval_s
            low -= LINE_SYNC_LEARNING_STEP_S
        self._learned_delay_s[zero_seen] = (low, high)
        return zero_seen

    def parse_reading(self, reply: str) -> DmmReading:
        """A reading string with the configured elements; overflow and garbage are typed errors."""
        return DmmReading(*self._parsed_reading(reply), reply)

    def _parsed_reading(self, reply: str) -> tuple[float, int | None, str | None, float | None]:
        """(resistance, reading number, status, time stamp) of a reading string (see :meth:`parse_reading`).

        A reply in the exact form the 2002 sends (upper case, no spaces) is read with one pattern made for
        the configured elements; any other goes through the field by field checks below, which accept it
        (with the same values) or say what is wrong with it.
        """
        if self._layout_key != self.elements:
            order = [e for e in (DataElement.READING, DataElement.TIMESTAMP, DataElement.READING_NUMBER,
                                 DataElement.CHANNEL) if e in self.elements]
            self._layout = (order, *(order.index(e) if e in order else None
                                     for e in (DataElement.READING, DataElement.TIMESTAMP,
                                               DataElement.READING_NUMBER)))
            self._exact_reply = _exact_reply_pattern(order)
            self._layout_key = self.elements
        exact = self._exact_reply.fullmatch(reply) if self._exact_reply is not None else None
        if exact is not None:
            resistance = float(exact["reading"])
            if resistance < OVERFLOW_MARKER and resistance > -OVERFLOW_MARKER:
                order, _, timestamp_at, number_at = self._layout
                return (resistance, int(exact["number"]) if number_at is not None else None, exact["status"],
                        float(exact["timestamp"]) if timestamp_at is not None else None)
        return self._parsed_field_by_field(reply)

    def _parsed_field_by_field(self, reply: str) -> tuple[float, int | None, str | None, float | None]:
        fields = reply.split(",")
        order, reading_at, timestamp_at, number_at = self._layout
        if len(fields) != len(order):
            raise BadReply(self.label, f"expected {len(order)} elements "
                                       f"({', '.join(e.value for e in order)}), got {len(fields)}", reply=reply)
        if reading_at is None:
            raise BadReply(self.label, "the READing element is not configured", reply=reply)
        match = _READING_FIELD.match(fields[reading_at].strip())
        if not match:
            raise BadReply(self.label, "reading is not a number", reply=reply)
        resistance = float(match.group(1))
        status = match.group(2).upper() if match.group(2) else None
        if status == "O" or abs(resistance) >= OVERFLOW_MARKER or not math.isfinite(resistance):
            raise OverflowReading(self.label, "overflow: resistance above the range "
                                              "(open sensor lead or wrong range)", reply=reply)
        reading_number = None
        if number_at is not None:
            match = _INTEGER_FIELD.match(fields[number_at].strip())
            if not match:
                raise BadReply(self.label, "reading number is not an integer", reply=reply)
            reading_number = int(match.group(1))
        timestamp = None
        if timestamp_at is not None:
            match = _DECIMAL_FIELD.match(fields[timestamp_at].strip())
            if not match:
                raise BadReply(self.label, "time stamp is not a number", reply=reply)
            timestamp = float(match.group(1))
        return resistance, reading_number, status, timestamp

    def shutdown(self) -> None:
        """Back to idle (``:ABORt``) and release the connection; best effort, never raises."""
        try:
            self.write(":ABORt")
        except Exception:  # noqa: BLE001 - shutting down: the link may already be gone
            pass
        self.transport.close()
