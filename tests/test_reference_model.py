"""The shipped model reproduces the paper's measurements (Table 1); the printed equations do not all."""

import numpy as np
import pytest

from cryod.analysis import paper_table1 as table1
from tests.table1_experiments import open_loop_line, step_responses


@pytest.mark.parametrize("model_name", ["reference_model", "printed_model"])
def test_flange_step_within_one_percent_of_step_height_at_every_time(model_name, request):
    model = request.getfixturevalue(model_name)
    times, flange, _ = step_responses(model)
    measured = table1.flange_step_response_K(times) - table1.FLANGE_START_K
    height = measured[-1]
    assert height == pytest.approx(0.06, rel=0.01)
    worst = np.max(np.abs(flange - measured)) / height
    assert worst < 0.01
    if model_name == "reference_model":
        assert worst < 1e-4   # fitted to Table 1 itself


def test_ptc_stage_step_rises_24_mK_with_135_s(reference_model):
    times, _, stage = step_responses(reference_model, 3000.0)
    height = stage[-1] / (1 - np.exp(-3000.0 / 135.0))
    assert height == pytest.approx(0.024, abs=0.0005)      # Table 1 gives 0.024 K to 2 digits
    # time constant from a log-linear fit of the approach to the final value
    early = times < 400.0
    slope = np.polyfit(times[early][1:], np.log(1 - stage[early][1:] / height), 1)[0]
    assert -1 / slope == pytest.approx(table1.PTC_STAGE_TIME_CONSTANT_S, rel=0.01)


def test_open_loop_line_amplitude_and_lag(reference_model):
    flange, stage, lag = open_loop_line(reference_model)
    assert flange == pytest.approx(table1.FLANGE_LINE_AMPLITUDE_K, rel=0.02)
    assert lag == pytest.approx(table1.FLANGE_LAG_BEHIND_PTC_STAGE_RAD, abs=0.03)
    assert stage == pytest.approx(0.1236, rel=1e-3)
    assert reference_model.ptc.angular_frequency_rad_s == 10.83


def test_printed_equations_miss_the_lag_by_the_link_pole(printed_model):
    """docs/explanation/cryostat-model.md: eq. (11)'s 0.1 s pole adds atan(0.1 * 10.83) = 0.825 rad the derivation neglected."""
    flange, _, lag = open_loop_line(printed_model)
    assert lag == pytest.approx(1.959, abs=0.005)
    assert lag - table1.FLANGE_LAG_BEHIND_PTC_STAGE_RAD == pytest.approx(np.arctan(0.1 * 10.83), abs=0.005)
    assert flange == pytest.approx(1.839e-3, rel=0.005)   # with C = M c(Cu, 4.23 K), as in the shipped model
