"""What the SCPI drivers share: declarative settings, identity, the error queue, fault reports.

A setting is declared once, on the driver class, with everything about it in
one place — the command that sets it, the query that reads it back, its
validation with units, its documentation::

    nplc = Control(":SENSe:FRESistance:NPLCycles {}", ":SENSe:FRESistance:NPLCycles?",
                   "Integration time (power-line cycles).", number(0.01, 10, "PLC"), float)

``dmm.nplc = 2`` writes ``:SENSe:FRESistance:NPLCycles 2``; ``dmm.nplc``
queries and parses. A value outside the limits is refused with a
``ValueError`` naming the setting — never clipped to the nearest limit —
and nothing is sent.

Examples
--------
>>> from drivers.clock import VirtualClock
>>> class Recorder:
...     name = "recorder"
...     def __init__(self): self.sent = []
...     def write(self, command): self.sent.append(command)
...     def query(self, command): self.sent.append(command); return "2"
>>> class Meter(ScpiInstrument):
...     nplc = Control(":NPLC {}", ":NPLC?", "Integration (PLC).", number(0.01, 10, "PLC"), float)
>>> meter = Meter(Recorder(), VirtualClock(), "meter")
>>> meter.nplc = 2
>>> meter.nplc
2.0
>>> meter.transport.sent
[':NPLC 2', ':NPLC?']
>>> meter.nplc = 20
Traceback (most recent call last):
...
ValueError: meter (recorder): nplc = 20 PLC refused: allowed 0.01 to 10 PLC
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Literal, Mapping

from drivers.clock import Clock
from drivers.errors import (
    BadReply,
    ConnectionLost,
    IdentityMismatch,
    InstrumentError,
    InstrumentReportedError,
    QueueEntry,
)
from drivers.transports.base import Transport

#: More entries than an instrument's queue holds (the 2002's holds 10): a safety stop.
ERROR_QUEUE_READ_LIMIT = 32

_QUEUE_ENTRY = re.compile(r'^\s*([+-]?\d+)\s*,\s*"(.*)"\s*$')


# ---------------------------------------------------------------------------
# validators: value -> SCPI token, or ValueError
# ---------------------------------------------------------------------------
class Refused(ValueError):
    """A value outside a setting's limits (re-raised with the setting's name)."""


def number(low: float, high: float, unit: str, text: str = "{:g}") -> Callable[[Any], str]:
    """A number within ``[low, high]`` (inclusive), formatted with ``text``."""
    def validate(value: Any) -> str:
        value = float(value)
        if not math.isfinite(value) or not low <= value <= high:
            raise Refused(f"{value:g} {unit} refused: allowed {low:g} to {high:g} {unit}")
        return text.format(value)
    return validate


def integer(low: int, high: int, unit: str = "") -> Callable[[Any], str]:
    """An integer within ``[low, high]``."""
    def validate(value: Any) -> str:
        if isinstance(value, bool) or int(value) != value or not low <= int(value) <= high:
            raise Refused(f"{value} {unit} refused: allowed integers {low} to {high} {unit}".replace("  ", " "))
        return str(int(value))
    return validate


def count_or_infinite(high: int) -> Callable[[Any], str]:
    """A count of 1 to ``high``, or ``math.inf`` (``INFinite``)."""
    finite = integer(1, high)

    def validate(value: Any) -> str:
        return "INFinite" if value == math.inf else finite(value)
    return validate


def one_of(tokens: Mapping[Any, str]) -> Callable[[Any], str]:
    """One of the keys of ``tokens``; sends its token."""
    def validate(value: Any) -> str:
        if value not in tokens:
            raise Refused(f"{value!r} refused: allowed {', '.join(repr(k) for k in tokens)}")
        return tokens[value]
    return validate


def on_off(value: Any) -> str:
    """A boolean as ``ON``/``OFF``."""
    if not isinstance(value, bool):
        raise Refused(f"{value!r} refused: allowed True or False")
    return "ON" if value else "OFF"


# ---------------------------------------------------------------------------
# parsers: reply -> value
# ---------------------------------------------------------------------------
def parse_bool(reply: str) -> bool:
    text = reply.strip().upper()
    if text in ("1", "ON"):
        return True
    if text in ("0", "OFF"):
        return False
    raise ValueError(f"not a boolean: {reply!r}")


def parse_token(tokens: Mapping[Any, str]) -> Callable[[str], Any]:
    """Reverse of :func:`one_of`: a reply in short or long form back to the key."""
    def parse(reply: str) -> Any:
        text = reply.strip().strip("'\"").upper()
        for key, token in tokens.items():
            long_form = token.upper()
            short = "".join(c for c in token if c.isupper() or c.isdigit())
            if text in (long_form, short):
                return key
        raise ValueError(f"unexpected reply {reply!r}")
    return parse


def parse_count(reply: str) -> float:
    text = reply.strip().upper()
    return math.inf if text.startswith("INF") else int(float(text))


class Control:
    """One SCPI setting of an instrument (a data descriptor on the driver class).

    Parameters
    ----------
    set_command : str
        Command with ``{}`` where the validated token goes.
    query_command : str or None
        Query that reads the setting back (None: write-only).
    doc : str
        What the setting is, with units.
    validate : callable
        Value to SCPI token; raises ``ValueError`` to refuse.
    parse : callable
        Reply text to value.
    """

    def __init__(self, set_command: str, query_command: str | None, doc: str,
                 validate: Callable[[Any], str], parse: Callable[[str], Any] = str):
        self.set_command = set_command
        self.query_command = query_command
        self.validate = validate
        self.parse = parse
        self.__doc__ = doc
        self.name = ""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def command(self, value: Any, instrument_name: str = "") -> str:
        """The command that sets ``value`` (``ValueError`` if refused); sends nothing."""
        try:
            return self.set_command.format(self.validate(value))
        except Refused as refusal:
            raise ValueError(f"{instrument_name}: {self.name} = {refusal}") from None

    def command_for(self, value: Any, instrument: "ScpiInstrument") -> str:
        """:meth:`command` for ``instrument``, whose label a refusal names (asked for only then: every setting of a
        cycle goes through here)."""
        try:
            return self.set_command.format(self.validate(value))
        except Refused:
            return self.command(value, instrument.label)

    def __get__(self, instrument: "ScpiInstrument | None", owner: type | None = None) -> Any:
        if instrument is None:
            return self
        if self.query_command is None:
            raise AttributeError(f"{self.name} cannot be read back")
        reply = instrument.query(self.query_command)
        try:
            return self.parse(reply)
        except ValueError:
            raise BadReply(instrument.label, f"{self.name}: cannot read the reply to {self.query_command}",
                           reply=reply) from None

    def __set__(self, instrument: "ScpiInstrument", value: Any) -> None:
        instrument.write(self.command(value, instrument.label))


# ---------------------------------------------------------------------------
# the instrument
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Identity:
    """The four fields of an IEEE 488.2 ``*IDN?`` reply."""

    manufacturer: str
    model: str
    serial_number: str
    firmware: str


def parse_identity(reply: str) -> Identity:
    fields = [field.strip() for field in reply.split(",")]
    if len(fields) != 4:
        raise ValueError(f"*IDN? reply has {len(fields)} fields, not 4")
    return Identity(*fields)


class ScpiInstrument:
    """Base of the SCPI drivers: talks through a transport, names itself in every error.

    Parameters
    ----------
    transport : Transport
        How to reach the instrument.
    clock : Clock
        The injected clock (waits for readings, time stamps).
    name : str
        The instrument's role in the lab ("flange DMM"), used in error messages.
    """

    #: The ``*IDN?`` model field this driver expects (e.g. ``MODEL 2002``); empty: any.
    expected_model: ClassVar[str] = ""
    #: Read the error queue as soon as an operation fails (True), or leave it to
    #: :meth:`~drivers.errors.InstrumentError.examine` (False: for a caller that acts first,
    #: as the daemon switches the heater off before it asks a failing DMM anything).
    examines_faults_at_once: bool = True

    def __init__(self, transport: Transport, clock: Clock, name: str):
        self.transport = transport
        self.clock = clock
        self.name = name
        self.identity: Identity | None = None

    @property
    def label(self) -> str:
        """Name and address, for messages."""
        where = getattr(self.transport, "name", "")
        return f"{self.name} ({where})" if where and where != self.name else self.name

    # -- I/O --------------------------------------------------------------------------
    def write(self, command: str) -> None:
        try:
            self.transport.write(command)
        except InstrumentError as error:
            error.relabelled(self.label)
            raise

    def query(self, command: str) -> str:
        try:
            return self.transport.query(command)
        except InstrumentError as error:
            error.relabelled(self.label)
            raise

    def query_number(self, command: str, what: str) -> float:
        """A numeric reply; :class:`BadReply` naming ``what`` if it is not a number."""
        reply = self.query(command)
        try:
            value = float(reply)
        except ValueError:
            raise BadReply(self.label, f"{what}: reply to {command} is not a number", reply=reply) from None
        if not math.isfinite(value):
            raise BadReply(self.label, f"{what}: reply to {command} is not finite", reply=reply)
        return value

    # -- identity and errors ------------------------------------------------------------
    def check_identity(self) -> Identity:
        """Ask ``*IDN?``; :class:`IdentityMismatch` unless it is the expected model."""
        reply = self.query("*IDN?")
        try:
            identity = parse_identity(reply)
        except ValueError as problem:
            raise IdentityMismatch(self.label, f"not a {self.expected_model}: {problem}", reply=reply) from None
        if self.expected_model and identity.model.upper() != self.expected_model.upper():
            raise IdentityMismatch(self.label, f"expected a {self.expected_model}, found {identity.model}",
                                   reply=reply)
        self.identity = identity
        return identity

    def read_error_queue(self) -> tuple[QueueEntry, ...]:
        """Empty the instrument's error queue (``:SYSTem:ERRor?`` until ``0,"No error"``)."""
        entries: list[QueueEntry] = []
        for _ in range(ERROR_QUEUE_READ_LIMIT):
            reply = self.query(":SYSTem:ERRor?")
            match = _QUEUE_ENTRY.match(reply)
            if not match:
                raise BadReply(self.label, "error queue entry is not <code>,\"<message>\"", reply=reply)
            code = int(match.group(1))
            if code == 0:
                break
            entries.append((code, match.group(2)))
        return tuple(entries)

    def check_error_queue(self, after: str) -> None:
        """:class:`InstrumentReportedError` if the error queue holds anything (``after``: what was done)."""
        entries = self.read_error_queue()
        if entries:
            raise InstrumentReportedError(self.label, f"instrument reported errors after {after}",
                                          error_queue=entries)

    def examine_fault(self, error: InstrumentError) -> None:
        """Attach what the error queue holds to ``error`` (best effort; the link may be down)."""
        if isinstance(error, ConnectionLost) or error.error_queue:
            return
        try:
            error.error_queue = self.read_error_queue()
        except InstrumentError:
            pass

    def reporting_faults(self) -> "_ReportingFaults":
        """Around driver operations: a fault leaves with the instrument's error queue attached (or, when
        :attr:`examines_faults_at_once` is False, with the means to attach it later).

        (A plain class rather than a generator context manager: it wraps every
        operation of every cycle; it holds nothing between uses, so one serves every operation.)
        """
        context = self.__dict__.get("_reporting_faults")
        if context is None:
            context = self._reporting_faults = _ReportingFaults(self)
        return context


class _ReportingFaults:
    """Context of :meth:`ScpiInstrument.reporting_faults`."""

    __slots__ = ("instrument",)

    def __init__(self, instrument: ScpiInstrument):
        self.instrument = instrument

    def __enter__(self) -> None:
        return None

    def __exit__(self, kind, error, traceback) -> Literal[False]:
        if error is None or isinstance(error, InstrumentReportedError) or not isinstance(error, InstrumentError):
            return False
        if self.instrument.examines_faults_at_once:
            self.instrument.examine_fault(error)
        else:
            error.examine_later(self.instrument.examine_fault)
        return False
