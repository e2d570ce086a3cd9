"""True sample instants: what the daemon writes is what the analysis tools can use.

A Keithley 2002 integrates for NPLC power-line cycles after its trigger, and a
NORMal autozero due every 200 ms puts one more integration before every third
reading of an 80 ms loop: that reading stands for an instant 20 ms later than
its trigger. The daemon records each reading's instant (``T2_sample_s``,
``T5_sample_s``) and when it set the heater (``heater_set_s``); the analysis
replays the model at those instants. Records from the daemon itself, not
records made for the test, must then come out clean.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cryod.analysis.pipeline import analyze
from cryod.analysis.record_data import RecordData
from cryod.config import load_config
from cryod.identification.fit import identify
from cryod.model import load_model
from cryod.records.columns import Row
from cryod.records.record import read_record
from drivers.clock import VirtualClock
from cryod.service.commands import Command
from cryod.service.daemon import Daemon
from cryod.service.notify import SystemdNotifier
from cryod.service.simulation import SimulatedInstrumentsOpener
from tests.conftest import CONFIG


def daemon_record(tmp_path, duration_s, autozero_type="synchronous", program=None, setpoint_K=5.0):
    """A record written by the daemon on the simulated cryostat; ``program``: {seconds: command}."""
    config = load_config(CONFIG / "cryod.yaml")
    dmm = dataclasses.replace(config.instruments.dmm, autozero_synchronous=autozero_type == "synchronous")
    config = dataclasses.replace(
        config, instruments=dataclasses.replace(config.instruments, dmm=dmm),
        data=dataclasses.replace(config.data, directory=tmp_path / "data"),
        control_socket=dataclasses.replace(config.control_socket, path=tmp_path / "control.sock"),
        simulation=dataclasses.replace(config.simulation, transport="in-process"),
        control=dataclasses.replace(config.control, setpoint_K=setpoint_K))
    pending = dict(program or {})
    start = []
    daemon = None

    def tap(item):
        if isinstance(item, Row):
            start.append(item.time_s) if not start else None
            for at in [at for at in pending if item.time_s - start[0] >= at]:
                daemon.loop.submit(Command(*pending.pop(at)))

    daemon = Daemon(config, SimulatedInstrumentsOpener(load_model(), seed=3), VirtualClock(),
                    notifier=SystemdNotifier({}), row_taps=[tap], install_signal_handlers=False)
    result = daemon.run(duration_s)
    assert result.exit_code == 0
    return read_record(result.log_paths[0])


@pytest.mark.parametrize("autozero_type, delays_ms", [("normal", {10.0, 30.0}), ("synchronous", {10.0})])
def test_each_reading_records_the_instant_it_stands_for(tmp_path, autozero_type, delays_ms):
    record = daemon_record(tmp_path, 30.0, autozero_type)
    for sensor in ("T2_sample_s", "T5_sample_s"):
        delay_ms = np.round(1e3 * (record.columns[sensor] - record.time_s), 3)
        assert set(delay_ms) == delays_ms                  # the middle of a 20 ms integration (NPLC 1, 50 Hz)
    if autozero_type == "normal":
        late = np.flatnonzero(np.round(1e3 * (record.columns["T2_sample_s"] - record.time_s)) == 30.0)
        assert late[0] == 0 and np.all(np.diff(late) == 3)     # every third reading: the 200 ms autozero
    closed = np.array([str(state).startswith("closed") for state in record.columns["state"]])
    set_after_ms = 1e3 * (record.columns["heater_set_s"][closed] - record.time_s[closed])
    assert np.all((set_after_ms > 20.0) & (set_after_ms < 80.0))


#: The NORMal autozero's late readings in a record of the daemon are also checked by the manual-steps test below.
@pytest.mark.parametrize("autozero_type", [pytest.param("normal", marks=pytest.mark.slow), "synchronous"])
def test_a_clean_pi_record_of_the_daemon_has_no_cause(tmp_path, reference_model, autozero_type):
    """A quarter hour is plenty: the same record with its instants left out reads as a dead time thousands of
    sigma over the noise."""
    analysis = analyze(RecordData.from_record(daemon_record(tmp_path, 900.0, autozero_type)), reference_model)
    assert analysis.cause == "none", analysis.decision.reason


def test_a_record_with_manual_heater_steps_gives_no_cause_and_identifies_the_model(tmp_path, reference_model):
    program = {0.0: ("manual", 0.0), 200.0: ("manual", 0.010), 600.0: ("manual", 0.030),
               1000.0: ("setpoint", 5.0), 1400.0: ("manual", 0.110)}          # 400 s each: 2.4 times the slow pole
    data = RecordData.from_record(daemon_record(tmp_path, 1800.0, "normal", program, setpoint_K=None))
    assert analyze(data, reference_model).cause == "none"
    model = identify([data], reference_model).model
    truth = reference_model.heater_to_thermometer
    found = model.heater_to_thermometer
    assert found.dc_gain == pytest.approx(truth.dc_gain, rel=0.01)
    assert sorted(found.time_constants_s) == pytest.approx(sorted(truth.time_constants_s), rel=0.01)
    assert model.heater_to_ptc_stage.dc_gain == pytest.approx(reference_model.heater_to_ptc_stage.dc_gain, rel=0.01)
    assert model.operating_point.flange_temperature_K == pytest.approx(4.23, abs=0.0005)
