"""The instruments as the loop sees them, built from the configuration.

:func:`open_instruments` opens the real instruments (``cryod run``); the
simulation (``cryod --simulate``) hands :func:`assemble_instruments` the
transports and trigger of the simulated bench instead, so both go through the
same drivers and the same :class:`DriverInstruments`.

Opening is all or nothing: if any instrument fails, the ones already open are
closed with the heater output off, and the error names the instrument.

Opened, the instruments wait for a reply at most as long as the loop allows
(:attr:`cryod.instrument_waits.InstrumentWaits.loop_reply_s`), and
``instruments.timeout_s`` only while they are configured again after a
reconnect; a failing DMM's error queue is read only when the loop asks
(:meth:`DriverInstruments.examine`), after the heater is off.
"""

from __future__ import annotations

import logging
from typing import Callable

from pyvisa import rname
from pyvisa.errors import VisaIOError
from pyvisa.resources import GPIBInterface

from cryod.config import INSTRUMENT_KEYS, DaemonConfig, DmmSettings, InstrumentAddress
from cryod.instrument_waits import InstrumentWaits
from cryod.service.instance_lock import InstrumentLocks
from cryod.thermometry import CalibrationCurve, load_calibration
from cryod.yaml_source import FileFormatError
from drivers.errors import ConnectionLost, InstrumentError
from drivers.heater import HeaterSupply
from drivers.keithley2002 import FourWireSettings, Keithley2002, TriggerSource
from drivers.keithley2400 import Keithley2400
from drivers.keithley6221 import Keithley6221
from drivers.pair_triggers import (
    GpibGroupTrigger,
    HardwareTrigger,
    PairTrigger,
    PrologixGroupTrigger,
    SequentialTrigger,
)
from drivers.thermometer_pair import PairReading, ThermometerPair
from drivers.transports.addresses import (
    canonical_prologix,
    canonical_prologix_adapter,
    canonical_resource,
    canonical_serial_port,
)
from drivers.transports.base import Transport
from drivers.transports.prologix import PrologixAdapter
from drivers.transports.visa import VisaTransport, resource_manager
from drivers.trigger_lines import SerialControlLine

log = logging.getLogger("cryod.instruments")

HEATER_DRIVERS = {"keithley6221": Keithley6221, "keithley2400": Keithley2400}


# ---------------------------------------------------------------------------
# calibration
# ---------------------------------------------------------------------------
def load_curves(config: DaemonConfig) -> tuple[CalibrationCurve, CalibrationCurve]:
    """The flange and PTC-stage calibration curves named in the configuration."""
    return (load_calibration(config.sensors.flange_calibration),
            load_calibration(config.sensors.ptc_stage_calibration))


def check_calibrations(config: DaemonConfig) -> str | None:
    """None if both calibration files load, else what is wrong with which file."""
    try:
        load_curves(config)
    except FileFormatError as error:
        return f"calibration file not usable: {error}"
    return None


# ---------------------------------------------------------------------------
# which instruments: what cryod run locks against other daemons
# ---------------------------------------------------------------------------
def instrument_addresses(config: DaemonConfig) -> dict[str, list[str]]:
    """Every instrument ``cryod run`` drives, by its canonical address, with the configuration keys naming it.

    The two DMMs and the heater supply; the Prologix controller they are behind, if any (two
    programs on one controller mix their GPIB traffic); the serial port of an external trigger.

    Raises
    ------
    ValueError
        An address that is not one (the message names its key).
    """
    instruments = config.instruments
    addresses: dict[str, list[str]] = {}

    def claim(address: str, key: str) -> None:
        keys = addresses.setdefault(address, [])
        if key not in keys:
            keys.append(key)

    for name in ("heater_supply", "flange_dmm", "ptc_stage_dmm"):
        address: InstrumentAddress = getattr(instruments, name)
        key = f"instruments.{name}"
        if address.resource:
            try:
                claim(canonical_resource(address.resource), f"{key}.resource")
            except ValueError as error:
                raise ValueError(f"{key}.resource: {error}") from None
        else:
            where = dict(port=address.prologix_port, host=address.prologix_host)
            claim(canonical_prologix(**where, gpib_address=_gpib_address(address)), f"{key}.prologix")
            claim(canonical_prologix_adapter(**where), f"{key}.prologix")
    if instruments.trigger == "external" and instruments.trigger_output is not None:
        claim(f"serial:{canonical_serial_port(instruments.trigger_output.port)}", "instruments.trigger_output.port")
    return addresses


def check_instrument_locking(config: DaemonConfig) -> str | None:
    """None if ``cryod run`` can lock the configured instruments' addresses, else what stands in the way."""
    from cryod.service.startup_checks import directory_problem

    try:
        instrument_addresses(config)
    except ValueError as error:
        return f"{config.source}: {error}"
    return directory_problem(config, "instruments.lock_directory", config.instruments.lock_directory)


# ---------------------------------------------------------------------------
# the loop's view
# ---------------------------------------------------------------------------
class DriverInstruments:
    """Two Keithley 2002s and a heater supply behind the loop's :class:`cryod.service.loop.Instruments` interface.

    Parameters
    ----------
    pair : ThermometerPair
    heater : HeaterSupply
    dmm_settings : FourWireSettings
        Applied again after a reconnect.
    transports : list of Transport
        Everything to reopen on :meth:`reconnect` and close on :meth:`close`.
    waits : InstrumentWaits
        How long to wait for a reply: on the loop's path, and while configuring after a reconnect.
    on_close : callable, optional
        Releases what else was opened (a trigger port, a GPIB board).
    """

    def __init__(self, pair: ThermometerPair, heater: HeaterSupply, dmm_settings: FourWireSettings,
                 transports: list[Transport], waits: InstrumentWaits, on_close: Callable[[], None] | None = None):
        self.pair = pair
        self.heater = heater
        self.dmm_settings = dmm_settings
        self.transports = transports
        self.waits = waits
        self.on_close = on_close
        for dmm in pair.dmms:                  # asked only after the heater is off (examine)
            dmm.examines_faults_at_once = False
        self.loop_reply_s = waits.loop_reply_s
        self._wait_for_replies(self.loop_reply_s)

    def wait_on_loop_path(self, reply_s: float) -> None:
        """Wait ``reply_s`` (real time) for a reply on the loop's path from now on.

        A paced dry run's simulated instruments answer in no simulated time: a reply that comes
        late in real time is the machine's load, not the instrument's, and is waited for up to
        ``instruments.timeout_s`` instead of five periods.
        """
        self.loop_reply_s = reply_s
        self._wait_for_replies(reply_s)

    def _wait_for_replies(self, timeout_s: float) -> None:
        for transport in self.transports:
            transport.timeout_s = timeout_s

    def measure(self) -> PairReading:
        return self.pair.measure()

    def set_heater_power(self, power_w: float) -> None:
        self.heater.set_power_w(power_w)

    def heater_off(self) -> float:
        """Heater output to 0 A and off; the clock time the supply confirmed it (InstrumentError: it could not)."""
        return self.heater.output_off()

    def examine(self, error: InstrumentError) -> None:
        """Attach what the failing instrument's error queue holds (asked after the heater is off; a
        queue that cannot be read is left out)."""
        error.examine()

    def reconnect(self) -> None:
        """Reopen every connection, then configure the DMMs and the heater again (output off), waiting
        ``instruments.timeout_s`` for each reply meanwhile."""
        self._wait_for_replies(self.waits.timeout_s)
        try:
            for transport in self.transports:
                transport.reopen()
            for dmm in self.pair.dmms:
                dmm.configure_four_wire_resistance(self.dmm_settings)
            self.pair.prepare()
            self.heater.configure()
        finally:
            self._wait_for_replies(self.loop_reply_s)

    def close(self) -> None:
        """Heater output off first, then everything else (each step best effort)."""
        try:
            self.heater.close()
        finally:
            try:
                self.pair.close()
            except InstrumentError as error:
                log.warning("closing the DMMs: %s", error)
            for transport in self.transports:
                try:
                    transport.close()
                except Exception as error:  # noqa: BLE001 - already closing; say so and go on
                    log.warning("closing %s: %s", getattr(transport, "name", transport), error)
            if self.on_close is not None:
                self.on_close()


def four_wire_settings(settings: DmmSettings) -> FourWireSettings:
    """The driver's settings from the configuration's ``instruments.dmm``."""
    return FourWireSettings(range_ohm=settings.range_ohm, nplc=settings.nplc, digits=settings.digits,
                            filter_count=settings.filter_count, autozero=settings.autozero,
                            autozero_synchronous=settings.autozero_synchronous,
                            offset_compensation=settings.offset_compensation, line_sync=settings.line_sync)


def assemble_instruments(config: DaemonConfig, clock, flange_transport: Transport, stage_transport: Transport,
                         heater_transport: Transport, make_trigger: Callable[[], PairTrigger],
                         on_close: Callable[[], None] | None = None) -> DriverInstruments:
    """Drivers on the given transports: identity checked, configured, heater output off.

    On any failure, what was opened is closed (heater off first) and the error re-raised.
    """
    transports = [heater_transport, flange_transport, stage_transport]
    heater = None
    try:
        heater_config = config.heater
        heater = HEATER_DRIVERS[config.instruments.heater_model](
            heater_transport, clock, heater_config.resistance_ohm, max_current_a=heater_config.max_current_A,
            voltage_compliance_v=heater_config.voltage_compliance_V, name=INSTRUMENT_KEYS["heater_supply"])
        line = config.instruments.dmm.line_frequency_hz
        flange = Keithley2002(flange_transport, clock, INSTRUMENT_KEYS["flange_dmm"], line_frequency_hz=line)
        stage = Keithley2002(stage_transport, clock, INSTRUMENT_KEYS["ptc_stage_dmm"], line_frequency_hz=line)
        settings = four_wire_settings(config.instruments.dmm)
        for dmm in (flange, stage):
            dmm.configure_four_wire_resistance(settings)
        pair = ThermometerPair(flange, stage, make_trigger(), clock)
        pair.prepare()
        if pair.reading_delay_s >= config.loop.period_s:
            raise ValueError(f"a reading takes {pair.reading_delay_s * 1e3:.0f} ms, longer than the "
                             f"{config.loop.period_s * 1e3:.0f} ms loop period: lower instruments.dmm.nplc")
        waits = InstrumentWaits(config.loop.period_s, config.instruments.timeout_s)
        return DriverInstruments(pair, heater, settings, transports, waits, on_close)
    except BaseException:
        if heater is not None:
            heater.close()
        for transport in transports:
            try:
                transport.close()
            except Exception:  # noqa: BLE001 - the original error is what matters
                pass
        if on_close is not None:
            on_close()
        raise


# ---------------------------------------------------------------------------
# real instruments
# ---------------------------------------------------------------------------
def _adapter_key(address: InstrumentAddress) -> tuple[str, str]:
    """("usb", its serial device) or ("ethernet", its host): the Prologix controller an instrument is behind."""
    if address.prologix_port:
        return "usb", address.prologix_port
    assert address.prologix_host is not None        # the configuration gives a port or a host
    return "ethernet", address.prologix_host


def _gpib_address(address: InstrumentAddress) -> int:
    """The GPIB address of an instrument behind a Prologix controller (the configuration gives it with one)."""
    assert address.gpib_address is not None
    return address.gpib_address


def open_transport(address: InstrumentAddress, config: DaemonConfig, adapters: dict, name: str) -> Transport:
    """A VISA transport, or a Prologix one sharing its adapter with the other instruments on it."""
    timeout = config.instruments.timeout_s
    if address.resource:
        return VisaTransport(address.resource, visa_library=config.instruments.visa_library, timeout_s=timeout,
                             name=name)
    key = _adapter_key(address)
    if key not in adapters:
        kind, place = key
        adapters[key] = (PrologixAdapter.usb(place, timeout_s=timeout) if kind == "usb"
                         else PrologixAdapter.ethernet(place, timeout_s=timeout))
    return adapters[key].instrument(address.gpib_address, name=name)


def open_instruments(config: DaemonConfig, clock) -> tuple[DriverInstruments, CalibrationCurve, CalibrationCurve]:
    """Open the configured instruments (``cryod run``).

    Returns
    -------
    (DriverInstruments, flange curve, PTC-stage curve)
    """
    curves = load_curves(config)
    instruments = config.instruments
    adapters: dict = {}
    opened: list = []
    try:
        for key in ("heater_supply", "flange_dmm", "ptc_stage_dmm"):
            try:
                opened.append(open_transport(getattr(instruments, key), config, adapters, INSTRUMENT_KEYS[key]))
            except InstrumentError as error:
                raise _with_key(error, key) from error.__cause__
        heater, flange, stage = opened
    except BaseException:
        for transport in opened:
            transport.close()
        for adapter in adapters.values():
            adapter.close()
        raise
    closers: list[Callable[[], None]] = [adapter.close for adapter in adapters.values()]

    def make_trigger() -> PairTrigger:
        mode = instruments.trigger
        if mode == "sequential":
            return SequentialTrigger([flange, stage], clock)
        if mode == "gpib-group":
            board = _gpib_board(instruments.flange_dmm)
            try:
                interface = resource_manager(instruments.visa_library).open_resource(f"GPIB{board}::INTFC")
            except (VisaIOError, OSError) as error:     # a card out of reach: waited for, as an instrument is
                raise ConnectionLost(f"GPIB{board}::INTFC (instruments.trigger: gpib-group)",
                                     f"cannot open the GPIB card to trigger both DMMs: {error}") from error
            closers.append(interface.close)
            assert isinstance(interface, GPIBInterface)     # what pyvisa opens a GPIBn::INTFC resource as
            return GpibGroupTrigger(interface, [flange, stage], clock)
        if mode == "prologix":           # the configuration puts both DMMs behind one controller
            addresses = [_gpib_address(instruments.flange_dmm), _gpib_address(instruments.ptc_stage_dmm)]
            return PrologixGroupTrigger(adapters[_adapter_key(instruments.flange_dmm)], addresses, clock)
        output = instruments.trigger_output
        assert output is not None           # the configuration gives an external trigger its wire
        line = SerialControlLine.open(output.port, clock, line=output.line)
        closers.append(line.close)
        source = TriggerSource.EXTERNAL if output.dmm_input == "external" else TriggerSource.TRIGGER_LINK
        return HardwareTrigger(line, clock, dmm_input=source, link_input_line=output.link_line)

    def close_others() -> None:
        for close in closers:
            try:
                close()
            except Exception as error:  # noqa: BLE001 - closing; say so and go on
                log.warning("closing: %s", error)

    try:
        instruments_set = assemble_instruments(config, clock, flange, stage, heater, make_trigger,
                                               on_close=close_others)
    except InstrumentError as error:
        config_key = next((key for key, name in INSTRUMENT_KEYS.items() if error.instrument == name), None)
        raise (error if config_key is None else _with_key(error, config_key)) from error.__cause__
    return (instruments_set, *curves)


def _with_key(error: InstrumentError, key: str) -> InstrumentError:
    """``error`` naming the configuration's key of its instrument too: ``heater supply (instruments.heater_supply)``,
    which the lab finds in the file, beside the resource the message quotes."""
    return error.relabelled(f"{error.instrument} (instruments.{key})")


def switch_supply_off(config: DaemonConfig, clock) -> None:
    """The configured heater supply to 0 A with its output off, without a daemon (``cryod run --supply-off``).

    What the service unit runs after the daemon ended, however it ended (``ExecStopPost``): after
    SIGKILL or a crash the supply would keep its last setting until the next start. The supply's
    address is locked first, as a daemon locks it, so a supply another daemon drives is left alone.

    Raises
    ------
    InstrumentInUse
        Another cryod drives the supply (nothing was sent).
    InstrumentError
        The supply is out of reach or did not confirm the off.
    """
    supply = {address: keys for address, keys in instrument_addresses(config).items()
              if any(key.startswith("instruments.heater_supply.") for key in keys)}
    locks = InstrumentLocks(config.instruments.lock_directory, supply, config.source)
    locks.acquire()
    adapters: dict = {}
    try:
        transport = open_transport(config.instruments.heater_supply, config, adapters,
                                   INSTRUMENT_KEYS["heater_supply"])
        try:
            heater = HEATER_DRIVERS[config.instruments.heater_model](      # opening sets 0 A, output off
                transport, clock, config.heater.resistance_ohm, max_current_a=config.heater.max_current_A,
                voltage_compliance_v=config.heater.voltage_compliance_V, name=INSTRUMENT_KEYS["heater_supply"])
            heater.output_off()
        finally:
            transport.close()
    finally:
        for adapter in adapters.values():
            adapter.close()
        locks.release()


def _gpib_board(address: InstrumentAddress) -> int:
    """The GPIB board of a DMM on a GPIB card (the configuration puts both DMMs of a gpib-group trigger on one)."""
    parsed = rname.parse_resource_name(address.resource or "")
    assert isinstance(parsed, rname.GPIBInstr)      # the configuration refuses gpib-group for other resources
    return int(parsed.board)
