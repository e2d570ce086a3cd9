"""Slow series measured in a record: their basis (B-splines two blocks apart) and their correlation time.

A slow change that nothing in the model makes (the cold end's drift, an
unrecorded heat load, a thermometer's offset) is fitted as a cubic B-spline
with knots two blocks apart (:func:`slow_splines`): every held-out block then
lies between fit blocks, and the spline's value there is predicted from them
(the cold end's drift cubic, the generic extension's series straight lines
between the knots).
What the model file keeps of such a series is its rms and correlation time
(:func:`correlation_time_s`), which the simulator realises as a random process
of the same spectrum (:class:`cryod.model.SlowProcess`).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import interpolate

from cryod.analysis.record_data import block_length_s


def slow_splines(data, degree: int = 3, blocks: float = 2.0) -> np.ndarray:
    """B-splines of ``degree`` on the record's time with knots ``blocks`` blocks apart, less the first (the offset
    is fitted anyway); one column per spline, one row per sample. Degree 1 (straight lines between knots at the
    blocks' edges) predicts a held-out block from the fit blocks on either side without the overshoot a cubic can
    make between fit blocks."""
    elapsed = data.elapsed_s
    spacing = blocks * block_length_s(data.duration_s)
    inner = np.arange(0.0, elapsed[-1], spacing)[1:]
    knots = np.concatenate([[elapsed[0]] * (degree + 1), inner, [elapsed[-1] + 1e-9] * (degree + 1)])
    design = interpolate.BSpline.design_matrix(elapsed, knots, degree).toarray()
    return design[:, 1:]


def correlation_time_s(values: np.ndarray, sample_interval_s: float) -> float:
    """Where a series' autocorrelation (about its mean) falls to 1/e (s); the whole length if it never does."""
    centred = np.asarray(values, dtype=float) - float(np.mean(values))
    spectrum = np.fft.rfft(centred, 2 * centred.size)
    correlation = np.fft.irfft(spectrum * np.conj(spectrum))[:centred.size]
    if correlation[0] <= 0.0:
        return sample_interval_s
    below = np.flatnonzero(correlation < correlation[0] / math.e)
    return float((below[0] if below.size else centred.size) * sample_interval_s)


def in_file_form(model):
    """``model`` with every effect measured in a record (one with a ``model_form()``: the cold end's drift, the
    generic disturbance) replaced by the form a model file holds: its statistics."""
    measured = {name: getattr(model.effects, name).model_form() for name in model.effects.present()
                if hasattr(getattr(model.effects, name), "model_form")}
    return model.with_effects(**measured) if measured else model


__all__ = ["correlation_time_s", "in_file_form", "slow_splines"]
