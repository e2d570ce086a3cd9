"""Replay a record through a model: the simulated T2 and T5 for the record's own heater.

The simulated cryostat (:func:`cryod.model.dynamics.simulate`) is driven by the
record's ``heater_W`` column, whatever the record holds (holds, steps,
modulation, PI segments: in a PI record the heater is a feedback signal, but it
is still the input that was applied). The cooler's line is the one measured in
T5 (:mod:`cryod.analysis.ptc_line`). What the record does not say is estimated
from it, by linear least squares on the fit samples, for every model replayed
alike:

* the operating point (T2_0, T5_0): records come from other days;
* the state at the first sample, which need not be a settled one (a record
  cut from a longer log starts in the middle of a transient): the amplitude
  of each of the T2 heater path's modes (they decay with the model's own time
  constants), and for T5 the heater power its path had settled at. That
  power, found with the base model, becomes the settled power of every later
  replay (:attr:`Replayer.initial_heater_power_w`), so that models whose time
  constants depend on temperature start from the right state: a PI record that
  starts at 0 W with the heater jumping to its limit in its first row is
  replayed as it happened.

Examples
--------
>>> import numpy as np
>>> from cryod.model import load_model
>>> model = load_model()
>>> elapsed = np.array([0.0, 10.0, 1000.0])
>>> stage = stage_release_response(model, elapsed)
>>> round(float(stage[0]), 3), round(float(stage[-1]), 4)     # K per W, at the first sample and after 1000 s
(2.77, 0.0017)
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from cryod.analysis.ptc_line import PtcLine, estimate_ptc_line
from cryod.analysis.record_data import RecordData
from cryod.model import CryostatModel, OperatingPoint
from cryod.model.dynamics import flange_transfer_functions, simulate, stage_transfer_functions
from cryod.model.transfer_function import TransferFunction


def _release_response(transfer_function: TransferFunction, elapsed_s: np.ndarray) -> np.ndarray:
    """Output (per W) of a path settled at 1 W above what it gets from t = 0 on."""
    form = transfer_function.modal_form()
    elapsed_s = np.clip(elapsed_s, 0.0, None)
    response = np.zeros(elapsed_s.size)
    for pole, residue in zip(form.poles, form.residues):
        response += np.real(-residue / pole * np.exp(pole * elapsed_s))
    return response


def flange_mode_columns(model: CryostatModel, elapsed_s, sample_interval_s: float) -> np.ndarray:
    """Free decays of the T2 heater path's modes from the first sample (one column per real mode,
    two per complex pair); modes faster than two samples are left out."""
    elapsed_s = np.asarray(elapsed_s, dtype=float)
    flange_heater, _ = flange_transfer_functions(model)
    delay = model.effects.dead_time.heater_to_flange_s if model.effects.dead_time else 0.0
    shifted = np.clip(elapsed_s - delay, 0.0, None)
    columns = []
    for pole in flange_heater.modal_form().poles:
        if -1.0 / pole.real < 2.0 * sample_interval_s or pole.imag < 0.0:
            continue
        decay = np.exp(pole * shifted)
        columns.append(decay.real)
        if pole.imag > 0.0:
            columns.append(decay.imag)
    return np.column_stack(columns) if columns else np.zeros((elapsed_s.size, 0))


def stage_release_response(model: CryostatModel, elapsed_s) -> np.ndarray:
    """T5 response in K per W of delivered power to a different settled power before the record.

    (T2's initial state is fitted mode by mode instead: :func:`flange_mode_columns`.)
    """
    stage_heater, _ = stage_transfer_functions(model)
    return _release_response(stage_heater, np.asarray(elapsed_s, dtype=float))


@dataclass(frozen=True)
class Replay:
    """A model's prediction of one record.

    Attributes
    ----------
    model : CryostatModel
        The model as replayed: the measured line and the estimated operating point in it.
    flange_K, ptc_stage_K : numpy.ndarray
        Predicted T2 and T5 at every sample (K).
    flange_residual_K, ptc_stage_residual_K : numpy.ndarray
        Measured minus predicted (NaN where a reading is missing).
    shared_coefficients : numpy.ndarray
        Coefficients of the extra columns fitted jointly (empty if none).
    initial_power_offset_w : float
        Settled power of T5's heater path before the record, less the power
        the replay assumed (W).
    """

    model: CryostatModel
    flange_K: np.ndarray
    ptc_stage_K: np.ndarray
    flange_residual_K: np.ndarray
    ptc_stage_residual_K: np.ndarray
    shared_coefficients: np.ndarray
    initial_power_offset_w: float = 0.0

    @property
    def operating_point(self) -> OperatingPoint:
        return self.model.operating_point


class Replayer:
    """Replays one record through models, fitting the nuisance parameters on the fit samples.

    Parameters
    ----------
    data : RecordData
    fit_mask : numpy.ndarray of bool
        Samples the nuisance parameters (and any candidate parameters) are fitted on.
    noise_rms_K : tuple of float, optional
        (T2, T5) noise used to weight the two thermometers when columns are
        fitted jointly; set once measured.
    """

    def __init__(self, data: RecordData, fit_mask: np.ndarray, noise_rms_K: tuple[float, float] = (20e-6, 0.3e-3)):
        self.data = data
        self.fit_mask = np.asarray(fit_mask, dtype=bool) & data.valid
        self.noise_rms_K = noise_rms_K
        #: Heater power the cryostat had settled at before the first sample (W); None: the first sample's.
        self.initial_heater_power_w: float | None = None

    def settle_from(self, replay: Replay) -> None:
        """Take the settled power before the record from a replay's T5 initial-state estimate."""
        start = self.initial_heater_power_w if self.initial_heater_power_w is not None else float(self.data.heater_w[0])
        self.initial_heater_power_w = max(start + replay.initial_power_offset_w, 0.0)

    # -- the line ----------------------------------------------------------
    def stage_line(self, model: CryostatModel, *, orders=(1,), drift: bool = False,
                   angular_frequency_rad_s: float | None = None, significant_only: bool = False) -> PtcLine:
        """Measure the PTC line in T5 less the model's heater-driven part, on the fit samples."""
        data = self.data
        quiet = model.with_ptc(ptc_stage_amplitude_K=0.0, harmonics=()).with_effects(ptc_frequency_drift=None)
        heater_part = self.simulate(quiet).ptc_stage_K - quiet.operating_point.ptc_stage_temperature_K
        release = stage_release_response(model, data.elapsed_s)
        valid = data.valid
        baseline = np.column_stack([np.ones(valid.sum()), release[valid]])
        return estimate_ptc_line(
            data.elapsed_s[valid], data.ptc_stage_K[valid] - heater_part[valid], baseline,
            mask=self.fit_mask[valid], orders=orders, drift=drift,
            angular_frequency_rad_s=angular_frequency_rad_s, significant_only=significant_only)

    # -- replay ------------------------------------------------------------
    def simulate(self, model: CryostatModel, heater_power_w=None, initial_heater_power_w=None):
        """The simulator on the record's instants (no noise).

        By default driven by the record's heater, settled at
        :attr:`initial_heater_power_w` before the first sample.
        """
        if heater_power_w is None:
            heater_power_w, initial_heater_power_w = self.data.heater_w, self.initial_heater_power_w
        return simulate(model, self.data.time_s, heater_power_w, initial_heater_power_w=initial_heater_power_w,
                        heater_change_s=self.data.heater_change_s)

    def replay(self, model: CryostatModel, line: PtcLine | None = None, shared_columns=None) -> Replay:
        """Predict the record with ``model`` (and the measured ``line``).

        Parameters
        ----------
        model : CryostatModel
        line : PtcLine, optional
            The measured line; None keeps the model's own PTC source.
        shared_columns : tuple of numpy.ndarray, optional
            (T2 columns, T5 columns), each n x m: extra regressors whose m
            coefficients are fitted jointly on both thermometers, weighted by
            their noise (e.g. a linear effect's response).

        Returns
        -------
        Replay
        """
        aligned = line.applied_to(model) if line is not None else model
        simulated = self.simulate(aligned)
        return self.replay_simulated(aligned, simulated.flange_K, simulated.ptc_stage_K, shared_columns)

    def replay_simulated(self, aligned: CryostatModel, flange_K: np.ndarray, stage_K: np.ndarray,
                         shared_columns=None) -> Replay:
        """Fit the nuisance parameters to a simulation already made."""
        data = self.data
        stage_release = stage_release_response(aligned, data.elapsed_s)
        modes = flange_mode_columns(aligned, data.elapsed_s, data.sample_interval_s)
        count = data.time_s.size
        flange_columns = 1 + modes.shape[1]                 # offset, mode amplitudes
        flange_design = np.column_stack([np.ones(count), modes, np.zeros((count, 2))])
        stage_design = np.column_stack([np.zeros((count, flange_columns)), np.ones(count), stage_release])
        shared = 0
        if shared_columns is not None:
            flange_extra = np.asarray(shared_columns[0], dtype=float).reshape(count, -1)
            stage_extra = np.asarray(shared_columns[1], dtype=float).reshape(count, -1)
            shared = flange_extra.shape[1]
            flange_design = np.column_stack([flange_design, flange_extra])
            stage_design = np.column_stack([stage_design, stage_extra])
        flange_weight, stage_weight = 1.0 / self.noise_rms_K[0], 1.0 / self.noise_rms_K[1]
        rows = self.fit_mask
        design = np.vstack([flange_design[rows] * flange_weight, stage_design[rows] * stage_weight])
        target = np.concatenate([(data.flange_K - flange_K)[rows] * flange_weight,
                                 (data.ptc_stage_K - stage_K)[rows] * stage_weight])
        solution, *_ = np.linalg.lstsq(design, target, rcond=None)
        flange_predicted = flange_K + flange_design @ solution
        stage_predicted = stage_K + stage_design @ solution
        point = aligned.operating_point
        estimated = OperatingPoint(point.flange_temperature_K + float(solution[0]),
                                   point.ptc_stage_temperature_K + float(solution[flange_columns]))
        return Replay(
            model=replace(aligned, operating_point=estimated),
            flange_K=flange_predicted,
            ptc_stage_K=stage_predicted,
            flange_residual_K=data.flange_K - flange_predicted,
            ptc_stage_residual_K=data.ptc_stage_K - stage_predicted,
            shared_coefficients=solution[flange_columns + 2:flange_columns + 2 + shared],
            initial_power_offset_w=float(solution[flange_columns + 1]),
        )
