"""What every simulated instrument shares: IEEE 488.2 common commands, status model, faults.

A subclass registers its own SCPI headers on ``self.commands`` and gets, from
here, the common commands the three Keithley manuals define (``*IDN?``,
``*RST``, ``*CLS``, ``*ESE``, ``*ESE?``, ``*ESR?``, ``*SRE``, ``*SRE?``,
``*STB?``, ``*OPC``, ``*OPC?``, ``*WAI``, ``*TRG``, ``*TST?``), the status
model of :mod:`simulated_hw.status` with its SCPI commands
(``:STATus:OPERation|QUEStionable|MEASurement[:EVENt]?``, ``:CONDition?``,
``:ENABle``, ``:STATus:PRESet``, ``:STATus:QUEue[:NEXT]?``,
``:STATus:QUEue:CLEar``, ``:SYSTem:ERRor[:NEXT]?``, ``:SYSTem:CLEar``,
``:SYSTem:PRESet``), the bus actions a controller performs without a command
(group execute trigger, selected device clear) and the faults a real
instrument shows (no reply, garbage reply, dropped connection). A subclass drives
the condition registers by overriding :attr:`EmulatedInstrument.operation_condition`,
:attr:`~EmulatedInstrument.questionable_condition` and
:attr:`~EmulatedInstrument.measurement_condition`.

The instruments are emulated here rather than declared to pyvisa-sim: its devices answer
from fixed tables, while these keep a status model and an error queue, take their readings
from the simulated cryostat at the instant of a trigger, and fail on demand, which is what
the real drivers are tested against.

Thread safety: the TCP server calls :meth:`EmulatedInstrument.handle` from
its connection threads; every entry point takes the instrument's lock.

Sessions stand for connections: :meth:`open_session` gives a number, and
:meth:`drop_connections` makes every open session dead, as a cable pulled
out or a server restarted would. A transport that finds its session dead
raises :class:`drivers.errors.ConnectionLost` and recovers by opening a new
one.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from drivers.clock import Clock
from simulated_hw.scpi import (
    PARAMETER_NOT_ALLOWED,
    TRIGGER_IGNORED,
    CommandTable,
    ErrorQueue,
    parse_boolean,
    parse_number,
    scpi_error,
    single_argument,
)
from simulated_hw.status import REGISTER_MASK, RegisterSet, StatusModel


@dataclass
class CommunicationFaults:
    """Faults of the link, injected by tests and ``cryod --simulate`` fault drills.

    Attributes
    ----------
    silent : bool
        The instrument executes commands but never answers a query (the
        controller times out), as a hung or powered-down instrument would.
    garbage_replies : int
        The next this many replies are replaced by line noise.
    reply_delay_s : float
        Each reply is sent this long after its query, in real time (the instruments served over TCP: a
        slow adapter or a busy bus; the virtual clock of the in-process bench does not see it).
    """

    silent: bool = False
    garbage_replies: int = 0
    #: Each reply is sent this long after its query (s, real time): a slow adapter, a busy bus.
    reply_delay_s: float = 0.0


#: What a garbage reply looks like: bytes of a corrupted transfer, no number in it.
GARBAGE_REPLY = "#\x7f?@K:;\x1b~"


class EmulatedInstrument:
    """Base of the simulated instruments.

    Parameters
    ----------
    clock : Clock
        The clock the instrument lives on (the simulated cryostat's).
    identity : str
        The ``*IDN?`` reply.
    """

    def __init__(self, clock: Clock, identity: str):
        self.clock = clock
        self.identity = identity
        self.status = StatusModel(operation=self._condition_reader("operation_condition"),
                                  questionable=self._condition_reader("questionable_condition"),
                                  measurement=self._condition_reader("measurement_condition"))
        self.errors = self.status.errors
        self.faults = CommunicationFaults()
        self.commands = CommandTable()
        self._lock = threading.RLock()
        self._generation = 0
        self._register_common_commands()

    def _condition_reader(self, name: str):
        """What reads the condition register ``name`` of this instrument; None where it is this class's constant 0."""
        condition = getattr(type(self), name)
        if condition is getattr(EmulatedInstrument, name):
            return None
        return condition.fget.__get__(self)

    # -- connections ---------------------------------------------------------
    def open_session(self) -> int:
        """A new connection; returns its token for :meth:`session_alive`."""
        with self._lock:
            return self._generation

    def session_alive(self, session: int) -> bool:
        return session == self._generation

    def drop_connections(self) -> None:
        """Fault: every open connection is lost (the next I/O on it fails)."""
        with self._lock:
            self._generation += 1

    # -- faults --------------------------------------------------------------
    def inject_no_reply(self, silent: bool = True) -> None:
        """Fault: stop (or resume) answering queries; the controller times out."""
        with self._lock:
            self.faults.silent = silent

    def inject_reply_delay(self, delay_s: float = 0.0) -> None:
        """Fault: each reply comes ``delay_s`` late (real time; 0 ends it)."""
        with self._lock:
            self.faults.reply_delay_s = float(delay_s)

    def inject_garbage(self, count: int = 1) -> None:
        """Fault: the next ``count`` replies are garbage."""
        with self._lock:
            self.faults.garbage_replies += count

    # -- the controller's side -------------------------------------------------
    def handle(self, message: str) -> str | None:
        """Execute one program message; its reply, or None when there is nothing to send."""
        with self._lock:
            self.update()
            sampled = self.status.changing_registers
            for register in sampled:
                register.sample()
            reply = self.commands.execute(message, self.errors)
            for register in sampled:
                register.sample()
            if reply is None or self.faults.silent:
                return None
            if self.faults.garbage_replies > 0:
                self.faults.garbage_replies -= 1
                return GARBAGE_REPLY
            delay_s = self.faults.reply_delay_s
        if delay_s > 0.0:
            time.sleep(delay_s)
        return reply

    def group_execute_trigger(self, time_s: float | None = None) -> None:
        """The GPIB GET interface message addressed to this instrument (same effect as ``*TRG``).

        ``time_s``: the instant of the GET when one message reaches several listeners
        (they all see the same instant); now by default.
        """
        with self._lock:
            self.update()
            self.bus_trigger(time_s)

    def selected_device_clear(self) -> None:
        """The GPIB SDC interface message: clear the input and output buffers."""
        with self._lock:
            self.update()

    # -- hooks for subclasses ----------------------------------------------------
    def update(self) -> None:
        """Bring the instrument's state to the clock's now (called on every entry)."""

    def reset(self) -> None:
        """``*RST``: the instrument's reset defaults."""

    def bus_trigger(self, time_s: float | None = None) -> None:
        """React to GET or ``*TRG`` (at ``time_s``, default now); the default ignores it with -211."""
        self.errors.push(*TRIGGER_IGNORED)

    @property
    def operation_condition(self) -> int:
        """The operation condition register (``:STATus:OPERation:CONDition?``); 0 here."""
        return 0

    @property
    def questionable_condition(self) -> int:
        """The questionable condition register; 0 here (no questionable state is simulated)."""
        return 0

    @property
    def measurement_condition(self) -> int:
        """The measurement condition register; 0 here."""
        return 0

    # -- common commands and the status model --------------------------------------
    def _register_common_commands(self) -> None:
        add = self.commands.add
        status = self.status
        add("*IDN", query=lambda args: self.identity)
        add("*RST", write=self._no_parameter(self.reset))
        add("*CLS", write=self._no_parameter(status.clear))
        add("*ESE", write=lambda args: setattr(status, "event_status_enable", _register_value(args, 255)),
            query=lambda args: f"{status.event_status_enable:d}")
        add("*ESR", query=lambda args: f"{status.read_event_status():d}")
        add("*SRE", write=lambda args: setattr(status, "service_request_enable", _register_value(args, 255) & ~64),
            query=lambda args: f"{status.service_request_enable:d}")
        add("*STB", query=lambda args: f"{status.status_byte(self.commands.pending_replies > 0):d}")
        add("*OPC", write=self._no_parameter(status.operation_complete), query=lambda args: "1")
        add("*WAI", write=self._no_parameter(lambda: None))
        add("*TRG", write=self._no_parameter(self.bus_trigger))
        add("*TST", query=lambda args: "0")
        add(":SYSTem:ERRor[:NEXT]", query=lambda args: ErrorQueue.format(self.errors.pop()))
        add(":SYSTem:CLEar", write=self._no_parameter(self.errors.clear))
        add(":SYSTem:PRESet", write=self._no_parameter(self.reset))
        add(":STATus:QUEue[:NEXT]", query=lambda args: ErrorQueue.format(self.errors.pop()))
        add(":STATus:QUEue:CLEar", write=self._no_parameter(self.errors.clear))
        add(":STATus:PRESet", write=self._no_parameter(status.preset))
        for name, register in status.registers.items():
            node = {"OPERATION": ":STATus:OPERation", "QUESTIONABLE": ":STATus:QUEStionable",
                    "MEASUREMENT": ":STATus:MEASurement"}[name]
            self._register_set_commands(node, register)

    def _register_set_commands(self, node: str, register: RegisterSet) -> None:
        """The event, condition and enable headers of one SCPI register set, under ``node``."""
        add = self.commands.add
        add(node + "[:EVENt]", query=lambda args: f"{register.read_event():d}")
        add(node + ":CONDition", query=lambda args: f"{register.condition:d}")
        add(node + ":ENABle", write=lambda args: setattr(register, "enable", _register_value(args, 65535)
                                                         & REGISTER_MASK),
            query=lambda args: f"{register.enable:d}")

    @staticmethod
    def _no_parameter(action):
        """A write handler for a command without parameters (``-108`` if one is given)."""
        def write(arguments: list[str]) -> None:
            if arguments:
                raise scpi_error(PARAMETER_NOT_ALLOWED)
            action()
        return write


def _register_value(arguments: list[str], maximum: int) -> int:
    """A register mask ``<NRf>``, 0 to ``maximum``, rounded to an integer."""
    return int(round(parse_number(arguments, 0, maximum)))


def on_off(value: bool) -> str:
    """How Keithley instruments answer a boolean query: ``1`` or ``0``."""
    return "1" if value else "0"


def boolean_setting(instrument: object, attribute: str):
    """(write, query) handlers for a boolean setting stored on ``instrument``."""
    def write(arguments: list[str]) -> None:
        setattr(instrument, attribute, parse_boolean(arguments))

    def query(arguments: list[str]) -> str:
        return on_off(getattr(instrument, attribute))

    return write, query


__all__ = ["EmulatedInstrument", "CommunicationFaults", "GARBAGE_REPLY", "on_off",
           "boolean_setting", "single_argument"]
