"""Ways to trigger the two thermometer DMMs at the same instant, and the fallback.

Each strategy knows which trigger source the DMMs must wait for and fires
one trigger, returning when it happened (clock time) and the skew between
the flange DMM's and the PTC-stage DMM's trigger. Bus triggers are time
stamped when the command has been sent (a GPIB write returns once the
listeners accepted it), the hardware edge just before it is made:

* :class:`GpibGroupTrigger` — one GPIB Group Execute Trigger to several
  listeners (IEEE 488.1 GET, sent by PyVISA's ``GPIBInterface.group_execute_trigger``):
  both DMMs see the same bus message; skew 0.
* :class:`PrologixGroupTrigger` — the Prologix controller's ``++trg a b``:
  one GET to the listed addresses; skew 0.
* :class:`HardwareTrigger` — an edge on a wire both DMMs share (EXTERNAL
  TRIGGER inputs, or one Trigger Link line); skew 0.
* :class:`SequentialTrigger` — the fallback: ``*TRG`` to each in turn; the
  skew is measured on the clock (time after the second write minus time
  after the first: a GPIB write returns once the device accepted the bytes).
"""

from __future__ import annotations

from typing import Any, NamedTuple, Protocol, Sequence

from pyvisa.errors import VisaIOError

from drivers.clock import Clock
from drivers.errors import ConnectionLost
from drivers.keithley2002 import TriggerSource
from drivers.transports.base import Transport
from drivers.transports.prologix import PrologixAdapter
from drivers.trigger_lines import TriggerOutput


class TriggerEvent(NamedTuple):
    """When a pair trigger happened.

    A named tuple: immutable, and made many times a second (a frozen dataclass costs four times as much to make).

    Attributes
    ----------
    time_s : float
        Clock time of the (flange DMM's) trigger.
    skew_s : float
        PTC-stage DMM's trigger time minus the flange DMM's (0 for a simultaneous trigger).
    """

    time_s: float
    skew_s: float


class PairTrigger(Protocol):
    """A way to trigger both DMMs."""

    #: Trigger source both DMMs must wait for.
    dmm_trigger_source: TriggerSource
    #: Trigger Link input line (used when the source is TRIGGER_LINK).
    link_input_line: int
    #: True when the trigger reaches the DMMs outside their command stream (a hardware
    #: edge), so each ``:INITiate`` must be confirmed parsed before firing.
    bypasses_command_stream: bool

    def fire(self) -> TriggerEvent: ...


class GpibInterface(Protocol):
    """PyVISA's ``GPIBInterface`` (``GPIB0::INTFC``), or a simulated bus with the same method."""

    def group_execute_trigger(self, *resources: Any) -> Any: ...


class AddressedTransport(Transport, Protocol):
    """A transport with the ``resource`` a GPIB interface addresses (PyVISA's ``GPIBInstrument``, or a simulated
    bus's own)."""

    resource: Any


class GpibGroupTrigger:
    """One GET on a GPIB card to both DMMs (``GPIBInterface.group_execute_trigger``).

    Parameters
    ----------
    interface : GpibInterface
        The board, e.g. ``resource_manager().open_resource("GPIB0::INTFC")``.
    transports : sequence of AddressedTransport
        (flange, PTC stage) transports; their ``resource`` is what the interface addresses.
    clock : Clock
        Time stamps.
    """

    dmm_trigger_source = TriggerSource.BUS
    link_input_line = 1
    bypasses_command_stream = False      # GET and *TRG are queued in order with commands

    def __init__(self, interface: GpibInterface, transports: Sequence[AddressedTransport], clock: Clock):
        self.interface = interface
        self.resources = [transport.resource for transport in transports]
        self.clock = clock

    def fire(self) -> TriggerEvent:
        try:
            self.interface.group_execute_trigger(*self.resources)
        except (VisaIOError, OSError) as error:
            raise ConnectionLost("GPIB interface", f"group execute trigger failed: {error}") from error
        return TriggerEvent(self.clock.now(), 0.0)      # the GET is on the bus when the call returns


class PrologixGroupTrigger:
    """One GET from a Prologix controller to both DMMs (``++trg <flange> <stage>``)."""

    dmm_trigger_source = TriggerSource.BUS
    link_input_line = 1
    bypasses_command_stream = False      # GET and *TRG are queued in order with commands

    def __init__(self, adapter: PrologixAdapter, primary_addresses: Sequence[int], clock: Clock):
        self.adapter = adapter
        self.primary_addresses = tuple(primary_addresses)
        self.clock = clock

    def fire(self) -> TriggerEvent:
        self.adapter.trigger(self.primary_addresses)
        return TriggerEvent(self.clock.now(), 0.0)      # sent; the controller issues the GET at once


class HardwareTrigger:
    """An edge on a wire both DMMs share.

    Parameters
    ----------
    output : TriggerOutput
        What makes the edge (e.g. :class:`drivers.trigger_lines.SerialControlLine`).
    clock : Clock
        Time stamps.
    dmm_input : TriggerSource
        EXTERNAL (rear BNC inputs, teed) or TRIGGER_LINK (a Trigger Link line).
    link_input_line : int
        The Trigger Link line the edge is on (TRIGGER_LINK only).
    """

    #: The edge reaches the DMMs outside their command stream: :class:`ThermometerPair`
    #: confirms each ``:INITiate`` was parsed before firing.
    bypasses_command_stream = True

    def __init__(self, output: TriggerOutput, clock: Clock, *,
                 dmm_input: TriggerSource = TriggerSource.EXTERNAL, link_input_line: int = 1):
        if dmm_input not in (TriggerSource.EXTERNAL, TriggerSource.TRIGGER_LINK):
            raise ValueError(f"a hardware trigger reaches EXTERNAL or TRIGGER_LINK inputs, not {dmm_input}")
        self.output = output
        self.clock = clock
        self.dmm_trigger_source: TriggerSource = dmm_input
        self.link_input_line = link_input_line

    def fire(self) -> TriggerEvent:
        time_s = self.clock.now()
        self.output.pulse()
        return TriggerEvent(time_s, 0.0)


class SequentialTrigger:
    """The fallback: ``*TRG`` to the flange DMM, then to the PTC-stage DMM; skew measured."""

    dmm_trigger_source = TriggerSource.BUS
    link_input_line = 1
    bypasses_command_stream = False      # GET and *TRG are queued in order with commands

    def __init__(self, transports: Sequence[Transport], clock: Clock):
        if len(transports) != 2:
            raise ValueError("a thermometer pair has two DMMs")
        self.transports = tuple(transports)
        self.clock = clock

    def fire(self) -> TriggerEvent:
        times = []
        for transport in self.transports:
            transport.write("*TRG")
            times.append(self.clock.now())
        return TriggerEvent(times[0], times[1] - times[0])
