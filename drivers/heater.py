"""One interface for the loop to the heater: power in watts, read back, off.

A heater supply here is a current source into the flange heater. The loop
asks for a power; the driver sends the current I = sqrt(P / R) for the
configured heater resistance R. Limits refuse, they never clip:

* a power needing more than ``max_current_a`` (100 mA by default), or more
  voltage than the compliance, raises :class:`~drivers.errors.HeaterLimitRefused`
  (a ``ValueError``) before anything is sent: the output stays as it was;
* a negative, infinite or NaN power is refused the same way (the heater only heats).

Safe by construction: the output is off until the first accepted power;
it goes to 0 A and off on :meth:`HeaterSupply.close`, on leaving a ``with``
block, and whenever an operation inside the driver fails for any reason
other than a refused request — first, before anything else is asked of the
supply; the error then carries the supply's error queue if the supply
answered the off. If the connection itself dropped, the driver reopens it
once to send the supply to 0 A: a supply left alone keeps its last current.
The supply reaching voltage compliance (an open heater) is such a failure:
:class:`~drivers.errors.HeaterCompliance`. An output that does not come on
(interlock, output enable) is :class:`~drivers.errors.HeaterRefused`.

The off is one program message, 0 A, output off and the output state read
back (:meth:`HeaterSupply.write_output_off`): the supply's reply confirms
it, at an instant the driver notes (:attr:`HeaterSupply.off_confirmed_s`).
An off that could not be confirmed leaves the output's state unknown
(:attr:`HeaterSupply.off_failure`); :meth:`HeaterSupply.output_off` then
says so at once instead of waiting on the supply again, and
:meth:`HeaterSupply.close` tries once more.

The largest power and the current for a power follow one rounding rule,
:mod:`drivers.heater_limits`, which the daemon's regulator uses too: the
heater's own maximum is always a power the driver accepts.
"""

from __future__ import annotations

import abc
import math
import numbers
from dataclasses import dataclass
from typing import ClassVar, Literal, NamedTuple

from drivers.clock import Clock
from drivers.errors import (
    BadReply,
    ConnectionLost,
    HeaterCompliance,
    HeaterLimitRefused,
    HeaterOutputOff,
    HeaterRefused,
    InstrumentError,
)
from drivers.heater_limits import current_for_power_a, largest_power_w
from drivers.scpi import Control, ScpiInstrument, on_off, parse_bool
from drivers.transports.base import Transport


class HeaterSetting(NamedTuple):
    """What :meth:`HeaterSupply.set_power_w` applied.

    A named tuple: immutable, and made many times a second (a frozen dataclass costs four times as much to make).

    Attributes
    ----------
    requested_power_w : float
        The power asked for (W).
    current_a : float
        The current sent to the supply (A).
    power_w : float
        I^2 R with the configured resistance (W): the request, to the supply's resolution.
    """

    requested_power_w: float
    current_a: float
    power_w: float


@dataclass(frozen=True)
class HeaterReadback:
    """The supply's state as read back.

    Attributes
    ----------
    current_a : float
        Output current (A): measured (2400) or the programmed value (6221).
    voltage_v : float
        Output voltage (V): measured (2400) or I R with the configured resistance (6221).
    power_w : float
        V I (W): the delivered power when the voltage is measured.
    voltage_measured : bool
        True when the supply measured the voltage (so the power is known, not assumed).
    """

    current_a: float
    voltage_v: float
    power_w: float
    voltage_measured: bool


#: Whether the output is on (both Keithley supplies: OUTPut subsystem).
OUTPUT_STATE_QUERY = ":OUTPut:STATe?"


class HeaterSupply(ScpiInstrument, abc.ABC):
    """Base of the heater supply drivers.

    Parameters
    ----------
    transport : Transport
        How to reach the supply.
    clock : Clock
        The injected clock.
    heater_resistance_ohm : float
        Resistance of the flange heater (ohm), as measured in the lab.
    max_current_a : float
        Hard limit of the heater current (A); 0.1 by default.
    voltage_compliance_v : float
        Voltage limit of the supply (V); must allow ``max_current_a`` through the heater.
    name : str
        Its role in error messages.
    check_identity : bool
        Ask ``*IDN?`` now and refuse another model.
    verify_each_setting : bool
        After every current change, ask the supply whether it is in compliance (one query).
    """

    #: The supply's own largest current and voltage limits (A, V), per model.
    supply_max_current_a: float = 0.0
    supply_compliance_range_v: tuple[float, float] = (0.0, 0.0)
    #: The output current setting (A), ``:SOURce:CURRent`` with the model's range: each model's class defines it.
    source_current_a: ClassVar[Control]

    def __init__(self, transport: Transport, clock: Clock, heater_resistance_ohm: float, *,
                 max_current_a: float = 0.1, voltage_compliance_v: float = 10.0, name: str = "heater supply",
                 check_identity: bool = True, verify_each_setting: bool = True):
        super().__init__(transport, clock, name)
        if not (math.isfinite(heater_resistance_ohm) and heater_resistance_ohm > 0.0):
            raise ValueError(f"{name}: heater resistance must be positive, got {heater_resistance_ohm}")
        if not 0.0 < max_current_a <= self.supply_max_current_a:
            raise ValueError(f"{name}: max current {max_current_a} A outside (0, {self.supply_max_current_a}] A "
                             f"of the {self.expected_model}")
        low, high = self.supply_compliance_range_v
        if not low <= voltage_compliance_v <= high:
            raise ValueError(f"{name}: voltage compliance {voltage_compliance_v} V outside {low} to {high} V")
        if heater_resistance_ohm * max_current_a > voltage_compliance_v:
            raise ValueError(f"{name}: {max_current_a} A through {heater_resistance_ohm} ohm needs "
                             f"{heater_resistance_ohm * max_current_a:.3g} V, above the {voltage_compliance_v:g} V "
                             "compliance: raise the compliance or lower the maximum current")
        self.heater_resistance_ohm = float(heater_resistance_ohm)
        self.max_current_a = float(max_current_a)
        self.voltage_compliance_v = float(voltage_compliance_v)
        self.verify_each_setting = verify_each_setting
        self.output_is_on = False
        self.current_a = 0.0
        #: Clock time the supply last confirmed 0 A and output off, with nothing sent since (None: not so).
        self.off_confirmed_s: float | None = None
        #: Why the last off could not be confirmed (None: it was, or the supply has been driven since).
        self.off_failure: InstrumentError | None = None
        with self.safe_on_fault():
            if check_identity:
                self.check_identity()
            self.configure()

    def configure(self) -> None:
        """Configure the supply (:meth:`configure_source`: output off, 0 A) and record that state.

        Called at connect and again after a reconnect, when the supply may have been reset.
        """
        self.configure_source()
        self.output_is_on = False
        self.current_a = 0.0
        self.off_confirmed_s = None             # off as configured, but not read back: output_off() asks
        self.off_failure = None

    # -- limits ------------------------------------------------------------------------
    @property
    def max_power_w(self) -> float:
        """Largest power the limits allow (W): R I_max^2, to the rounding of :func:`~drivers.heater_limits.largest_power_w`."""
        return largest_power_w(self.heater_resistance_ohm, self.max_current_a)

    def current_for_power(self, power_w: float) -> float:
        """I = sqrt(P / R) for ``power_w``; :class:`HeaterLimitRefused` outside the limits."""
        if type(power_w) is not float and (isinstance(power_w, bool) or not isinstance(power_w, numbers.Real)) \
                or not math.isfinite(power_w):
            raise HeaterLimitRefused(self.label, f"heater power {power_w!r} W refused: not a finite number")
        if power_w < 0.0:
            raise HeaterLimitRefused(self.label, f"heater power {power_w:g} W refused: the heater cannot cool")
        current = current_for_power_a(power_w, self.heater_resistance_ohm)
        self._check_current(current, power_w)
        return current

    def _check_current(self, current_a: float, power_w: float | None = None) -> None:
        """:class:`HeaterLimitRefused` unless ``current_a`` is a current the limits allow (asked for as ``power_w``,
        where given: the refusal names it; the message is put together only then)."""
        if type(current_a) is not float and (isinstance(current_a, bool) or not isinstance(current_a, numbers.Real)) \
                or not (math.isfinite(current_a) and 0.0 <= current_a):
            raise HeaterLimitRefused(self.label, f"heater current {current_a!r} A refused")
        if current_a > self.max_current_a:
            what = f"{current_a * 1e3:.4g} mA" if power_w is None else f"{power_w:g} W"
            raise HeaterLimitRefused(
                self.label, f"{what} refused: needs {current_a * 1e3:.4g} mA, above the "
                            f"{self.max_current_a * 1e3:.4g} mA maximum "
                            f"({self.max_power_w * 1e3:.4g} mW at {self.heater_resistance_ohm:g} ohm)")

    # -- safety --------------------------------------------------------------------------
    def safe_on_fault(self) -> "_SafeOnFault":
        """Any failure inside: output to 0 A and off (best effort), error queue attached, re-raised.

        (A plain class rather than a generator context manager: it wraps every heater setting; it holds
        nothing between uses, so one serves every setting.)
        """
        context = self.__dict__.get("_safe_on_fault")
        if context is None:
            context = self._safe_on_fault = _SafeOnFault(self)
        return context

    def _force_off(self) -> float | None:
        """0 A and output off whatever happened (never raises); a dropped connection is reopened once for it.

        Returns
        -------
        float or None
            The clock time the supply confirmed it; None when it could not be confirmed
            (:attr:`off_failure` says why: the output's state is unknown).
        """
        try:
            try:
                self.write_output_off()
            except ConnectionLost:
                self.transport.reopen()
                self.write_output_off()
        except Exception as error:  # noqa: BLE001 - kept as off_failure; the caller reports the fault it handles
            self.off_confirmed_s = None
            self.off_failure = error if isinstance(error, InstrumentError) else \
                ConnectionLost(self.label, f"switching the output off failed: {type(error).__name__}: {error}")
        else:
            self.off_confirmed_s = self.clock.now()
            self.off_failure = None
        self.output_is_on = False
        self.current_a = 0.0
        return self.off_confirmed_s

    # -- the loop's interface ----------------------------------------------------------------
    def set_power_w(self, power_w: float) -> HeaterSetting:
        """Apply ``power_w`` (W) as I = sqrt(P / R); turns the output on the first time.

        Raises
        ------
        HeaterLimitRefused
            Above the maximum current or negative: nothing sent, output unchanged.
        HeaterRefused, HeaterCompliance, InstrumentError
            The output is then at 0 A and off.
        """
        current = self.current_for_power(power_w)      # checked: applied as it is
        self._apply_current_a(current)
        return HeaterSetting(float(power_w), current, current ** 2 * self.heater_resistance_ohm)

    def set_current_a(self, current_a: float) -> HeaterSetting:
        """Apply ``current_a`` (A) directly; same limits and safety as :meth:`set_power_w`."""
        self._check_current(current_a)
        self._apply_current_a(current_a)
        power = current_a ** 2 * self.heater_resistance_ohm
        return HeaterSetting(power, current_a, power)

    def _apply_current_a(self, current_a: float) -> None:
        """Send ``current_a`` (A), which the limits allow (checked before), with the checks of every setting."""
        with self.safe_on_fault():
            self.off_confirmed_s = self.off_failure = None      # from here on the supply is being driven
            if self.output_is_on and self.verify_each_setting:
                # every cycle, in one program message: the setting, whether the output is still on (an
                # interlock that opens turns it off unseen otherwise), and its compliance
                reply = self.query(f"{self.current_command(current_a)};{OUTPUT_STATE_QUERY};{self.compliance_query}")
                self.current_a = current_a
                output_reply, _, compliance_reply = reply.partition(";")
                self._raise_if_output_went_off(output_reply, compliance_reply)
                self._raise_if_in_compliance(self.compliance_from_reply(compliance_reply))
            else:
                self.write_current(current_a)
                self.current_a = current_a
                if not self.output_is_on:
                    self.turn_output_on()
                    self.output_is_on = True
                if self.verify_each_setting:
                    self.check_compliance()

    def read_back(self) -> HeaterReadback:
        """Current, voltage and power as the supply reports them; compliance is a fault."""
        with self.safe_on_fault():
            return self.measure_output()

    def output_off(self) -> float:
        """Current to 0 A and output off, confirmed by the supply; returns the clock time it was.

        Asks nothing when the output is already confirmed off with nothing sent since (returns
        that time). A dropped connection is reopened once for it.

        Raises
        ------
        InstrumentError
            The off could not be confirmed: the output's state is unknown. An off that already
            failed so is not tried again here (the caller is to stop and go to the supply;
            :meth:`close` tries once more): the same error is raised at once.
        """
        if self.off_confirmed_s is not None:
            return self.off_confirmed_s
        if self.off_failure is None:
            confirmed_s = self._force_off()
            if confirmed_s is not None:
                return confirmed_s
        # _force_off sets off_failure whenever it returns None
        assert self.off_failure is not None
        raise self.off_failure

    shutdown = output_off

    def close(self) -> None:
        """Output off (best effort) and release the connection."""
        self._force_off()
        self.transport.close()

    def __enter__(self) -> "HeaterSupply":
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    # -- what both Keithley supplies share: :SOURce:CURRent and :OUTPut:STATe ------------------
    output_enabled = Control(":OUTPut:STATe {}", ":OUTPut:STATe?", "Output on/off (OUTPut subsystem).",
                             on_off, parse_bool)

    def write_current(self, current_a: float) -> None:
        """Program the output current (the model's ``source_current_a`` setting)."""
        self.write(self.current_command(current_a))

    def current_command(self, current_a: float) -> str:
        """The command that programs ``current_a``, without sending it."""
        return type(self).source_current_a.command_for(current_a, self)

    #: The query whose reply says whether the output is in compliance (per model).
    compliance_query: str = ""

    def compliance_from_reply(self, reply: str) -> bool:
        """True if ``reply`` to :attr:`compliance_query` says the output is in compliance (per model)."""
        raise NotImplementedError

    def in_compliance(self) -> bool:
        """Ask the supply whether its output is voltage-limited."""
        return self.compliance_from_reply(self.query(self.compliance_query))

    def turn_output_on(self) -> None:
        """Turn the output on and read it back: :meth:`output_refused` if it stays off."""
        self.output_enabled = True
        if not self.output_enabled:
            raise self.output_refused()

    def check_compliance(self) -> None:
        """:class:`HeaterCompliance` if the output is voltage-limited."""
        self._raise_if_in_compliance(self.in_compliance())

    def _raise_if_output_went_off(self, output_reply: str, compliance_reply: str) -> None:
        try:
            on = parse_bool(output_reply)
        except ValueError:
            raise BadReply(self.label, f"output state: reply to {OUTPUT_STATE_QUERY} is not 1 or 0",
                           reply=output_reply) from None
        if not on:
            raise HeaterOutputOff(self.label, f"output went off while driving {self.current_a * 1e3:.4g} mA "
                                              f"({self.output_off_reason(compliance_reply)}): the heater was "
                                              "getting no power; check the interlock before restarting")

    def output_off_reason(self, compliance_reply: str) -> str:
        """Why the output may have gone off, from the reply to :attr:`compliance_query` (per model)."""
        return "interlock, output enable or front panel"

    def _raise_if_in_compliance(self, in_compliance: bool) -> None:
        if in_compliance:
            raise HeaterCompliance(self.label, f"in voltage compliance at {self.current_a * 1e3:.4g} mA "
                                               f"({self.voltage_compliance_v:g} V limit): heater open or "
                                               "its resistance too high")

    def write_output_off(self) -> None:
        """0 A and output off in one program message, confirmed by the output state it reads back
        (the reply comes once the supply has executed the off)."""
        reply = self.query(f"{self.current_command(0.0)};{type(self).output_enabled.command(False, self.label)};"
                           f"{OUTPUT_STATE_QUERY}")
        try:
            on = parse_bool(reply)
        except ValueError:
            raise BadReply(self.label, f"output state after the off: reply to {OUTPUT_STATE_QUERY} is not 1 or 0",
                           reply=reply) from None
        if on:
            raise HeaterRefused(self.label, "output still on after :OUTPut:STATe OFF")

    # -- per model -----------------------------------------------------------------------------
    @abc.abstractmethod
    def configure_source(self) -> None:
        """Output off, current source on a range holding ``max_current_a``, compliance set, 0 A."""

    @abc.abstractmethod
    def output_refused(self) -> HeaterRefused:
        """The error for an output that stayed off, with the supply's reason."""

    @abc.abstractmethod
    def measure_output(self) -> HeaterReadback:
        """Read the output back."""


class _SafeOnFault:
    """Context of :meth:`HeaterSupply.safe_on_fault`."""

    __slots__ = ("supply",)

    def __init__(self, supply: HeaterSupply):
        self.supply = supply

    def __enter__(self) -> None:
        return None

    def __exit__(self, kind, error, traceback) -> Literal[False]:
        if error is None or isinstance(error, HeaterLimitRefused):
            return False
        confirmed = self.supply._force_off()         # the heater first; then, if the supply answers, why
        if confirmed is not None and isinstance(error, InstrumentError):
            self.supply.examine_fault(error)
        return False
