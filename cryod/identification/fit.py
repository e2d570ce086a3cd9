"""Identify the cryostat model from measured records.

What is fitted, all records at once (they are taken to be from one cryostat):

* heater to T2, ``G2 G1 = r_a / (tau_a s + 1) + r_b / (tau_b s + 1)``: the two
  time constants by :func:`scipy.optimize.least_squares` (in log), the two
  residues by linear least squares inside each evaluation (variable
  projection); the response to the record's heater is the simulator's exact
  zero-order hold (:class:`cryod.model.heater_path.HeaterPath`);
* heater to T5, ``G3 = k3 / (tau_3 s + 1)``, the same way;
* the PTC line's complex gain from T5 to T2 at the line, a linear
  coefficient: it gives ``G2 G_link`` at the line, hence the link
  (:func:`cryod.analysis.candidates.first_order_link`, with the model's heat
  capacity C, which only scales the link and is kept from the base model);
* the operating point (T2_0, T5_0), shared by the records;
* per record, the state at the first sample: each mode's amplitude, free;
* the cooler's line (frequency, amplitude, phase at the first record's start,
  significant harmonics) from the first record's T5 (:mod:`cryod.analysis.ptc_line`);
* the sensor noise, from the final residuals (:mod:`cryod.analysis.noise`).

Which time constant belongs to G2 (flange to thermometer) cannot be told from
the records (only G2 G1 is observable); as in the paper, the shorter one is
G2's, ``G2 = 1 / (tau_short s + 1)`` and ``G1`` holds the rest.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy import optimize

from cryod.analysis.candidates import first_order_link
from cryod.analysis.noise import white_noise_rms
from cryod.analysis.ptc_line import PtcLine, measurable_orders
from cryod.analysis.record_data import RecordData
from cryod.analysis.replay import Replayer
from cryod.model import CryostatModel, OperatingPoint, SensorNoise
from cryod.model.heater_path import HeaterPath
from cryod.model.transfer_function import TransferFunction

#: Time constants are searched within these bounds (s).
TIME_CONSTANT_BOUNDS_S = (0.5, 20000.0)


class IdentificationError(ValueError):
    """The records cannot determine the model (too little excitation, a failed fit)."""


@dataclass
class _Prepared:
    """One record made ready: its line measured in T5 and removed."""

    data: RecordData
    line: PtcLine
    stage_without_line: np.ndarray
    line_phasor: np.ndarray           # B e^{j(theta + phi)} of the fundamental, per sample


@dataclass(frozen=True)
class Identification:
    """The identified model and how well it fits.

    Attributes
    ----------
    model : CryostatModel
    flange_time_constants_s : tuple of float
        The two time constants of G2 G1 (short, long).
    flange_residues_K_per_W : tuple of float
        Their static gains, summing to G2 G1's DC gain.
    stage_gain_K_per_W, stage_time_constant_s : float
        G3.
    ptc_gain_at_line : complex
        T2 line over T5 line (complex amplitudes) at the fundamental.
    noise_rms_K : tuple of float
        (T2, T5) white noise measured in the residuals.
    residual_rms_in_noise : list of tuple of float
        Per record: (T2, T5) residual rms in units of the noise (1 = noise only).
    """

    model: CryostatModel
    flange_time_constants_s: tuple[float, float]
    flange_residues_K_per_W: tuple[float, float]
    stage_gain_K_per_W: float
    stage_time_constant_s: float
    ptc_gain_at_line: complex
    noise_rms_K: tuple[float, float]
    residual_rms_in_noise: list[tuple[float, float]]


def _prepare(data: RecordData, base: CryostatModel, harmonics: bool) -> _Prepared:
    replayer = Replayer(data, np.ones(data.time_s.size, dtype=bool))
    orders = measurable_orders(base.ptc.angular_frequency_rad_s, data.sample_interval_s) if harmonics else (1,)
    line = replayer.stage_line(base, orders=orders, significant_only=True)
    phase = line.phase_rad(data.elapsed_s)
    oscillation = sum(c.amplitude_K * np.sin(c.order * phase + c.phase_rad) for c in line.components)
    fundamental = line.fundamental
    phasor = fundamental.amplitude_K * np.exp(1j * (phase + fundamental.phase_rad))
    return _Prepared(data, line, data.ptc_stage_K - oscillation, phasor)


def _lag_response(time_s: np.ndarray, heater_w: np.ndarray, time_constant_s: float) -> np.ndarray:
    """Response of 1/(tau s + 1) to the held heater power, settled at the first power."""
    path = HeaterPath(TransferFunction.first_order_lag(time_constant_s))
    path.settle(float(heater_w[0]))
    return path.run(np.diff(time_s), heater_w[:-1])


class _Problem:
    """The variable-projection least-squares problem over all records."""

    def __init__(self, prepared: list[_Prepared], noise_rms_K: tuple[float, float]):
        self.prepared = prepared
        self.noise_rms_K = noise_rms_K
        self.valid = [p.data.valid for p in prepared]
        self.solution = None

    def design(self, time_constants):
        tau_a, tau_b, tau_3 = time_constants
        records = len(self.prepared)
        shared = 5          # r_a, r_b, k3, Re d, Im d
        columns = shared + 2 + 3 * records
        blocks, targets = [], []
        flange_weight, stage_weight = 1.0 / self.noise_rms_K[0], 1.0 / self.noise_rms_K[1]
        for index, (prepared, valid) in enumerate(zip(self.prepared, self.valid)):
            data = prepared.data
            t, heater, elapsed = data.time_s, data.heater_w, data.elapsed_s
            count = int(np.count_nonzero(valid))
            flange = np.zeros((count, columns))
            stage = np.zeros((count, columns))
            flange[:, 0] = _lag_response(t, heater, tau_a)[valid]
            flange[:, 1] = _lag_response(t, heater, tau_b)[valid]
            stage[:, 2] = _lag_response(t, heater, tau_3)[valid]
            flange[:, 3] = prepared.line_phasor.real[valid]
            flange[:, 4] = -prepared.line_phasor.imag[valid]
            flange[:, 5] = 1.0
            stage[:, 6] = 1.0
            base = shared + 2 + 3 * index
            flange[:, base] = np.exp(-elapsed[valid] / tau_a)
            flange[:, base + 1] = np.exp(-elapsed[valid] / tau_b)
            stage[:, base + 2] = np.exp(-elapsed[valid] / tau_3)
            blocks += [flange * flange_weight, stage * stage_weight]
            targets += [data.flange_K[valid] * flange_weight, prepared.stage_without_line[valid] * stage_weight]
        return np.vstack(blocks), np.concatenate(targets)

    def residual(self, log_time_constants) -> np.ndarray:
        design, target = self.design(np.exp(log_time_constants))
        solution, *_ = np.linalg.lstsq(design, target, rcond=None)
        self.solution = solution
        return target - design @ solution

    def split_residuals(self, time_constants):
        """Per record: (T2 residual, T5 residual) in K on its valid samples."""
        design, target = self.design(time_constants)
        solution, *_ = np.linalg.lstsq(design, target, rcond=None)
        residual = target - design @ solution
        self.solution = solution
        out, start = [], 0
        for valid in self.valid:
            count = int(np.count_nonzero(valid))
            out.append((residual[start:start + count] * self.noise_rms_K[0],
                        residual[start + count:start + 2 * count] * self.noise_rms_K[1]))
            start += 2 * count
        return out


def identify(records: list[RecordData], base: CryostatModel, harmonics: bool = True) -> Identification:
    """Fit the model's transfer functions, operating point and PTC source to records.

    Parameters
    ----------
    records : list of RecordData
        Records of one cryostat; the heater must change in them (steps,
        modulation or PI segments).
    base : CryostatModel
        Starting point of the fit, and the source of what records cannot
        give (the PTC heat capacity C).
    harmonics : bool
        Keep harmonics of the line that T5 shows above 5 standard errors.

    Returns
    -------
    Identification

    Raises
    ------
    IdentificationError
        When no record moves the heater, or the fit does not converge.
    """
    if not records:
        raise IdentificationError("no records given")
    if all(np.ptp(data.heater_w) <= 0.0 for data in records):
        raise IdentificationError("the heater never changes in these records: the heater paths cannot be identified "
                                  "(record heater steps, modulation or a PI setpoint change)")
    prepared = [_prepare(data, base, harmonics) for data in records]
    taus = sorted(base.heater_to_thermometer.time_constants_s)
    stage_taus = base.heater_to_ptc_stage.time_constants_s
    if len(taus) != 2 or len(stage_taus) != 1:
        taus, stage_taus = [20.0, 200.0], [100.0]
    start = np.log([taus[0], taus[1], stage_taus[0]])
    problem = _Problem(prepared, (base.sensor_noise.flange_thermometer_rms_K,
                                  base.sensor_noise.ptc_stage_thermometer_rms_K))
    bounds = (np.log(TIME_CONSTANT_BOUNDS_S[0]), np.log(TIME_CONSTANT_BOUNDS_S[1]))
    result = None
    for _ in range(2):                      # second pass with the noise measured in the first pass's residuals
        result = optimize.least_squares(problem.residual, start, bounds=bounds, x_scale=1.0, method="trf",
                                        max_nfev=200)
        if not np.all(np.isfinite(result.x)):
            raise IdentificationError(f"the fit did not converge: {result.message}")
        start = result.x
        residuals = problem.split_residuals(np.exp(result.x))
        problem.noise_rms_K = _measured_noise(prepared, residuals)
    return _assemble(prepared, problem, np.exp(result.x), residuals, base)


def _measured_noise(prepared: list[_Prepared], residuals) -> tuple[float, float]:
    flange, stage = [], []
    for p, (flange_residual, stage_residual) in zip(prepared, residuals):
        frequency = p.line.angular_frequency_rad_s
        flange.append(white_noise_rms(flange_residual, p.data.sample_interval_s, frequency))
        stage.append(white_noise_rms(stage_residual, p.data.sample_interval_s, frequency))
    return float(np.median(flange)), float(np.median(stage))


def _assemble(prepared, problem: _Problem, time_constants, residuals, base: CryostatModel) -> Identification:
    tau_a, tau_b, tau_3 = (float(t) for t in time_constants)
    solution = problem.solution
    residue_a, residue_b, stage_gain = float(solution[0]), float(solution[1]), float(solution[2])
    ptc_coefficient = complex(solution[3], solution[4])
    if tau_a > tau_b:
        tau_a, tau_b, residue_a, residue_b = tau_b, tau_a, residue_b, residue_a
    # G2 G1 = r_a/(tau_a s + 1) + r_b/(tau_b s + 1); G2 = 1/(tau_a s + 1), G1 = (r_a (tau_b s + 1) + r_b (tau_a s + 1))/(tau_b s + 1)
    flange_to_thermometer = TransferFunction((1.0,), (tau_a, 1.0))
    heater_to_flange = TransferFunction((residue_a * tau_b + residue_b * tau_a, residue_a + residue_b), (tau_b, 1.0))
    heater_to_stage = TransferFunction((stage_gain,), (tau_3, 1.0))
    first = prepared[0].line
    omega = first.angular_frequency_rad_s
    capacity = base.ptc.heat_capacity_J_per_K
    # T2 line = Re(d B e^{j(theta+phi)}), and the plant's T2 line is Re(H_q(j w) C w B e^{j(theta+phi)})
    heat_path_at_line = ptc_coefficient / (capacity * omega)
    link = first_order_link(heat_path_at_line / flange_to_thermometer.frequency_response(omega), omega)
    point = OperatingPoint(float(solution[5]), float(solution[6]))
    model = dataclasses.replace(
        base,
        operating_point=point,
        heater_to_flange=heater_to_flange,
        flange_to_thermometer=flange_to_thermometer,
        heater_to_ptc_stage=heater_to_stage,
        ptc_to_flange=link,
        effects=dataclasses.replace(base.effects, **{name: None for name in base.effects.present()}),
        sensor_noise=SensorNoise(problem.noise_rms_K[0], problem.noise_rms_K[1]),
    )
    model = first.applied_to(model).with_effects(ptc_frequency_drift=None)
    rms = [(float(np.sqrt(np.mean(f ** 2)) / problem.noise_rms_K[0]),
            float(np.sqrt(np.mean(s ** 2)) / problem.noise_rms_K[1])) for f, s in residuals]
    # the gain from the T5 line (Re(-j B e^{j..})) to the T2 line (Re(d B e^{j..})): d / (-j) = j d
    return Identification(model, (tau_a, tau_b), (residue_a, residue_b), stage_gain, tau_3, 1j * ptc_coefficient,
                          problem.noise_rms_K, rms)


__all__ = ["Identification", "IdentificationError", "identify"]
