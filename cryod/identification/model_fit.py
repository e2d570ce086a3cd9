"""The model from records, with the number of terms chosen from the data and every parameter's uncertainty.

What :func:`identify_model` fits (all records at once, taken to be from one cryostat):

* T2: ``G2 G1 = sum_i g_i / (tau_i s + 1)`` with the number of terms chosen by
  the BIC (:mod:`cryod.identification.step_terms`), jointly with the cooler
  line's complex gain from T5 to T2 (a linear coefficient on T5's measured
  fundamental), the operating point T2_0 and each record's initial state;
* T5 (its measured line removed): ``G3 = sum_j k_j / (tau_j s + 1)`` likewise,
  with T5_0;
* the cooler's line (frequency, amplitude, phase, significant harmonics) in the
  first record's T5 (:mod:`cryod.cooler.line`), with its standard errors;
* the sensor noise, the white floor of the final residuals.

G2 is the shortest term's lag and G1 the rest (only G2 G1 is observable; the
paper's choice). The link G_link follows from the line gain with the model's
heat capacity C, which records cannot give and which is kept from the base model.

Every fitted parameter carries an uncertainty (:mod:`cryod.identification.uncertainty`:
the fit's covariance, checked by a block bootstrap of the residuals); the model
returned holds them (:class:`cryod.model.uncertainty.ModelUncertainty`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from cryod.analysis.noise import white_noise_rms
from cryod.analysis.record_data import RecordData
from cryod.cooler.line import PtcLine
from cryod.identification.fit import IdentificationError, prepared_records
from cryod.identification.step_terms import (
    ChannelRecord,
    StepChannel,
    StepFitError,
    TermSelection,
    select_terms,
)
from cryod.identification.uncertainty import BOOTSTRAP_BLOCK_S, BOOTSTRAP_REPLICATES, FitUncertainty, fit_uncertainty
from cryod.model import CryostatModel, SensorNoise
from cryod.model.uncertainty import ModelUncertainty, apply_parameters, check_consistent

FLANGE_OTHER = ("ptc_line.d_real", "ptc_line.d_imaginary", "operating_point.flange_temperature_K")
STAGE_OTHER = ("operating_point.ptc_stage_temperature_K",)


@dataclass
class ChannelResult:
    """One thermometer's fit: the term selection, the uncertainties, the residuals."""

    channel: StepChannel
    selection: TermSelection
    uncertainty: FitUncertainty
    prediction_K: list[np.ndarray]        # per record, every row (NaN where invalid)
    residual_K: list[np.ndarray]

    @property
    def fit(self):
        return self.selection.chosen


@dataclass
class ModelIdentification:
    """The identified model and everything that went into it.

    Attributes
    ----------
    model : CryostatModel
        With :attr:`~cryod.model.parameters.CryostatModel.uncertainty` set.
    records : list of RecordData
    flange, stage : ChannelResult
        The T2 and T5 fits.
    line : cryod.cooler.line.PtcLine
        The first record's cooler line.
    noise_rms_K : tuple of float
        (T2, T5) white noise in the residuals.
    residual_rms_in_noise : list of tuple of float
        Per record: (T2, T5) residual rms in units of the noise.
    bootstrap_ratio : dict of str to float
        Per fitted parameter: the bootstrap's standard uncertainty over the covariance's.
    """

    model: CryostatModel
    records: list[RecordData]
    flange: ChannelResult
    stage: ChannelResult
    line: PtcLine
    noise_rms_K: tuple[float, float]
    residual_rms_in_noise: list[tuple[float, float]]
    bootstrap_ratio: dict[str, float] = dataclasses.field(default_factory=dict)

    @property
    def uncertainty(self) -> ModelUncertainty:
        uncertainty = self.model.uncertainty
        assert uncertainty is not None          # an identified model states its uncertainty
        return uncertainty

    def estimate(self, name: str) -> tuple[float, float]:
        """(value, standard uncertainty) of a stated parameter."""
        return self.uncertainty.value(name), self.uncertainty.standard_uncertainty(name)

    def derived(self) -> dict[str, tuple[float, float]]:
        """Quantities computed from the parameters, each (value, standard uncertainty), linear propagation."""
        stated = self.uncertainty
        names = stated.names
        covariance = stated.covariance
        values = np.asarray(stated.values)

        def linear(weights: dict[str, float]) -> tuple[float, float]:
            vector = np.array([weights.get(name, 0.0) for name in names])
            return float(vector @ values), math.sqrt(max(float(vector @ covariance @ vector), 0.0))

        out = {
            "heater_to_thermometer_dc_gain_K_per_W": linear(
                {n: 1.0 for n in names if n.startswith("heater_to_thermometer.gain_K_per_W.")}),
            "heater_to_ptc_stage_dc_gain_K_per_W": linear(
                {n: 1.0 for n in names if n.startswith("heater_to_ptc_stage.gain_K_per_W.")}),
        }
        real, imaginary = (names.index("ptc_line.T2_over_T5_real"), names.index("ptc_line.T2_over_T5_imaginary"))
        x, y = values[real], values[imaginary]
        block = covariance[np.ix_([real, imaginary], [real, imaginary])]
        magnitude = math.hypot(x, y)
        gradient_magnitude = np.array([x, y]) / magnitude
        gradient_lag = np.array([y, -x]) / magnitude ** 2          # lag = -atan2(y, x)
        out["ptc_line_gain_T2_over_T5"] = (magnitude, math.sqrt(gradient_magnitude @ block @ gradient_magnitude))
        out["ptc_line_T2_lag_behind_T5_rad"] = (-math.atan2(y, x), math.sqrt(gradient_lag @ block @ gradient_lag))
        return out


def _channel_records(prepared, which: str) -> list[ChannelRecord]:
    records = []
    for p in prepared:
        data = p.data
        if which == "flange":
            others = np.column_stack([p.line_phasor.real, -p.line_phasor.imag, np.ones(data.time_s.size)])
            target = data.flange_K
        else:
            others = np.ones((data.time_s.size, 1))
            target = p.stage_without_line
        records.append(ChannelRecord(data.time_s, data.heater_w, np.where(data.valid, target, np.nan), others,
                                     data.heater_change_s, data.valid))
    return records


def _channel_result(channel: StepChannel, selection: TermSelection, replicates: int, block_s: float,
                    seed: int | None) -> ChannelResult:
    fit = selection.chosen
    uncertainty = fit_uncertainty(channel, fit, replicates=replicates, block_s=block_s, seed=seed)
    design, target = channel.design(fit.time_constants_s)
    prediction = design @ fit.coefficients
    predictions, residuals, start = [], [], 0
    for record in channel.records:
        count = int(np.count_nonzero(record.rows))
        full = np.full(record.time_s.size, np.nan)
        full[record.rows] = prediction[start:start + count]
        predictions.append(full)
        residuals.append(record.target_K - full)
        start += count
    return ChannelResult(channel, selection, uncertainty, predictions, residuals)


def _measured_noise(records: list[RecordData], residuals: list[np.ndarray], line_rad_s: float) -> float:
    floors = [white_noise_rms(residual[data.valid], data.sample_interval_s, line_rad_s)
              for data, residual in zip(records, residuals)]
    return float(np.median(floors))


def identify_model(records: list[RecordData], base: CryostatModel, *, harmonics: bool = True,
                   max_terms: int = 4, replicates: int = BOOTSTRAP_REPLICATES, block_s: float = BOOTSTRAP_BLOCK_S,
                   seed: int | None = 0) -> ModelIdentification:
    """Identify the model with its uncertainties.

    Parameters
    ----------
    records : list of RecordData
        Records of one cryostat; the heater must change in them.
    base : CryostatModel
        Gives the PTC heat capacity and where the time-constant search starts.
    harmonics : bool
        Keep harmonics of the line that T5 shows above 5 standard errors.
    max_terms : int
        Most first-order terms tried for each heater path.
    replicates, block_s : int, float
        Block bootstrap of the residuals: refits and block length (s); 0 refits: covariance only.
    seed : int, optional
        The bootstrap's random draws.

    Returns
    -------
    ModelIdentification

    Raises
    ------
    IdentificationError
        When no record moves the heater, or a fit fails.
    """
    prepared = prepared_records(records, base, harmonics)
    flange_channel = StepChannel("T2 (heater to flange thermometer)", _channel_records(prepared, "flange"),
                                 FLANGE_OTHER)
    stage_channel = StepChannel("T5 (heater to PTC stage)", _channel_records(prepared, "stage"), STAGE_OTHER)
    try:
        flange_selection = select_terms(flange_channel, max_terms=max_terms,
                                        base_time_constants_s=base.heater_to_thermometer.time_constants_s)
        flange_channel.forget_responses()       # a long record's heater responses: one channel's at a time
        stage_selection = select_terms(stage_channel, max_terms=max_terms,
                                       base_time_constants_s=base.heater_to_ptc_stage.time_constants_s)
        stage_channel.forget_responses()
    except StepFitError as error:
        raise IdentificationError(str(error)) from None
    flange = _channel_result(flange_channel, flange_selection, replicates, block_s, seed)
    flange_channel.forget_responses()
    stage = _channel_result(stage_channel, stage_selection, replicates, block_s, None if seed is None else seed + 1)
    stage_channel.forget_responses()
    line = prepared[0].line
    noise = (_measured_noise(records, flange.residual_K, line.angular_frequency_rad_s),
             _measured_noise(records, stage.residual_K, line.angular_frequency_rad_s))
    first = records[0]
    names, values, covariance, ratios = _parameters(flange, stage, line, float(np.mean(first.elapsed_s[first.valid])))
    method = (f"fit covariance (Jacobian at the solution, residual variance), checked by a moving-block bootstrap "
              f"of the residuals ({flange.uncertainty.replicates} and {stage.uncertainty.replicates} refits of "
              f"{block_s:g} s blocks; a parameter whose bootstrap spread is larger beyond its sampling error takes "
              f"it); the cooler's line: standard errors of its linear fit; terms chosen by BIC "
              f"(T2 {flange.fit.count}, T5 {stage.fit.count})")
    uncertainty = ModelUncertainty.from_covariance(names, values, covariance, method)
    start = dataclasses.replace(
        base, effects=dataclasses.replace(base.effects, **{name: None for name in base.effects.present()}),
        sensor_noise=SensorNoise(*noise), uncertainty=None)
    start = line.applied_to(start).with_effects(ptc_frequency_drift=None)
    model = dataclasses.replace(apply_parameters(start, uncertainty.as_dict()), uncertainty=uncertainty)
    check_consistent(model, uncertainty)
    rms = [(float(np.sqrt(np.nanmean(f ** 2)) / noise[0]), float(np.sqrt(np.nanmean(s ** 2)) / noise[1]))
           for f, s in zip(flange.residual_K, stage.residual_K)]
    return ModelIdentification(model, list(records), flange, stage, line, noise, rms, ratios)


def _parameters(flange: ChannelResult, stage: ChannelResult, line, middle_s: float):
    """Names, values and covariance of the stated parameters, from the two channels and the line
    (measured in a record whose samples' mean elapsed time is ``middle_s``)."""
    names: list[str] = []
    rows: list[tuple[int, int]] = []          # (block, index within the block's parameter vector)
    sources: list[tuple[int, int] | None] = []

    def add_terms(result: ChannelResult, path: str, block: int):
        count = result.fit.count
        for i in range(count):
            names.append(f"{path}.time_constant_s.{i + 1}")
            rows.append((block, i))
        for i in range(count):
            names.append(f"{path}.gain_K_per_W.{i + 1}")
            rows.append((block, count + i))

    add_terms(flange, "heater_to_thermometer", 0)
    add_terms(stage, "heater_to_ptc_stage", 1)
    flange_count, stage_count = flange.fit.count, stage.fit.count
    d_real, d_imaginary, flange_offset = (flange_count + flange_count + k for k in range(3))
    stage_offset = stage_count + stage_count
    blocks = [(flange.selection.chosen, flange.uncertainty), (stage.selection.chosen, stage.uncertainty)]
    vectors = [np.concatenate([fit.time_constants_s, fit.coefficients]) for fit, _ in blocks]
    count = len(names) + 2 + 2 + 3
    transform_rows = []
    values = []
    for block, index in rows:
        weights = [np.zeros(vectors[0].size), np.zeros(vectors[1].size)]
        weights[block][index] = 1.0
        transform_rows.append(weights)
        sources.append((block, index))
    # the line gain T2/T5 = j d: real part -d_imaginary, imaginary part d_real
    for name, index, sign in (("ptc_line.T2_over_T5_real", d_imaginary, -1.0),
                              ("ptc_line.T2_over_T5_imaginary", d_real, 1.0)):
        weights = [np.zeros(vectors[0].size), np.zeros(vectors[1].size)]
        weights[0][index] = sign
        names.append(name)
        transform_rows.append(weights)
        sources.append((0, index))
    for name, block, index in (("operating_point.flange_temperature_K", 0, flange_offset),
                               ("operating_point.ptc_stage_temperature_K", 1, stage_offset)):
        weights = [np.zeros(vectors[0].size), np.zeros(vectors[1].size)]
        weights[block][index] = 1.0
        names.append(name)
        transform_rows.append(weights)
        sources.append((block, index))
    covariance = np.zeros((count, count))
    fitted = len(transform_rows)
    for a in range(fitted):
        values.append(float(sum(w @ v for w, v in zip(transform_rows[a], vectors))))
        for b in range(fitted):
            covariance[a, b] = sum(transform_rows[a][k] @ blocks[k][1].covariance @ transform_rows[b][k]
                                   for k in range(2))
    # the line: its phase is known best in the middle of the record; at the record's start (the model's
    # reference) the frequency's error adds omega_error * t_mid, fully correlated with the frequency
    fundamental = line.fundamental
    amplitude = fundamental.amplitude_K
    middle_phase_sigma = fundamental.amplitude_uncertainty_K / amplitude if amplitude > 0 else 0.0
    frequency_sigma = line.frequency_uncertainty_rad_s
    for offset, (name, value) in enumerate((("ptc.angular_frequency_rad_s", line.angular_frequency_rad_s),
                                            ("ptc.ptc_stage_amplitude_K", amplitude),
                                            ("ptc.phase_rad", fundamental.phase_rad))):
        names.append(name)
        values.append(float(value))
        sources.append(None)
    frequency, amplitude_index, phase = fitted, fitted + 1, fitted + 2
    covariance[frequency, frequency] = frequency_sigma ** 2
    covariance[amplitude_index, amplitude_index] = fundamental.amplitude_uncertainty_K ** 2
    covariance[phase, phase] = middle_phase_sigma ** 2 + (frequency_sigma * middle_s) ** 2
    covariance[phase, frequency] = covariance[frequency, phase] = -frequency_sigma ** 2 * middle_s
    ratios = {}
    for name, source in zip(names, sources):
        if source is None:
            continue
        uncertainty = blocks[source[0]][1]
        ratio = uncertainty.bootstrap_ratio(source[1] + 1)
        if ratio is not None:
            ratios[name] = float(ratio[source[1]])
    return names, values, covariance, ratios


__all__ = ["ChannelResult", "ModelIdentification", "identify_model"]
