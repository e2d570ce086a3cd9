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
  (:func:`cryod.model.transfer_function.first_order_link`, with the model's heat
  capacity C, which only scales the link and is kept from the base model);
* the operating point (T2_0, T5_0), shared by the records;
* per record, the state at the first sample: each mode's amplitude, free;
* the cooler's line (frequency, amplitude, phase at the first record's start,
  significant harmonics) from the first record's T5 (:mod:`cryod.cooler.line`);
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

from cryod.analysis.noise import white_noise_rms
from cryod.analysis.record_data import RecordData
from cryod.analysis.replay import Replayer
from cryod.cooler.line import PtcLine, measurable_orders
from cryod.model import CryostatModel, OperatingPoint, SensorNoise
from cryod.model.heater_path import HeaterPath
from cryod.model.transfer_function import TransferFunction, first_order_link

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


def prepared_records(records, base: CryostatModel, harmonics: bool) -> list[_Prepared]:
    """Each record with its cooler line measured and taken out; refused when none moves the heater.

    Raises
    ------
    IdentificationError
        No records, or the heater never changes in any of them.
    """
    if not records:
        raise IdentificationError("no records given")
    if all(np.ptp(data.heater_w) <= 0.0 for data in records):
        raise IdentificationError("the heater never changes in these records: the heater paths cannot be identified "
                                  "(record heater steps, modulation or a PI setpoint change)")
    return [_prepare(data, base, harmonics) for data in records]


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
    """The variable-projection least-squares problem over all records.

    The heater-to-T2 and heater-to-T5 parts share no coefficient, so each is
    its own problem: T2's residuals depend on (tau_a, tau_b) alone, T5's on
    tau_3 alone. Each part's linear coefficients are solved on a design
    matrix of its own (samples x its coefficients); the responses to the
    heater are kept for the last few time constants, as the Jacobian moves one
    time constant at a time. Coefficients, in
    the order of :attr:`solution`: r_a, r_b, k3, Re d, Im d, T2_0, T5_0, then
    per record the amplitudes of the three free decays.
    """

    #: Heater responses kept (each one float per sample of each record).
    KEPT_RESPONSES = 8

    def __init__(self, prepared: list[_Prepared], noise_rms_K: tuple[float, float]):
        self.prepared = prepared
        self.noise_rms_K = noise_rms_K
        self.valid = [p.data.valid for p in prepared]
        self.counts = [int(np.count_nonzero(valid)) for valid in self.valid]
        self.solution: np.ndarray | None = None
        self._responses: dict[tuple[int, float], np.ndarray] = {}
        self._flange: tuple | None = None      # ((tau_a, tau_b), coefficients, residual in K)
        self._stage: tuple | None = None       # (tau_3, coefficients, residual in K)

    def _response(self, index: int, time_constant_s: float) -> np.ndarray:
        """Record ``index``'s response to its heater through 1/(tau s + 1), on its valid samples."""
        key = (index, time_constant_s)
        if key not in self._responses:
            if len(self._responses) >= self.KEPT_RESPONSES * len(self.prepared):
                del self._responses[next(iter(self._responses))]
            data = self.prepared[index].data
            self._responses[key] = _lag_response(data.time_s, data.heater_w, time_constant_s)[self.valid[index]]
        return self._responses[key]

    def _solve_flange(self, tau_a: float, tau_b: float):
        """T2 = r_a x_a + r_b x_b + Re(d B e^{j..}) + T2_0 + per record, its two decays."""
        if self._flange is not None and self._flange[0] == (tau_a, tau_b):
            return self._flange
        records = len(self.prepared)
        design = np.zeros((sum(self.counts), 5 + 2 * records))
        target = np.empty(design.shape[0])
        start = 0
        for index, (prepared, valid, count) in enumerate(zip(self.prepared, self.valid, self.counts)):
            rows = slice(start, start + count)
            elapsed = prepared.data.elapsed_s[valid]
            design[rows, 0] = self._response(index, tau_a)
            design[rows, 1] = self._response(index, tau_b)
            design[rows, 2] = prepared.line_phasor.real[valid]
            design[rows, 3] = -prepared.line_phasor.imag[valid]
            design[rows, 4] = 1.0
            design[rows, 5 + 2 * index] = np.exp(-elapsed / tau_a)
            design[rows, 6 + 2 * index] = np.exp(-elapsed / tau_b)
            target[rows] = prepared.data.flange_K[valid]
            start += count
        coefficients, *_ = np.linalg.lstsq(design, target, rcond=None)
        target -= design @ coefficients
        self._flange = ((tau_a, tau_b), coefficients, target)
        return self._flange

    def _solve_stage(self, tau_3: float):
        """T5 less its line = k3 x_3 + T5_0 + per record, its decay."""
        if self._stage is not None and self._stage[0] == tau_3:
            return self._stage
        records = len(self.prepared)
        design = np.zeros((sum(self.counts), 2 + records))
        target = np.empty(design.shape[0])
        start = 0
        for index, (prepared, valid, count) in enumerate(zip(self.prepared, self.valid, self.counts)):
            rows = slice(start, start + count)
            design[rows, 0] = self._response(index, tau_3)
            design[rows, 1] = 1.0
            design[rows, 2 + index] = np.exp(-prepared.data.elapsed_s[valid] / tau_3)
            target[rows] = prepared.stage_without_line[valid]
            start += count
        coefficients, *_ = np.linalg.lstsq(design, target, rcond=None)
        target -= design @ coefficients
        self._stage = (tau_3, coefficients, target)
        return self._stage

    def _solve(self, time_constants):
        tau_a, tau_b, tau_3 = (float(t) for t in time_constants)
        _, flange, flange_residual = self._solve_flange(tau_a, tau_b)
        _, stage, stage_residual = self._solve_stage(tau_3)
        records = len(self.prepared)
        solution = np.empty(7 + 3 * records)
        solution[[0, 1, 3, 4, 5]] = flange[:5]
        solution[[2, 6]] = stage[:2]
        solution[7::3], solution[8::3], solution[9::3] = flange[5::2], flange[6::2], stage[2:]
        self.solution = solution
        return flange_residual, stage_residual

    def flange_residual(self, log_time_constants) -> np.ndarray:
        """T2's residuals in units of its noise, for log(tau_a), log(tau_b)."""
        tau_a, tau_b = np.exp(log_time_constants)
        return self._solve_flange(float(tau_a), float(tau_b))[2] / self.noise_rms_K[0]

    def stage_residual(self, log_time_constants) -> np.ndarray:
        """T5's residuals in units of its noise, for log(tau_3)."""
        return self._solve_stage(float(np.exp(log_time_constants[0])))[2] / self.noise_rms_K[1]

    def split_residuals(self, time_constants):
        """Per record: (T2 residual, T5 residual) in K on its valid samples."""
        flange, stage = self._solve(time_constants)
        bounds = np.cumsum([0] + self.counts)
        return [(flange[start:end], stage[start:end]) for start, end in zip(bounds[:-1], bounds[1:])]


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
    prepared = prepared_records(records, base, harmonics)
    taus = sorted(base.heater_to_thermometer.time_constants_s)
    stage_taus = base.heater_to_ptc_stage.time_constants_s
    if len(taus) != 2 or len(stage_taus) != 1:
        taus, stage_taus = [20.0, 200.0], [100.0]
    problem = _Problem(prepared, (base.sensor_noise.flange_thermometer_rms_K,
                                  base.sensor_noise.ptc_stage_thermometer_rms_K))
    bounds = (np.log(TIME_CONSTANT_BOUNDS_S[0]), np.log(TIME_CONSTANT_BOUNDS_S[1]))
    flange_start, stage_start = np.log(taus), np.log(stage_taus)
    for _ in range(2):                      # second pass with the noise measured in the first pass's residuals
        # T2's part and T5's part share no coefficient: two problems, each with its own residuals
        flange = optimize.least_squares(problem.flange_residual, flange_start, bounds=bounds, x_scale=1.0,
                                        method="trf", max_nfev=200)
        stage = optimize.least_squares(problem.stage_residual, stage_start, bounds=bounds, x_scale=1.0,
                                       method="trf", max_nfev=200)
        for result in (flange, stage):
            if not np.all(np.isfinite(result.x)):
                raise IdentificationError(f"the fit did not converge: {result.message}")
        flange_start, stage_start = flange.x, stage.x
        time_constants = np.exp(np.concatenate([flange.x, stage.x]))
        residuals = problem.split_residuals(time_constants)
        problem.noise_rms_K = _measured_noise(prepared, residuals)
    return _assemble(prepared, problem, time_constants, residuals, base)


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
    assert solution is not None             # the problem was solved at these time constants
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
