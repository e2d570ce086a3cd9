"""The generic extension: a data-driven model of what no cause explains, fitted and judged like a cause.

Where the extended model (the recalibration and the causes named) still shows
a discrepancy, ``cryod analyze`` extends it anyway with a low-order error model
of the heater's paths: first-order terms of fixed time constants
(:data:`TIME_CONSTANTS_S`) in parallel with G1 (heater to flange, so through
G2 and every thermometer effect to T2) and with G3 (heater to T5), the gains
free (:class:`cryod.model.HeaterPathCorrection`). Each term's response to the
record's heater is a column; the gains are linear least-squares coefficients
fitted on the fit blocks with the nuisance parameters, and the extension is
judged on the held-out blocks by the rules of a cause
(:mod:`cryod.analysis.decision`): it is added to the model when it counts
(5 sigma and an improvement of 25), with its gain. It is marked generic in the
model file (the effect ``heater_path_correction``, not a cause), and
``cryod --simulate --sim-model`` runs it like any effect.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from cryod.analysis.candidates import CandidateFit, FitContext
from cryod.analysis.decision import CandidateScore, score_candidate
from cryod.model import CryostatModel, HeaterPathCorrection, TransferFunction

#: Time constants of the correction's terms (s): log-spaced from the fastest the records resolve to the slowest.
TIME_CONSTANTS_S = tuple(float(tau) for tau in np.geomspace(1.0, 1000.0, 8))


@dataclass
class GenericExtension:
    """The generic extension fitted on top of a model.

    Attributes
    ----------
    fit : CandidateFit
        Its fit (``cause`` is ``"generic"``); the model is the extended one plus the correction.
    score : CandidateScore
        On the held-out blocks against the extended model.
    added : bool
        Whether it counts, and so is part of the extended model.
    """

    fit: CandidateFit
    score: CandidateScore
    added: bool

    def as_dict(self) -> dict:
        correction = self.fit.extended_model.effects.heater_path_correction
        return {"kind": "heater_path_correction", "generic": True, "added": self.added,
                "time_constants_s": list(correction.time_constants_s),
                "flange_gains_K_per_W": list(correction.flange_gains_K_per_W),
                "ptc_stage_gains_K_per_W": list(correction.ptc_stage_gains_K_per_W),
                "held_out_improvement": self.score.improvement, "significance": self.score.significance,
                "explained_fraction": self.score.explained_fraction, "gain": self.score.gain.as_dict()}


def _term_columns(context: FitContext, model: CryostatModel, time_constant_s: float):
    """T2's and T5's response (K) to the record's heater through ``1 / (tau s + 1)`` in place of G1 and G3."""
    lag = TransferFunction.first_order_lag(time_constant_s)
    quiet = model.with_ptc(ptc_stage_amplitude_K=0.0, harmonics=()).with_effects(
        ptc_frequency_drift=None, ptc_amplitude_modulation=None, ptc_stage_drift=None, heater_path_correction=None,
        heat_capacity_temperature=None)
    quiet = dataclasses.replace(quiet, heater_to_flange=lag, heater_to_ptc_stage=lag)
    simulated = context.replayer.simulate(quiet)
    point = quiet.operating_point
    return simulated.flange_K - point.flange_temperature_K, simulated.ptc_stage_K - point.ptc_stage_temperature_K


def fit_generic_extension(context: FitContext, base) -> GenericExtension:
    """The correction fitted on top of ``context``'s model and replay, judged against ``base`` (its discrepancy)."""
    model, replay = context.base_model, context.base_replay
    flange_columns, stage_columns = [], []
    for tau in TIME_CONSTANTS_S:
        flange, stage = _term_columns(context, model, tau)
        flange_columns.append(flange)
        stage_columns.append(stage)
    count = len(TIME_CONSTANTS_S)
    zeros = np.zeros((context.data.time_s.size, count))
    columns = (np.column_stack(flange_columns + [zeros]), np.column_stack([zeros] + stage_columns))
    fitted = context.replayer.replay_simulated(replay.model, replay.flange_K, replay.ptc_stage_K, columns)
    gains = fitted.shared_coefficients
    correction = HeaterPathCorrection(TIME_CONSTANTS_S, tuple(float(g) for g in gains[:count]),
                                      tuple(float(g) for g in gains[count:]))
    extended = model.with_effects(heater_path_correction=correction)
    fit = CandidateFit("generic", {"time_constants_s": list(TIME_CONSTANTS_S),
                                   "flange_gains_K_per_W": list(correction.flange_gains_K_per_W),
                                   "ptc_stage_gains_K_per_W": list(correction.ptc_stage_gains_K_per_W)},
                       extended, fitted, context.base_line, "generic: not a physical cause",
                       parameter_count=2 * count)
    score = score_candidate(context, fit, base)
    return GenericExtension(fit, score, score.counts)


__all__ = ["GenericExtension", "TIME_CONSTANTS_S", "fit_generic_extension"]
