"""A one-hour record at 12.5 Hz, base parameters off, is analysed (recalibration, every candidate, naming the
causes, figures) within the 15 s budget.

The analysis' own cost is its CPU time (the machine may be running other work: the wall time then says little);
the wall time is held to the budget too when a core is free for it."""

import os
import time

import pytest

from cryod import cli
from cryod.model import HeatCapacityTemperature
from cryod.records.record import write_record
from simulated_hw.hidden_effects import perturbed_base
from simulated_hw.measurement_programs import make_record

#: The budget of an hour's analysis with figures (s).
BUDGET_S = 15.0


@pytest.mark.slow
def test_one_hour_record_in_15_seconds(reference_model, tmp_path, capsys):
    model, _ = perturbed_base(reference_model.with_effects(
        heat_capacity_temperature=HeatCapacityTemperature(1.0, 4.23)), seed=4)
    record = make_record(model, "identification", duration_s=3600.0, seed=1)
    path = write_record(tmp_path / "hour.csv", record.columns, record.metadata)
    assert len(record.columns["time_s"]) == 45000
    started, started_cpu = time.perf_counter(), time.process_time()
    status = cli.main(["analyze", str(path), "--out", str(tmp_path / "out"), "--json"])
    elapsed, cpu = time.perf_counter() - started, time.process_time() - started_cpu
    assert status == 0 and '"cause": "heat_capacity_temperature"' in capsys.readouterr().out
    assert cpu <= BUDGET_S
    if os.getloadavg()[0] < (os.cpu_count() or 1):       # a core free for the analysis (this test's own load in)
        assert elapsed <= BUDGET_S
