"""The paper's Fig. 10 (docs/figures/paper_fig10.py, docs/explanation/feedforward.md "The paper, reproduced"), on short runs.

A fixed 100 mW sinusoid locked to the cooler, over PI at 5 K, at the paper's eight phases: at the
phase that opposes the line it reduces it, at the opposite phase it increases it, and the
minimum lies where the analysis puts it (between pi and 5 pi/4 for the shipped model, between
3 pi/4 and pi, as the paper says, for the paper's printed equations).
"""

from __future__ import annotations

import importlib.util
import sys

import numpy as np
import pytest

from tests.conftest import REPOSITORY

DURATION_S = 240.0
WINDOW_S = 120.0


@pytest.fixture(scope="module")
def fig10():
    specification = importlib.util.spec_from_file_location("paper_fig10",
                                                           REPOSITORY / "docs" / "figures" / "paper_fig10.py")
    module = importlib.util.module_from_spec(specification)
    sys.modules[specification.name] = module       # the term's factory entry imports it by name
    try:
        specification.loader.exec_module(module)
        with module.fixed_sinusoid_registered():
            yield module
    finally:
        del sys.modules[specification.name]


def ratios(fig10, heater, model):
    """The line with the sinusoid at each of the eight phases over the line with PI alone (settled at 5 K)."""
    def line(more_terms=()):
        result = fig10.run(heater, more_terms, model=model, duration_s=DURATION_S, settled=True)
        return fig10.measure(result, model, window_s=WINDOW_S).periodic_K
    alone = line()
    return np.array([line(fig10.sinusoid(phase, model)) for phase in fig10.PHASES_RAD]) / alone


def test_the_analysis_puts_the_minimum_between_pi_and_5pi_4_and_the_paper_s_equations_between_3pi_4_and_pi(fig10):
    """T2 lags T5 by the measured 1.134 rad in the shipped model, by 1.959 rad in the printed equations
    (docs/explanation/cryostat-model.md): the sinusoid that opposes the line moves by the difference."""
    assert np.pi < fig10.best_phase_rad(fig10.MODEL) < 5 * np.pi / 4
    assert 3 * np.pi / 4 < fig10.best_phase_rad(fig10.PRINTED_MODEL) < np.pi
    assert fig10.best_phase_rad(fig10.MODEL) - fig10.best_phase_rad(fig10.PRINTED_MODEL) == pytest.approx(0.825,
                                                                                                           abs=0.01)


def test_the_sinusoid_leads_t5_by_its_phase(fig10):
    """The convention: T5 ~ sin(w t), heater sinusoid ~ sin(w t + phase); the value set at a tick is the
    one at the middle of the coming hold, half a period later."""
    phase = 5 * np.pi / 4
    result = fig10.run(fig10.EXAMPLE_HEATER, fig10.sinusoid(phase), duration_s=60.0, settled=True)
    late = result.time_s > 20.0
    t = result.time_s[late]
    rotor = np.exp(-1j * fig10.MODEL.ptc.angular_frequency_rad_s * t)
    stage = np.mean((result.ptc_stage_K[late] - np.mean(result.ptc_stage_K[late])) * rotor)
    sine = np.mean(result.control["sine_W"][late] * rotor)
    lead = np.angle(sine / stage)
    expected = phase + fig10.MODEL.ptc.angular_frequency_rad_s * fig10.PERIOD_S / 2
    assert np.angle(np.exp(1j * (lead - expected))) == pytest.approx(0.0, abs=0.05)
    assert 2 * abs(sine) == pytest.approx(fig10.AMPLITUDE_W, rel=0.01)


def test_example_heater_unclipped_follows_the_linear_prediction(fig10):
    """50 ohm, Kp 10: the heater is never at R I_max^2; the minimum at pi or 5 pi/4 (0.62-0.64 of PI alone),
    the opposite phases 1.4 times PI alone, each phase within 0.03 of |L_1 + H_1 a| / |L_1|."""
    ratio = ratios(fig10, fig10.EXAMPLE_HEATER, fig10.MODEL)
    best = int(np.argmin(ratio))
    assert fig10.PHASES_RAD[best] in (np.pi, 5 * np.pi / 4)
    assert ratio[best] < 0.7
    assert ratio[(best + 4) % 8] > 1.3
    predicted = fig10.linear_prediction_K(fig10.MODEL, fig10.PHASES_RAD) / abs(fig10.fundamentals(fig10.MODEL)[0])
    assert np.max(np.abs(ratio - predicted)) < 0.03


def test_paper_heater_clipped_at_170_mw_reduces_the_line_by_about_30_percent(fig10):
    """17 ohm, Kp 80: the heater is clipped at 0 W and 170 mW; the best phase still near 5 pi/4, the line
    about 30 % below PI alone there (the companion experiment's 'about 30 % less'), more at the opposite."""
    ratio = ratios(fig10, fig10.PAPER_HEATER, fig10.MODEL)
    best = int(np.argmin(ratio))
    assert fig10.PHASES_RAD[best] in (np.pi, 5 * np.pi / 4)
    assert 0.62 < ratio[best] < 0.78
    assert ratio[(best + 4) % 8] > 1.1


def test_paper_s_printed_equations_put_the_minimum_between_3pi_4_and_pi(fig10):
    """The same run on config/model-paper-printed.yaml: the paper's statement, in this phase convention."""
    ratio = ratios(fig10, fig10.PAPER_HEATER, fig10.PRINTED_MODEL)
    best = int(np.argmin(ratio))
    assert fig10.PHASES_RAD[best] in (3 * np.pi / 4, np.pi)
    assert ratio[best] < 0.8
    assert ratio[(best + 4) % 8] > 1.1
