"""A new control term is one class plus one line in the factory: shown with a small test term.

The test term adds a constant heater power (its own section ``control.bias``,
optional, reloadable). Registering it is the one line a real term adds to
``cryod.control.terms.TERM_TYPES``; here the test adds it for its own duration.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cryod.config import load_config
from cryod.control.pi import PiGains
from cryod.control.terms import TERM_TYPES, ControlTerm, TickInputs, term_type
from cryod.records.columns import Column, Row
from cryod.records.record import read_record_text
from cryod.service.commands import Command
from drivers.clock import VirtualClock
from cryod.service.instruments import load_curves
from cryod.service.loop import ControlLoop
from cryod.yaml_source import FileFormatError, Section
from cryod.control.closed_loop import Segment, run_program
from simulated_hw.cryostat import SimulatedCryostat
from tests.conftest import CONFIG
from tests.loop_doubles import DirectInstruments


class BiasTerm(ControlTerm):
    """A constant heater power added to the other terms (W)."""

    name = "bias"
    required = False
    columns = (Column("bias_W", "W", "constant added heater power"),)

    def __init__(self, power_w: float, output_max: float):
        self.power_w = power_w
        self.limited = 0

    @staticmethod
    def settings_from(section: Section | None) -> float:
        if section is None:
            return 0.0
        power = section.number("power_W", minimum=0.0, maximum=0.1)
        section.finish()
        return power

    def reconfigure(self, power_w: float, output_max: float) -> None:
        self.power_w = power_w

    def start(self, tick: TickInputs, present_output: float) -> None:
        pass

    def update(self, tick: TickInputs) -> float:
        return self.power_w

    def limit(self, requested: float, applied: float) -> None:
        self.limited += applied != requested

    def column_values(self) -> tuple[float, ...]:
        return (self.power_w,)


@pytest.fixture
def bias_registered(monkeypatch):
    monkeypatch.setitem(TERM_TYPES, "bias", f"{__name__}.BiasTerm")      # the one line in the factory
    term_type.cache_clear()
    yield
    term_type.cache_clear()


def config_with(tmp_path, extra: str):
    text = (CONFIG / "cryod.yaml").read_text()
    text = text.replace("calibration: calibration/", f"calibration: {CONFIG}/calibration/")
    text = text.replace("  pi:", extra + "  pi:")
    path = tmp_path / "cryod.yaml"
    path.write_text(text)
    return load_config(path)


def test_term_section_is_validated_optional_and_named_in_errors(tmp_path, bias_registered):
    assert config_with(tmp_path, "").control.term("bias") == 0.0
    assert config_with(tmp_path, "  bias:\n    power_W: 0.02\n").control.term("bias") == 0.02
    with pytest.raises(FileFormatError, match="control.bias.power_W: must be at most 0.1"):
        config_with(tmp_path, "  bias:\n    power_W: 0.5\n")


def test_term_runs_in_the_loop_with_its_column_in_the_record_and_reloads(tmp_path, reference_model, bias_registered):
    config = config_with(tmp_path, "  bias:\n    power_W: 0.02\n")
    clock = VirtualClock()
    curves = load_curves(config)
    instruments = DirectInstruments(SimulatedCryostat(reference_model, clock, seed=1), *curves, clock)
    rows = []
    loop = ControlLoop(config, instruments, *curves, clock,
                       emit=lambda item: isinstance(item, Row) and rows.append(item))
    assert "bias_W" in loop.schema.names and "bias_W [W]: constant added heater power" in loop.schema.units_text()
    terms = tuple((name, 0.05 if name == "bias" else settings) for name, settings in config.control.terms)
    loop.submit(Command("reload", dataclasses.replace(config, control=dataclasses.replace(config.control,
                                                                                          terms=terms))))
    loop.run(duration_s=300.0, manage_gc=False)
    closed = [row for row in rows if row.state.startswith("closed")]
    assert {row.control["bias_W"] for row in closed} == {0.05}
    # the heater is the sum of the terms (where not held at a limit)
    free = [row for row in closed if row.state == "closed"]
    assert all(row.heater_W == pytest.approx(row.control["pi_proportional_W"] + row.control["pi_integral_W"]
                                             + row.control["ff_W"] + 0.05) for row in free)
    text = "# cryod-log v1\n" + ",".join(loop.schema.names) + "\n" + "".join(loop.schema.format_row(r) for r in rows)
    assert read_record_text(text).columns["bias_W"][-1] == 0.05


def test_term_runs_in_the_offline_simulation_too(reference_model, bias_registered):
    """The same regulator: the PI's integral gives back what the bias adds, at the same temperature."""
    plain = run_program(reference_model, [Segment(0.0, setpoint_K=5.0)], 600.0, gains=PiGains(0.4, 0.01),
                        heater_max_w=0.5, seed=1)
    biased = run_program(reference_model, [Segment(0.0, setpoint_K=5.0)], 600.0, gains=PiGains(0.4, 0.01),
                         heater_max_w=0.5, seed=1, more_terms=(("bias", 0.03),))
    late = plain.time_s > 450.0
    assert np.all(biased.control["bias_W"][late] == 0.03)
    assert np.mean(biased.heater_w[late]) == pytest.approx(np.mean(plain.heater_w[late]), rel=0.02)
    assert np.mean(biased.control["pi_integral_W"][late]) == pytest.approx(
        np.mean(plain.control["pi_integral_W"][late]) - 0.03, abs=0.003)
