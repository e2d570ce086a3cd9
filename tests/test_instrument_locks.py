"""One daemon per instrument: two configurations naming one supply (or DMM, or Prologix controller) cannot both drive it.

Each instrument is locked host-wide by its canonical address before any instrument is touched;
the second daemon stops with exit 2, naming the instrument, its key and the daemon holding it,
and the first goes on undisturbed.
"""

import dataclasses
import os
import time

import pytest

from cryod.cli import main
from cryod.config import load_config
from cryod.service.daemon import Daemon
from cryod.service.instance_lock import InstrumentInUse, InstrumentLocks, lock_file_name
from cryod.service.instruments import instrument_addresses
from drivers.clock import VirtualClock
from cryod.service.notify import SystemdNotifier
from drivers.transports.addresses import canonical_prologix, canonical_resource
from tests.conftest import CONFIG
from tests.service_bench import BenchOverTcp, RunProcess, faults_of_its_own
from tests.example_config import simulated_config
from tests.fault_drills import FlakyOpener

#: Processes, real sockets or real time: the second step of the suite (pytest -m system).
pytestmark = pytest.mark.system


@pytest.mark.parametrize("one, other", [
    ("GPIB0::12::INSTR", "gpib::12"),
    ("GPIB0::12::INSTR", "GPIB::012::INSTR"),
    ("TCPIP0::Cryo-Bench.lab::5025::SOCKET", "TCPIP::cryo-bench.LAB::5025::SOCKET"),
    ("TCPIP::10.0.0.5::INSTR", "TCPIP0::10.0.0.5::inst0::INSTR"),
    ("USB0::0x05E6::0x2400::4083212::INSTR", "USB::0x5e6::0x2400::4083212::0::INSTR"),
])
def test_one_instrument_written_two_ways_has_one_address(one, other):
    assert canonical_resource(one) == canonical_resource(other)
    assert lock_file_name(canonical_resource(one)) == lock_file_name(canonical_resource(other))


def test_different_instruments_have_different_addresses_and_lock_files():
    addresses = ["GPIB0::12::INSTR", "GPIB1::12::INSTR", "GPIB0::12::1::INSTR", "TCPIP0::10.0.0.5::5025::SOCKET",
                 "TCPIP0::10.0.0.5::5026::SOCKET", "ASRL/dev/ttyS0::INSTR"]
    canonical = [canonical_resource(address) for address in addresses]
    assert len(set(canonical)) == len(addresses) and len({lock_file_name(a) for a in canonical}) == len(addresses)


def test_a_serial_device_by_its_link_and_by_its_name_is_one_prologix_controller(tmp_path):
    device = tmp_path / "ttyUSB0"
    device.touch()
    link = tmp_path / "usb-Prologix_GPIB-USB_PX9XYSC5-if00-port0"
    link.symlink_to(device)
    assert canonical_prologix(port=str(link), gpib_address=12) == canonical_prologix(port=str(device), gpib_address=12)
    assert canonical_prologix(port=str(device), gpib_address=12) != canonical_prologix(port=str(device),
                                                                                        gpib_address=13)


def with_addresses(config, tmp_path, **instruments):
    return dataclasses.replace(config, instruments=dataclasses.replace(
        config.instruments, lock_directory=tmp_path / "locks", **instruments))


def test_the_addresses_locked_are_the_instruments_their_controller_and_the_trigger_port(tmp_path):
    from cryod.config import InstrumentAddress, TriggerOutputConfig

    config = load_config(CONFIG / "cryod.yaml")
    assert instrument_addresses(config) == {"GPIB0::12::INSTR": ["instruments.heater_supply.resource"],
                                            "GPIB0::16::INSTR": ["instruments.flange_dmm.resource"],
                                            "GPIB0::17::INSTR": ["instruments.ptc_stage_dmm.resource"]}
    behind_prologix = with_addresses(
        config, tmp_path, flange_dmm=InstrumentAddress(prologix_port="/dev/ttyUSB0", gpib_address=16),
        ptc_stage_dmm=InstrumentAddress(prologix_port="/dev/ttyUSB0", gpib_address=17), trigger="external",
        trigger_output=TriggerOutputConfig(port="/dev/ttyS0", line="rts", dmm_input="external", link_line=1))
    assert instrument_addresses(behind_prologix) == {
        "GPIB0::12::INSTR": ["instruments.heater_supply.resource"],
        "prologix-usb:/dev/ttyUSB0:gpib16": ["instruments.flange_dmm.prologix"],
        "prologix-usb:/dev/ttyUSB0": ["instruments.flange_dmm.prologix", "instruments.ptc_stage_dmm.prologix"],
        "prologix-usb:/dev/ttyUSB0:gpib17": ["instruments.ptc_stage_dmm.prologix"],
        "serial:/dev/ttyS0": ["instruments.trigger_output.port"]}
    unreadable = with_addresses(config, tmp_path, heater_supply=InstrumentAddress(resource="GPIB0::twelve::INSTR"))
    with pytest.raises(ValueError, match="instruments.heater_supply.resource: 'GPIB0::twelve::INSTR' is not a VISA"):
        instrument_addresses(unreadable)


def test_a_second_daemon_naming_the_first_ones_supply_touches_no_instrument_and_names_the_holder(tmp_path, caplog):
    """The easy mistake with cryod@NAME: a copied configuration, its own socket, the same supply."""
    first_config = simulated_config(tmp_path / "first")
    first_config = dataclasses.replace(with_addresses(first_config, tmp_path), source="/etc/cryod/k2-flange.yaml")
    held = InstrumentLocks(tmp_path / "locks", instrument_addresses(first_config), first_config.source)
    held.acquire()
    try:
        from cryod.config import InstrumentAddress

        second_config = with_addresses(simulated_config(tmp_path / "second"), tmp_path,        # its own DMMs
                                       flange_dmm=InstrumentAddress(resource="GPIB0::20::INSTR"),
                                       ptc_stage_dmm=InstrumentAddress(resource="GPIB0::21::INSTR"))
        assert second_config.control_socket.path != first_config.control_socket.path
        opener = FlakyOpener(failures=0)
        daemon = Daemon(second_config, opener, VirtualClock(), notifier=SystemdNotifier({}),
                        install_signal_handlers=False, instrument_addresses=instrument_addresses)
        result = daemon.run(10.0)
    finally:
        held.release()
    assert result.exit_code == 2 and opener.attempts == [] and result.log_paths == []
    refusal = [record.getMessage() for record in caplog.records if record.levelname == "CRITICAL"]
    assert refusal == [f"not started: instruments.heater_supply.resource GPIB0::12::INSTR is driven by another cryod "
                       f"(process {os.getpid()} with /etc/cryod/k2-flange.yaml, as "
                       f"instruments.heater_supply.resource); not started, no instrument was touched: give each "
                       f"daemon its own instruments"]
    assert not second_config.control_socket.path.exists()       # nothing of it is left listening


def test_locks_are_all_or_none_and_freed_with_the_process(tmp_path):
    locks = tmp_path / "locks"
    first = InstrumentLocks(locks, {"GPIB0::17::INSTR": ["instruments.ptc_stage_dmm.resource"]}, "a.yaml")
    first.acquire()
    second = InstrumentLocks(locks, {"GPIB0::12::INSTR": ["instruments.heater_supply.resource"],
                                     "GPIB0::17::INSTR": ["instruments.ptc_stage_dmm.resource"]}, "b.yaml")
    with pytest.raises(InstrumentInUse, match="instruments.ptc_stage_dmm.resource GPIB0::17::INSTR"):
        second.acquire()
    third = InstrumentLocks(locks, {"GPIB0::12::INSTR": ["instruments.heater_supply.resource"]}, "c.yaml")
    third.acquire()                                 # the refused one kept none of its locks
    third.release()
    first.release()
    second.acquire()
    second.release()


def test_check_names_an_unusable_lock_directory_and_an_address_that_is_not_one(tmp_path, capsys):
    text = (CONFIG / "cryod.yaml").read_text().replace("calibration: calibration/", f"calibration: {CONFIG}/calibration/")
    (tmp_path / "a-file").write_text("")
    bad_directory = tmp_path / "bad-directory.yaml"
    bad_directory.write_text(text.replace("  timeout_s: 1.0", f"  timeout_s: 1.0\n  lock_directory: {tmp_path}/a-file/locks"))
    assert main(["run", "--config", str(bad_directory), "--check"]) == 2
    assert "instruments.lock_directory" in capsys.readouterr().err
    bad_address = tmp_path / "bad-address.yaml"
    bad_address.write_text(text.replace("resource: GPIB0::12::INSTR", "resource: GPIB0::twelve::INSTR")
                           .replace('visa_library: "@py"', 'visa_library: ""')                  # NI-VISA
                           .replace("  timeout_s: 1.0", f"  timeout_s: 1.0\n  lock_directory: {tmp_path}/locks"))
    assert main(["run", "--config", str(bad_address), "--check"]) == 2
    assert "instruments.heater_supply.resource" in capsys.readouterr().err


def second_daemon_on_the_first_ones_supply(folder):
    """``cryod run`` regulating, then a second ``cryod run`` naming its supply: what the supply delivered from the
    second's start to its end, the second's exit code and journal, the first's state after and the faults the first
    found by itself meanwhile."""
    with BenchOverTcp() as bench:
        first = RunProcess(bench.write_config(folder / "first"))
        try:
            first.wait_for_heating(bench.supply)
            started = time.monotonic()
            second = RunProcess(bench.write_config(folder / "second"))
            try:
                exit_code = second.wait(60)
            finally:
                second.close()
            delivered_w = [power for changed_s, power in bench.supply.delivered_w if changed_s >= started]
            delivered_w.append(bench.supply.heater_power_w)
            state = first.status()["state"] if first.process.poll() is None else None
            return exit_code, second.journal, delivered_w, state, faults_of_its_own(first.journal)
        finally:
            first.close()


def test_two_cryod_run_on_one_supply_the_second_stops_with_exit_2_and_the_first_keeps_its_heater(tmp_path):
    """A run in which the first daemon switched its heater off for a fault of its own (a reply late on a busy
    machine) cannot show that the second left the heater alone: it is run again, up to three times."""
    faults = []
    for attempt in range(3):
        exit_code, journal, delivered_w, first_state, first_faults = \
            second_daemon_on_the_first_ones_supply(tmp_path / str(attempt))
        if not first_faults:
            break
        faults.append(first_faults[0])
    else:
        raise AssertionError(f"the first daemon switched its heater off by itself in every run: {faults}")
    assert exit_code == 2
    assert "first/cryod.yaml" in journal and "instruments.heater_supply.resource" in journal
    assert "no instrument was touched" in journal
    assert all(power > 0.0 for power in delivered_w)                      # never reset to 0 W
    assert first_state is not None and first_state.startswith("closed")
