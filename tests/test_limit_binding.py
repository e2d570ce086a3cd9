"""What binds the feedforward's limit (the 0 W floor, the top, neither), said by feedforward-limit, the
feedforward's status and the dry run's summary, and a measured value against the limit in one measure."""

import json
import time

import pytest

from cryod.cli import main
from cryod.control.feedforward.limit import feedforward_limit, limit_changes
from cryod.control.feedforward.limit_binding import limit_binding, measured_against_limit


@pytest.fixture(scope="module")
def model():
    from cryod.model import load_model

    return load_model()


@pytest.mark.parametrize("setpoint_K, resistance_ohm, bound, bigger_heater_helps", [
    (5.0, 50.0, "floor", False),            # 113 mW of 500 mW: the waveform rests at 0 W
    (5.0, 35.0, "floor", False),            # it touches the 350 mW top too, but a bigger heater changes nothing
    (5.0, 25.0, "floor and top", True),
    (7.0, 50.0, "top", True),               # 406 mW of 500 mW
    (6.0, 50.0, "none", False),             # the heater can cancel the line
])
def test_what_binds_and_what_a_bigger_heater_would_do(model, setpoint_K, resistance_ohm, bound, bigger_heater_helps):
    limit = feedforward_limit(model, setpoint_K, resistance_ohm, 0.1, certify=False)
    changes = limit_changes(model, setpoint_K, limit.max_heater_power_W)
    binding = limit_binding(limit, changes)
    assert binding.bound == bound, binding.explanation
    doubled = changes[2].point.limit.ptc_periodic_limit_K
    assert (doubled < 0.99 * limit.ptc_periodic_limit_K) == bigger_heater_helps
    if bound == "floor":
        assert "A bigger heater does not help" in binding.explanation and "a higher setpoint does" in binding.explanation
        assert f"{doubled * 1e6:.1f} µK" in binding.explanation
    if bound == "top":
        assert "A bigger heater helps (R I_max^2 x 2 (1000 mW):" in binding.explanation
        assert "so does a lower setpoint (setpoint 6.5 K:" in binding.explanation
    if bound == "none":
        assert "no bound binds" in binding.explanation and "noise of the line's estimate" in binding.explanation


def test_a_measured_value_below_the_limit_is_said_with_why():
    assert measured_against_limit(540e-6, 526e-6, 4e-6).startswith("measured 540.0 µK, 1.03 x the limit 526.0 µK")
    within = measured_against_limit(520e-6, 526e-6, 4e-6)
    assert "below the limit 526.0 µK (harmonics 1-6 both) by 6.0 µK, within twice the estimate's noise" in within
    beyond = measured_against_limit(253.6e-6, 345.3e-6, 3.6e-6, "the learned plant")
    assert "by 91.7 µK, more than the estimate's noise (3.6 µK)" in beyond
    assert "the learned plant's line, plant and mean heater power" in beyond


def test_feedforward_limit_says_what_binds_in_text_and_json(capsys):
    assert main(["feedforward-limit"]) == 0
    text = capsys.readouterr().out
    assert "limited by                    authority: the 0 W floor" in text
    assert "What binds: the heater's 0 W floor binds: the setpoint needs 112.9 mW" in text
    rows = {line.split()[0] + line.split()[1]: line for line in text.splitlines() if " mW " in line and "ohm" in line}
    assert rows["35ohm"].endswith("the 0 W floor") and rows["25ohm"].endswith("the 0 W floor and the top")
    assert main(["feedforward-limit", "--setpoint", "7", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["binding"]["bound"] == "top" and summary["limited_by"] == "authority"
    assert summary["binding"]["top_fraction"] > 0.3
    assert [row["bound"] for row in summary["sweeps"]["setpoint"][:4]] == ["floor", "floor", "floor", "none"]


def test_the_feedforward_status_says_what_binds_and_t2_against_the_limit(tmp_path):
    from tests.gated_daemon import GatedDaemon

    with GatedDaemon(tmp_path) as daemon:
        term = daemon.loop.regulator.term("feedforward")
        deadline = time.monotonic() + 120
        while term.physical_limit is None or "T2 now against the limit" not in term.describe():
            assert time.monotonic() < deadline, term.describe()
            daemon.gate.run_ticks(125)
        text = term.describe()
    assert "what binds it: the heater's 0 W floor binds" in text
    against = next(line for line in text.splitlines() if line.startswith("T2 now against the limit: "))
    assert "(harmonics 1-6 both)" in against
