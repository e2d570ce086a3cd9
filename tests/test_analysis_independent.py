"""``cryod analyze`` on records of an independent simulator (:mod:`simulated_hw.lumped_cryostat`): pairs of effects
named right, both causes and nothing else (docs/explanation/analysis-method.md; results: benchmarks/results/analysis-independent.md).

Slow (``pytest -m slow``): the benchmark's 18 pair records (``benchmarks/analysis_independent.py``'s plan, seed 35:
each record its own network, effect sizes and noise), 7 to 20 s of CPU each: the issue's goal (marked xfail while
it is not met) and the level reached. The rate is over those 18 draws, not
one seed's outcome; the fast checks of the simulator itself are below.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulated_hw.lumped_cryostat import Effects, LumpedCryostat, run_protocol


def test_the_clean_network_is_the_shipped_models_cryostat():
    """Without effects the network shows what the shipped model says: T2's line 1.73 mK lagging T5 by 1.134 rad
    (within 1 % and 0.01 rad), and the 8.8 mW step of Table 1 within 0.3 % of its height (seed-free: 20 µK of noise
    against fits over thousands of samples)."""
    from cryod.analysis.paper_table1 import flange_step_response_K

    cryostat = LumpedCryostat.nominal()
    record = run_protocol(cryostat, "paper", 1200.0, seed=1)
    t, flange, stage = record["time_s"], record["T2_K"], record["T5_K"]
    before = t < 300.0
    columns = np.column_stack([np.sin(cryostat.line_rad_s * t[before]), np.cos(cryostat.line_rad_s * t[before]),
                               np.ones(before.sum())])
    on_flange = np.linalg.lstsq(columns, flange[before], rcond=None)[0]
    on_stage = np.linalg.lstsq(columns, stage[before], rcond=None)[0]
    flange_line, stage_line = complex(*on_flange[:2]), complex(*on_stage[:2])
    assert abs(flange_line) == pytest.approx(1.73e-3, rel=0.01)
    assert float(np.angle(stage_line / flange_line)) == pytest.approx(1.134, abs=0.01)
    after = (t >= 300.0) & (t < 1200.0)
    window = np.convolve(flange - flange_step_response_K(t - 300.0), np.ones(58) / 58.0, mode="same")
    assert np.max(np.abs(window[after][60:-60])) < 0.003 * 0.06


def test_each_effect_changes_the_record_where_it_should():
    """A thermometer's lag delays the line on T2 and leaves T5; a transport delay shifts the step by its length;
    a heater that sags lowers the step in proportion to P^2 (seed-free: the same seed with and without)."""
    plain = run_protocol(LumpedCryostat.nominal(), "paper", 600.0, seed=2)
    lagging = run_protocol(LumpedCryostat.nominal().with_effects(Effects(thermometer_lag_s=0.5)), "paper", 600.0, 2)
    assert np.array_equal(plain["T5_K"], lagging["T5_K"])
    assert np.std(lagging["T2_K"][:3000] - lagging["T2_K"][:3000].mean()) < np.std(plain["T2_K"][:3000]
                                                                                    - plain["T2_K"][:3000].mean())
    delayed = run_protocol(LumpedCryostat.nominal().with_effects(Effects(delay_s=5.0)), "paper", 600.0, seed=2)
    t = plain["time_s"]
    # means over eight line periods (4.64 s) cancel the line
    rise = lambda record, at: float(np.mean(record["T2_K"][(t >= at - 2.32) & (t < at + 2.32)]))  # noqa: E731
    assert rise(delayed, 310.0) == pytest.approx(rise(plain, 305.0), abs=3e-5)
    sagging = run_protocol(LumpedCryostat.nominal().with_effects(Effects(heater_sag_per_W2=-4.0)), "paper", 600.0, 2)
    step = lambda record: float(np.mean(record["T2_K"][t > 550.0]) - np.mean(record["T2_K"][t < 290.0]))  # noqa: E731
    assert step(sagging) / step(plain) == pytest.approx(1.0 - 4.0 * 0.0088 ** 2, abs=2e-3)
    assert math.isfinite(step(plain))


@pytest.fixture(scope="module")
def pair_results() -> list[dict]:
    """The benchmark's 18 pair records (seed 35) analysed, once for the tests below."""
    from benchmarks.analysis_independent import plan, run_one

    return [run_one(job) for job in plan(35) if job["kind"] == "two effects"]


def _wrong_causes(results: list[dict]) -> int:
    from benchmarks.analysis_independent import CATALOGUE

    return sum(bool(set(result["named"]) - {CATALOGUE[name] for name in result["effects"]})
               or result["cause"] == "base_model_off" for result in results)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="5 of 18 pairs named right (seed 35; 7 of 18 on seed 36), a catalogue cause not in the record in 10 of 18: goal not met")
def test_pairs_of_effects_are_named_right(pair_results):
    """The issue's goal on the benchmark's 18 pair records: both causes named and nothing else in at least 90 %, a
    catalogue cause that is not in the record in at most one."""
    from benchmarks.analysis_independent import right

    named_right = sum(right(result) for result in pair_results)
    assert named_right >= 0.9 * len(pair_results), [(result["effects"], result["named"]) for result in pair_results]
    assert _wrong_causes(pair_results) <= 1


@pytest.mark.slow
def test_pairs_of_effects_hold_the_level_reached(pair_results):
    """The level the analysis reaches on the same records (benchmarks/results/analysis-independent-compare.md): at least 5 of the 18
    pairs named right, a catalogue cause not in the record in at most 10, no record the analysis fails on."""
    from benchmarks.analysis_independent import right

    named_right = sum(right(result) for result in pair_results)
    assert named_right >= 5, [(result["effects"], result["named"]) for result in pair_results]
    assert _wrong_causes(pair_results) <= 10, [(result["effects"], result["named"]) for result in pair_results]
    assert not any(result["cause"].startswith("error") for result in pair_results)
