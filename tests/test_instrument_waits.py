"""How long the daemon waits on an instrument, held against systemd's watchdog and refused in the config."""

import logging

import pytest

from cryod.config import load_config
from cryod.instrument_waits import (LOOP_REPLY_PERIODS, UNIT_WATCHDOG_S, WATCHDOG_PING_SHARE, InstrumentWaits)
from cryod.service.notify import SystemdNotifier
from cryod.yaml_source import FileFormatError
from tests.conftest import CONFIG
from tests.example_config import line_of, written
from tests.systemd_units import TEMPLATE, UNIT, unit_sections


@pytest.mark.parametrize("unit", [UNIT, TEMPLATE])
def test_the_configuration_is_checked_against_the_shipped_units_watchdog(unit):
    assert float(unit_sections(unit)["Service"]["WatchdogSec"]) == UNIT_WATCHDOG_S


def test_the_example_fits_and_its_loop_waits_five_periods_for_a_reply():
    config = load_config(CONFIG / "cryod.yaml")
    waits = InstrumentWaits(config.loop.period_s, config.instruments.timeout_s)
    assert waits.watchdog_problem() is None
    assert waits.loop_reply_s == LOOP_REPLY_PERIODS * config.loop.period_s == 0.4
    assert InstrumentWaits(0.08, 0.05).loop_reply_s == 0.05       # a shorter timeout is kept


@pytest.mark.parametrize("timeout_s", [30.0, 60.0, 2.0])
def test_a_timeout_the_watchdog_cannot_wait_out_is_refused_with_file_line_and_key(tmp_path, timeout_s):
    path, text = written(tmp_path, "  timeout_s: 1.0 ", f"  timeout_s: {timeout_s:g} ")
    with pytest.raises(FileFormatError) as caught:
        load_config(path)
    message = str(caught.value)
    assert message.startswith(f"{path}:{line_of(text, 'timeout_s:')}: instruments.timeout_s: {timeout_s:g} s per reply")
    assert "WatchdogSec in systemd/cryod.service" in message and "at most 1.985 s per reply fits" in message


def test_the_largest_timeout_fits_and_a_little_more_does_not():
    for period_s in (0.01, 0.08, 0.5, 1.0, 2.0):
        largest = InstrumentWaits(period_s, 1.0).largest_timeout_s()
        assert InstrumentWaits(period_s, largest).watchdog_problem() is None
        assert InstrumentWaits(period_s, largest * 1.001).watchdog_problem() is not None


def test_a_loop_period_no_timeout_fits_is_refused_at_the_period(tmp_path):
    path, text = written(tmp_path, "  period_s: 0.08 ", "  period_s: 6.0 ")
    with pytest.raises(FileFormatError) as caught:
        load_config(path)
    assert str(caught.value).startswith(f"{path}:{line_of(text, 'period_s:')}: loop.period_s: 6 s: ")
    assert "no timeout fits a 6 s loop period" in str(caught.value)


def test_the_watchdog_is_pinged_at_the_spacing_the_check_assumes():
    sent = []
    notifier = SystemdNotifier(environ={"NOTIFY_SOCKET": "/nowhere", "WATCHDOG_USEC": "10000000"})
    notifier.send = lambda *fields: sent.append(fields)
    for _ in range(3):
        notifier.watchdog()
    assert len(sent) == 1
    notifier._last_ping -= UNIT_WATCHDOG_S * WATCHDOG_PING_SHARE
    notifier.watchdog()
    assert len(sent) == 2


def test_a_shorter_watchdog_than_the_units_is_a_warning_at_start(tmp_path, caplog):
    from drivers.clock import VirtualClock
    from cryod.service.daemon import Daemon
    from tests.example_config import simulated_config
    from tests.fault_drills import FlakyOpener

    notifier = SystemdNotifier(environ={"WATCHDOG_USEC": "2000000"})
    daemon = Daemon(simulated_config(tmp_path), FlakyOpener(failures=0), VirtualClock(), notifier=notifier,
                    install_signal_handlers=False)
    with caplog.at_level(logging.WARNING, logger="cryod.daemon"):
        assert daemon.run(1.0).exit_code == 0
    warning = next(record.message for record in caplog.records if "watchdog" in record.message)
    assert "WatchdogSec of this service" in warning and "instruments.timeout_s 1 s per reply" in warning
