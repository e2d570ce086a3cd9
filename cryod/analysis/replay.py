"""Replay a record through a model: the simulated T2 and T5 for the record's own heater.

The simulated cryostat (:func:`cryod.model.dynamics.simulate`) is driven by the
record's ``heater_W`` column, whatever the record holds (holds, steps,
modulation, PI segments: in a PI record the heater is a feedback signal, but it
is still the input that was applied). The cooler's line is the one measured in
T5 (:mod:`cryod.cooler.line`). What the record does not say is estimated
from it, by linear least squares on the fit samples, for every model replayed
alike:

* the operating point (T2_0, T5_0): records come from other days;
* the state at the first sample, which need not be a settled one (a record
  cut from a longer log starts in the middle of a transient): the amplitude
  of each of the T2 heater path's modes (they decay with the model's own time
  constants; a penalty of width :data:`INITIAL_STATE_WIDTH_K` prefers a settled
  start where the record cannot tell, e.g. a PI record whose start looks like a
  step of a different static gain), and for T5 the heater power its path had settled at. That
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

from dataclasses import dataclass, field, replace

import numpy as np
from scipy import optimize

from cryod.analysis.record_data import RecordData
from cryod.cooler.line import PtcLine, estimate_ptc_line, measured_cycle
from cryod.model import CryostatModel, OperatingPoint
from cryod.model.cooler_cycle import MeasuredCoolerCycle
from cryod.model.dynamics import flange_transfer_functions, simulate, stage_transfer_functions
from cryod.model.kept_results import KeptResults, digest
from cryod.model.transfer_function import TransferFunction

#: Free decays and release responses of the last models' paths over the last records (the analysis replays one
#: record through many models that share their heater paths).
_FREE_RESPONSES = KeptResults(16)


def _release_response(transfer_function: TransferFunction, elapsed_s: np.ndarray) -> np.ndarray:
    """Output (per W) of a path settled at 1 W above what it gets from t = 0 on (kept, read-only)."""
    form = transfer_function.modal_form()

    def made():
        elapsed = np.clip(elapsed_s, 0.0, None)
        response = np.zeros(elapsed.size)
        for pole, residue in zip(form.poles, form.residues):
            response += np.real(-residue / pole * np.exp(pole * elapsed))
        return response

    return _FREE_RESPONSES.get_or_make(digest("release", form.poles, form.residues, elapsed_s), made)


def flange_mode_columns(model: CryostatModel, elapsed_s, sample_interval_s: float) -> np.ndarray:
    """Free decays of the T2 heater path's modes from the first sample (one column per real mode,
    two per complex pair); modes faster than two samples are left out. Kept, read-only."""
    elapsed_s = np.asarray(elapsed_s, dtype=float)
    flange_heater, _ = flange_transfer_functions(model)
    delay = model.effects.dead_time.heater_to_flange_s if model.effects.dead_time else 0.0
    poles = flange_heater.modal_form().poles

    def made():
        shifted = np.clip(elapsed_s - delay, 0.0, None)
        columns = []
        for pole in poles:
            if -1.0 / pole.real < 2.0 * sample_interval_s or pole.imag < 0.0:
                continue
            decay = np.exp(pole * shifted)
            columns.append(decay.real)
            if pole.imag > 0.0:
                columns.append(decay.imag)
        return np.column_stack(columns) if columns else np.zeros((elapsed_s.size, 0))

    return _FREE_RESPONSES.get_or_make(digest("modes", poles, delay, sample_interval_s, elapsed_s), made)


def stage_release_response(model: CryostatModel, elapsed_s) -> np.ndarray:
    """T5 response in K per W of delivered power to a different settled power before the record.

    (T2's initial state is fitted mode by mode instead: :func:`flange_mode_columns`.)
    """
    stage_heater, _ = stage_transfer_functions(model)
    return _release_response(stage_heater, np.asarray(elapsed_s, dtype=float))


#: Kept mode and release columns whose fit rows a replayer keeps.
ROWS_KEPT = 16
#: Bases whose columns on the fit rows a replayer keeps (the recalibration's, in the replays of one search).
BASES_KEPT = 8

#: The T2 modes' amplitudes at the first sample are free, with a penalty (a / width)^2 that prefers a settled
#: start where the record cannot tell (a record starting inside a transient shows it at thousands of sigma).
INITIAL_STATE_WIDTH_K = 0.01


@dataclass(frozen=True)
class LinearBasis:
    """A linearised change of the model, fitted jointly with the nuisance parameters of every replay.

    The recalibration (:mod:`cryod.analysis.recalibration`) hands one to the
    :class:`Replayer`: the change of the predicted T2 and T5 per unit of each
    of its parameters, taken at the parameters' present values. A replay then
    fits the parameters' changes by the same weighted least squares as the
    operating point and the initial state, held within their bounds, with a
    penalty ``sum((value / width)^2)`` that decides between fits the data
    cannot tell apart (the smaller change is taken).

    Attributes
    ----------
    names : tuple of str
    flange_columns, stage_columns : numpy.ndarray
        n x p: change of T2 and of T5 (K) per unit change of each parameter.
    values : numpy.ndarray
        The parameters' values where the columns were taken (the fit finds the change from these).
    lower, upper : numpy.ndarray
        Bounds on each parameter's value.
    widths : numpy.ndarray
        Width of each parameter's penalty (same units as the value).
    """

    names: tuple
    flange_columns: np.ndarray
    stage_columns: np.ndarray
    values: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    widths: np.ndarray

    #: The bases :meth:`without` made, by the names left out (each made once: every replay of a candidate asks).
    _without: dict = field(init=False, default_factory=dict, repr=False, compare=False)

    def without(self, names) -> "LinearBasis | None":
        """The same basis without the named parameters (None if nothing is left)."""
        key = frozenset(names)
        if key not in self._without:
            self._without[key] = self._made_without(key)
        return self._without[key]

    def _made_without(self, names: frozenset) -> "LinearBasis | None":
        keep = [index for index, name in enumerate(self.names) if name not in names]
        if not keep:
            return None
        return LinearBasis(tuple(self.names[i] for i in keep), self.flange_columns[:, keep],
                           self.stage_columns[:, keep], self.values[keep], self.lower[keep], self.upper[keep],
                           self.widths[keep])


def solve_with_basis(gram: np.ndarray, basis_index: slice | None = None, basis: LinearBasis | None = None):
    """Linear least squares from the normal equations, the basis's coefficients bounded and penalised.

    Parameters
    ----------
    gram : numpy.ndarray
        ``[A b]^T [A b]`` of the weighted design A (m x n) and target b: (n + 1) x (n + 1).
    basis_index : slice, optional
        The columns of A that are the basis's.
    basis : LinearBasis, optional

    Returns
    -------
    solution : numpy.ndarray
    penalty : float
        The basis's penalty at the solution.
    normal_inverse : numpy.ndarray
        Inverse of ``A^T A`` (the covariance of the solution for unit-variance rows); NaN if singular.

    Notes
    -----
    The columns are scaled to unit norm first; the residuals are computed by the
    caller from the design itself, so the normal equations only choose the
    coefficients.
    """
    count = gram.shape[0] - 1
    normal, right = gram[:count, :count].copy(), gram[:count, count].copy()
    scale = np.sqrt(np.diag(normal))
    scale[scale <= 0.0] = 1.0
    data_normal = normal / np.outer(scale, scale)
    normal = data_normal.copy()
    right /= scale
    if basis is not None:
        columns = np.arange(count)[basis_index]
        widths = basis.widths * scale[columns]
        normal[columns, columns] += 1.0 / widths ** 2
        right[columns] -= basis.values * scale[columns] / widths ** 2
    solution = _solve_symmetric(normal, right)
    if basis is not None:
        change = solution[basis_index] / scale[basis_index]
        lower, upper = basis.lower - basis.values, basis.upper - basis.values
        if np.any(change < lower - 1e-12) or np.any(change > upper + 1e-12):
            low, high = np.full(count, -np.inf), np.full(count, np.inf)
            low[basis_index] = np.minimum(lower, 0.0) * scale[basis_index]
            high[basis_index] = np.maximum(upper, 0.0) * scale[basis_index]
            factor = _cholesky_factor(normal)
            target = np.linalg.solve(factor.T, right)
            solution = optimize.lsq_linear(factor, target, bounds=(low, high), method="bvls").x
    solution = solution / scale
    penalty = 0.0
    if basis is not None:
        penalty = float(np.sum(((basis.values + solution[basis_index]) / basis.widths) ** 2))
    try:
        inverse = np.linalg.inv(data_normal) / np.outer(scale, scale)
    except np.linalg.LinAlgError:
        inverse = np.full((count, count), np.nan)
    return solution, penalty, inverse


def _cholesky_factor(normal: np.ndarray) -> np.ndarray:
    """Upper triangular R with R^T R = normal (a little ridge if it is singular)."""
    try:
        return np.linalg.cholesky(normal).T
    except np.linalg.LinAlgError:
        ridge = 1e-12 * np.trace(normal) / normal.shape[0]
        return np.linalg.cholesky(normal + ridge * np.eye(normal.shape[0])).T


def _solve_symmetric(normal: np.ndarray, right: np.ndarray) -> np.ndarray:
    try:
        factor = np.linalg.cholesky(normal)
        return np.linalg.solve(factor.T, np.linalg.solve(factor, right))
    except np.linalg.LinAlgError:
        solution, *_ = np.linalg.lstsq(normal, right, rcond=1e-13)
        return solution


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
    basis : LinearBasis or None
        The linearised model change fitted alongside, if any.
    initial_mode_amplitudes_K : numpy.ndarray
        Fitted amplitude of each column of :func:`flange_mode_columns` (the T2 state at the first sample).
    basis_change : numpy.ndarray
        Its fitted change of each parameter (already in the predictions).
    penalty : float
        The basis's penalty at that change (noise-variance units, like a chi-square).
    normal_inverse : numpy.ndarray or None
        Inverse normal matrix of the fit (nuisance, shared, basis columns in that order).
    """

    model: CryostatModel
    flange_K: np.ndarray
    ptc_stage_K: np.ndarray
    flange_residual_K: np.ndarray
    ptc_stage_residual_K: np.ndarray
    shared_coefficients: np.ndarray
    initial_power_offset_w: float = 0.0
    basis: LinearBasis | None = None
    initial_mode_amplitudes_K: np.ndarray = field(default_factory=lambda: np.zeros(0))
    basis_change: np.ndarray = field(default_factory=lambda: np.zeros(0))
    penalty: float = 0.0
    normal_inverse: np.ndarray | None = None

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
        fitted jointly (once measured: :meth:`weighted`).
    """

    def __init__(self, data: RecordData, fit_mask: np.ndarray, noise_rms_K: tuple[float, float] = (20e-6, 0.3e-3)):
        self.data = data
        self.fit_mask = np.asarray(fit_mask, dtype=bool) & data.valid
        self.noise_rms_K = noise_rms_K
        #: Heater power the cryostat had settled at before the first sample (W); None: the first sample's.
        self.initial_heater_power_w: float | None = None
        self._measured_cycle: MeasuredCoolerCycle | None = None
        self._fit_rows = np.flatnonzero(self.fit_mask)
        self._basis_rows: dict = {}
        self._kept_rows: dict = {}

    def weighted(self, noise_rms_K: tuple[float, float]) -> "Replayer":
        """The same replayer (record, fit samples, settled power, measured cycle) weighting by ``noise_rms_K``."""
        other = Replayer(self.data, self.fit_mask, noise_rms_K)
        other.initial_heater_power_w = self.initial_heater_power_w
        other._measured_cycle = self._measured_cycle
        return other

    def share_measured_cycle(self, other: "Replayer") -> None:
        """Use ``other``'s cooler phase measured in T5 (same record) instead of measuring it again."""
        if other.data is not self.data:
            raise ValueError("the measured cooler phase belongs to another record")
        self._measured_cycle = other._measured_cycle

    def settle_from(self, replay: Replay) -> None:
        """Take the settled power before the record from a replay's T5 initial-state estimate."""
        start = self.initial_heater_power_w if self.initial_heater_power_w is not None else float(self.data.heater_w[0])
        self.initial_heater_power_w = max(start + replay.initial_power_offset_w, 0.0)

    def _on_fit_rows(self, kept: np.ndarray) -> np.ndarray:
        """A kept (read-only) array's fit rows, taken once per array: every replay of one model needs its mode
        and release columns there."""
        found = self._kept_rows.get(id(kept))
        if found is None or found[0] is not kept:
            if kept.flags.writeable:
                return kept[self._fit_rows]
            if len(self._kept_rows) >= ROWS_KEPT:
                self._kept_rows.pop(next(iter(self._kept_rows)))
            found = self._kept_rows[id(kept)] = (kept, kept[self._fit_rows])
        return found[1]

    def _basis_on_fit_rows(self, basis: LinearBasis):
        """A basis's columns on the fit rows (T2, T5) and their weighted Gram matrix, made once per basis."""
        found = self._basis_rows.get(id(basis))
        if found is None or found[0] is not basis:
            flange = basis.flange_columns[self._fit_rows]
            stage = basis.stage_columns[self._fit_rows]
            gram = (flange.T @ flange) / self.noise_rms_K[0] ** 2 + (stage.T @ stage) / self.noise_rms_K[1] ** 2
            if len(self._basis_rows) >= BASES_KEPT:
                self._basis_rows.pop(next(iter(self._basis_rows)))
            found = self._basis_rows[id(basis)] = (basis, flange, stage, gram)
        return found[1:]

    # -- the line ----------------------------------------------------------
    def stage_line(self, model: CryostatModel, *, orders=(1,), drift: bool = False,
                   angular_frequency_rad_s: float | None = None, significant_only: bool = False,
                   measured_phase: bool = False) -> PtcLine:
        """Measure the PTC line in T5 less the model's heater-driven part, on the fit samples.

        ``measured_phase``: at the cooler's phase followed sample by sample in
        T5 (:func:`cryod.cooler.line.measured_cycle`, measured once per
        record) instead of a frequency of the model's form; ``drift`` is then
        the form fitted to that phase.
        """
        data = self.data
        quiet = model.with_ptc(ptc_stage_amplitude_K=0.0, harmonics=()).with_effects(ptc_frequency_drift=None)
        heater_part = self.simulate(quiet).ptc_stage_K - quiet.operating_point.ptc_stage_temperature_K
        release = stage_release_response(model, data.elapsed_s)
        valid = data.valid
        baseline = np.column_stack([np.ones(valid.sum()), release[valid]])
        cycle = None
        if measured_phase:
            if self._measured_cycle is None:
                nominal = angular_frequency_rad_s or model.ptc.angular_frequency_rad_s
                self._measured_cycle = measured_cycle(data.elapsed_s[valid], (data.ptc_stage_K - heater_part)[valid],
                                                      nominal)
            cycle = self._measured_cycle
        return estimate_ptc_line(
            data.elapsed_s[valid], data.ptc_stage_K[valid] - heater_part[valid], baseline,
            mask=self.fit_mask[valid], orders=orders, drift=drift,
            angular_frequency_rad_s=angular_frequency_rad_s, significant_only=significant_only, cycle=cycle)

    # -- replay ------------------------------------------------------------
    def simulate(self, model: CryostatModel, heater_power_w=None, initial_heater_power_w=None, cycle=None):
        """The simulator on the record's instants (no noise).

        By default driven by the record's heater, settled at
        :attr:`initial_heater_power_w` before the first sample; ``cycle``: the
        cooler's phase measured in the record, instead of the model's.
        """
        if heater_power_w is None:
            heater_power_w, initial_heater_power_w = self.data.heater_w, self.initial_heater_power_w
        return simulate(model, self.data.time_s, heater_power_w, initial_heater_power_w=initial_heater_power_w,
                        heater_change_s=self.data.heater_change_s, ptc_cycle=cycle)

    def replay(self, model: CryostatModel, line: PtcLine | None = None, shared_columns=None, *,
               basis: LinearBasis | None = None) -> Replay:
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
        basis : LinearBasis, optional
            A linearised model change fitted alongside (the recalibration's, :class:`LinearBasis`).

        Returns
        -------
        Replay
        """
        aligned = line.applied_to(model) if line is not None else model
        simulated = self.simulate(aligned, cycle=line.cycle if line is not None else None)
        return self.replay_simulated(aligned, simulated.flange_K, simulated.ptc_stage_K, shared_columns,
                                     basis=basis)

    def replay_simulated(self, aligned: CryostatModel, flange_K: np.ndarray, stage_K: np.ndarray,
                         shared_columns=None, basis: LinearBasis | None = None) -> Replay:
        """Fit the nuisance parameters (and ``basis``'s changes, if given) to a simulation already made."""
        data = self.data
        stage_release = stage_release_response(aligned, data.elapsed_s)
        modes = flange_mode_columns(aligned, data.elapsed_s, data.sample_interval_s)
        count = data.time_s.size
        flange_columns = 1 + modes.shape[1]                 # offset, mode amplitudes
        shared = 0
        flange_extra = stage_extra = None
        if shared_columns is not None:
            flange_extra = np.asarray(shared_columns[0], dtype=float).reshape(count, -1)
            stage_extra = np.asarray(shared_columns[1], dtype=float).reshape(count, -1)
            shared = flange_extra.shape[1]
        basis_count = len(basis.names) if basis is not None else 0
        start = flange_columns + 2 + shared
        basis_index = slice(start, start + basis_count) if basis is not None else None
        columns = start + basis_count
        rows = self._fit_rows
        # Each thermometer's design has only some of the columns: T2 the offset, the modes, the shared columns,
        # the basis and the target; T5 its offset, the release, the shared, the basis and the target.
        flange_part = np.empty((rows.size, flange_columns + shared + 1))
        flange_part[:, 0] = 1.0
        flange_part[:, 1:flange_columns] = self._on_fit_rows(modes)
        stage_part = np.empty((rows.size, 2 + shared + 1))
        stage_part[:, 0] = 1.0
        stage_part[:, 1] = self._on_fit_rows(stage_release)
        if shared and flange_extra is not None and stage_extra is not None:
            flange_part[:, flange_columns:-1] = flange_extra[rows]
            stage_part[:, 2:-1] = stage_extra[rows]
        flange_part[:, -1] = (data.flange_K - flange_K)[rows]
        stage_part[:, -1] = (data.ptc_stage_K - stage_K)[rows]
        flange_weight, stage_weight = 1.0 / self.noise_rms_K[0] ** 2, 1.0 / self.noise_rms_K[1] ** 2
        flange_at = np.r_[0:flange_columns, flange_columns + 2:start, columns]
        stage_at = np.r_[flange_columns:start, columns]
        gram = np.zeros((columns + 1, columns + 1))
        gram[np.ix_(flange_at, flange_at)] = (flange_part.T @ flange_part) * flange_weight
        gram[np.ix_(stage_at, stage_at)] += (stage_part.T @ stage_part) * stage_weight
        if basis is not None:
            flange_basis, stage_basis, basis_gram = self._basis_on_fit_rows(basis)
            crossed = np.zeros((columns + 1, basis_count))
            crossed[flange_at] = (flange_part.T @ flange_basis) * flange_weight
            crossed[stage_at] += (stage_part.T @ stage_basis) * stage_weight
            gram[:, basis_index] = crossed
            gram[basis_index, :] = crossed.T
            gram[basis_index, basis_index] = basis_gram
        modes_index = np.arange(1, flange_columns)
        gram[modes_index, modes_index] += 1.0 / INITIAL_STATE_WIDTH_K ** 2
        solution, penalty, normal_inverse = solve_with_basis(gram, basis_index, basis)
        flange_predicted = flange_K + solution[0] + modes @ solution[1:flange_columns]
        stage_predicted = stage_K + solution[flange_columns] + stage_release * solution[flange_columns + 1]
        if shared:
            flange_predicted = flange_predicted + flange_extra @ solution[flange_columns + 2:start]
            stage_predicted = stage_predicted + stage_extra @ solution[flange_columns + 2:start]
        if basis is not None:
            flange_predicted = flange_predicted + basis.flange_columns @ solution[basis_index]
            stage_predicted = stage_predicted + basis.stage_columns @ solution[basis_index]
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
            basis=basis,
            initial_mode_amplitudes_K=solution[1:flange_columns],
            basis_change=solution[basis_index] if basis is not None else np.zeros(0),
            penalty=penalty,
            normal_inverse=normal_inverse,
        )
