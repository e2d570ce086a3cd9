"""A heater path as a sum of first-order terms, with the number of terms chosen from the data.

The response of one thermometer (T2 or T5) to the heater is fitted as

    y(t) = sum_i g_i [L(tau_i) P](t) + sum_m b_m x_m(t) + per record: sum_i a_i exp(-(t - t0) / tau_i)

with ``L(tau) = 1 / (tau s + 1)`` driven by the recorded heater power held
between changes (the simulator's exact zero-order hold,
:class:`cryod.model.heater_path.HeaterPath`, with the change at ``heater_set_s``
where the record has it), ``x_m`` the channel's other columns (an offset, the
cooler's line) and one free amplitude per term and record for the state the
record starts in. The time constants are found by
:func:`scipy.optimize.least_squares` (in log), every linear coefficient by
linear least squares inside each evaluation (variable projection).

How many terms: fits with 1, 2, ... terms are compared by the Bayesian
information criterion ``BIC = N ln(RSS / N) + k ln N`` (N samples, k
parameters); more terms are tried while the criterion falls by more than
:data:`BIC_MARGIN`. A fit whose time constants merge or run to a bound of the
search does not count as better. Held-out blocks (every other block of the
record, :func:`cryod.analysis.record_data.fit_block_mask`) give the second
opinion reported beside it: each count fitted on the fit blocks, its rms on
the others.

Examples
--------
>>> import numpy as np
>>> t = np.arange(0.0, 1500.0, 0.1)
>>> heater = np.where(t >= 100.0, 0.01, 0.0)
>>> rise = np.clip(t - 100.0, 0.0, None)
>>> y = 4.2 + 0.01 * 1.2 * (1 - np.exp(-rise / 26.0)) + 0.01 * 5.6 * (1 - np.exp(-rise / 165.0))
>>> channel = StepChannel("T2", [ChannelRecord(t, heater, y, np.ones((t.size, 1)))], ("offset_K",))
>>> selection = select_terms(channel, noise_floor_K=2e-5)
>>> selection.chosen.count, [round(float(tau), 1) for tau in selection.chosen.time_constants_s]
(2, [26.0, 165.0])
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg, optimize

from cryod.analysis.record_data import fit_block_mask
from cryod.model.heater_path import HeaterPath
from cryod.model.transfer_function import TransferFunction

#: Time constants are searched within these bounds (s).
TIME_CONSTANT_BOUNDS_S = (0.5, 20000.0)
#: Most terms tried.
MAX_TERMS = 4
#: A count of terms is preferred to one fewer only if it lowers the BIC by more than this.
BIC_MARGIN = 10.0
#: The search of a fit stops after this many evaluations per time constant (and one more):
#: a term the data cannot place makes the search wander along a flat valley.
MAX_EVALUATIONS_PER_PARAMETER = 40
#: Two time constants closer than this ratio count as one (a degenerate fit).
MERGED_RATIO = 1.05
#: Heater responses kept per record (each one float per row): a fit's current time constants and the last ones.
KEPT_RESPONSES = 2 * MAX_TERMS


class StepFitError(ValueError):
    """The records do not determine the path (no heater change, a failed fit)."""


@dataclass
class ChannelRecord:
    """One record's samples of one thermometer.

    Attributes
    ----------
    time_s : numpy.ndarray
        Sample instants of every row (s).
    heater_w : numpy.ndarray
        Heater power from each row to the next (W).
    target_K : numpy.ndarray
        The thermometer's reading, every row (K; NaN where missing).
    other_columns : numpy.ndarray
        rows x m: the channel's other regressors (shared by all records).
    heater_change_s : numpy.ndarray, optional
        When each row's heater power took effect (s); None: at the sample instants.
    valid : numpy.ndarray, optional
        Rows that take part (default: finite target).
    """

    time_s: np.ndarray
    heater_w: np.ndarray
    target_K: np.ndarray
    other_columns: np.ndarray
    heater_change_s: np.ndarray | None = None
    valid: np.ndarray | None = None

    def __post_init__(self) -> None:
        self._responses: dict[float, np.ndarray] = {}
        self.time_s = np.asarray(self.time_s, dtype=float)
        self.heater_w = np.asarray(self.heater_w, dtype=float)
        self.target_K = np.asarray(self.target_K, dtype=float)
        self.other_columns = np.asarray(self.other_columns, dtype=float).reshape(self.time_s.size, -1)
        valid = np.isfinite(self.target_K) if self.valid is None else np.asarray(self.valid, dtype=bool)
        self.valid = valid & np.isfinite(self.target_K)

    @property
    def rows(self) -> np.ndarray:
        """The rows that take part: ``valid`` as given, where the target is finite (a boolean mask)."""
        valid = self.valid
        assert valid is not None            # completed as the record is made
        return valid

    @property
    def elapsed_s(self) -> np.ndarray:
        return self.time_s - self.time_s[0]

    def with_target(self, target_K: np.ndarray) -> "ChannelRecord":
        """The same record with another target (a bootstrap's), sharing the heater responses kept."""
        record = dataclasses.replace(self, target_K=target_K, valid=self.rows.copy())
        record._responses = self._responses
        return record

    def response(self, time_constant_s: float) -> np.ndarray:
        """:func:`heater_response`, kept for the last :data:`KEPT_RESPONSES` time constants asked for (a fit
        asks again and again; records that differ only in their target share them, :meth:`with_target`)."""
        key = float(time_constant_s)
        found = self._responses.get(key)
        if found is None:
            if len(self._responses) >= KEPT_RESPONSES:
                self._responses.pop(next(iter(self._responses)))
            found = self._responses[key] = heater_response(self, key)
        return found


def heater_response(record: ChannelRecord, time_constant_s: float) -> np.ndarray:
    """Response of ``1 / (tau s + 1)`` to the record's heater, settled at the first power, at every row (K/W x W).

    The power of row k acts from its change instant (``heater_change_s``, else
    the row's sample instant) until the next row's change.
    """
    path = HeaterPath(TransferFunction.first_order_lag(time_constant_s))
    heater = record.heater_w
    path.settle(float(heater[0]))
    t = record.time_s
    if record.heater_change_s is None:
        return path.run(np.diff(t), heater[:-1])
    change = np.clip(record.heater_change_s, t, np.append(t[1:], t[-1]))
    # intervals: [t_k, c_k) at the previous power, [c_k, t_k+1) at row k's power
    durations = np.empty(2 * (t.size - 1))
    durations[0::2] = change[:-1] - t[:-1]
    durations[1::2] = t[1:] - change[:-1]
    inputs = np.empty_like(durations)
    inputs[0::2] = np.concatenate(([heater[0]], heater[:-2]))
    inputs[1::2] = heater[:-1]
    return path.run(durations, inputs)[0::2]


@dataclass
class StepChannel:
    """One thermometer's samples in all records, and the names of its other regressors."""

    name: str
    records: list[ChannelRecord]
    other_names: tuple[str, ...]

    @property
    def sample_count(self) -> int:
        return int(sum(np.count_nonzero(r.rows) for r in self.records))

    def design(self, time_constants_s, masks=None) -> tuple[np.ndarray, np.ndarray]:
        """Design matrix and target over the valid rows (or ``masks``, one per record).

        Columns: the n term responses, the other regressors, then per record
        the n initial-state decays.
        """
        taus = np.asarray(time_constants_s, dtype=float)
        count = taus.size
        others = len(self.other_names)
        columns = count + others + count * len(self.records)
        selected = [record.rows if masks is None else (record.rows & masks[index])
                    for index, record in enumerate(self.records)]
        sizes = [int(np.count_nonzero(rows)) for rows in selected]
        # column by column (Fortran order): what a QR factorisation works on, without a copy
        design = np.zeros((sum(sizes), columns), order="F")
        target = np.empty(sum(sizes))
        start = 0
        for index, (record, rows, size) in enumerate(zip(self.records, selected, sizes)):
            block = slice(start, start + size)
            elapsed = record.elapsed_s[rows]
            for i, tau in enumerate(taus):
                design[block, i] = record.response(tau)[rows]
                design[block, count + others + count * index + i] = np.exp(-elapsed / tau)
            design[block, count:count + others] = record.other_columns[rows]
            target[block] = record.target_K[rows]
            start += size
        return design, target

    def prediction_derivative(self, time_constants_s, coefficients, index: int, masks=None) -> np.ndarray:
        """d(design @ coefficients) / d tau_index over the rows of :meth:`design` (K/s).

        The term's response is differenced (a relative step of 1e-6); the
        initial-state decays ``exp(-t / tau)`` are differentiated exactly.
        """
        taus = np.asarray(time_constants_s, dtype=float)
        count = taus.size
        others = len(self.other_names)
        tau = float(taus[index])
        step = 1e-6 * tau
        pieces = []
        for number, record in enumerate(self.records):
            rows = record.rows if masks is None else (record.rows & masks[number])
            elapsed = record.elapsed_s[rows]
            response = (heater_response(record, tau + step) - heater_response(record, tau - step))[rows] / (2 * step)
            amplitude = coefficients[count + others + count * number + index]
            pieces.append(coefficients[index] * response
                          + amplitude * elapsed / tau ** 2 * np.exp(-elapsed / tau))
        return np.concatenate(pieces)

    def forget_responses(self) -> None:
        """Let go of the heater responses the records keep (one float per row each)."""
        for record in self.records:
            record._responses.clear()

    def has_heater_change(self) -> bool:
        return any(np.ptp(r.heater_w) > 0.0 for r in self.records)


@dataclass
class TermFit:
    """A fit with a given number of terms.

    Attributes
    ----------
    time_constants_s : numpy.ndarray
        Ascending (s).
    coefficients : numpy.ndarray
        Linear coefficients in the design's column order: gains g_i (K/W),
        the other regressors, the initial-state amplitudes.
    residual_sum_of_squares : float
        K^2 over the samples.
    sample_count, parameter_count : int
    bic : float
    degenerate : str
        Why the fit does not count as better (merged or bounded time constants); empty if it does.
    """

    time_constants_s: np.ndarray
    coefficients: np.ndarray
    residual_sum_of_squares: float
    sample_count: int
    parameter_count: int
    degenerate: str = ""
    held_out_rms_K: float = math.nan

    @property
    def count(self) -> int:
        return int(self.time_constants_s.size)

    @property
    def gains_K_per_W(self) -> np.ndarray:
        return self.coefficients[:self.count]

    @property
    def residual_rms_K(self) -> float:
        return math.sqrt(self.residual_sum_of_squares / self.sample_count)

    @property
    def bic(self) -> float:
        n = self.sample_count
        return n * math.log(max(self.residual_sum_of_squares, 1e-300) / n) + self.parameter_count * math.log(n)

    def other(self, index: int) -> float:
        """Coefficient of the channel's other regressor ``index``."""
        return float(self.coefficients[self.count + index])


def least_squares_solution(design: np.ndarray, target: np.ndarray, *,
                           overwrite_design: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Linear least squares by a QR factorisation of the column-scaled design.

    Parameters
    ----------
    design : numpy.ndarray
        rows x columns.
    target : numpy.ndarray
    overwrite_design : bool
        Scale and factorise ``design`` in place (it is left scaled and
        destroyed): no copy of a long record's design.

    Returns
    -------
    solution : numpy.ndarray
    basis : numpy.ndarray
        Orthonormal columns spanning the design's columns (for projections).
    """
    scale = np.linalg.norm(design, axis=0)
    scale[scale == 0.0] = 1.0
    if overwrite_design:
        design /= scale
        scaled = design
    else:
        scaled = design / scale
    q, r = linalg.qr(scaled, mode="economic", overwrite_a=True, check_finite=False)
    diagonal = np.abs(np.diag(r))
    if diagonal.size and diagonal.min() > 1e-10 * diagonal.max():
        return linalg.solve_triangular(r, q.T @ target) / scale, q
    # rank-deficient: the minimum-norm solution from the SVD of R (scaled = Q R = (Q U) S V^T)
    u, singular, vt = np.linalg.svd(r)
    kept = singular > np.finfo(float).eps * max(scaled.shape) * singular.max()
    solution = vt[kept].T @ ((u[:, kept].T @ (q.T @ target)) / singular[kept])
    return solution / scale, q @ u[:, singular > 1e-10 * singular.max()]


def _solve(channel: StepChannel, taus, masks=None):
    design, target = channel.design(taus, masks)
    solution, _ = least_squares_solution(design, target)
    return design, target, solution


def fit_terms(channel: StepChannel, start_time_constants_s, masks=None) -> TermFit:
    """Fit ``len(start_time_constants_s)`` terms, starting from those time constants.

    Raises
    ------
    StepFitError
        When the optimiser does not return finite time constants.
    """
    low, high = (math.log(b) for b in TIME_CONSTANT_BOUNDS_S)
    start = np.clip(np.log(np.sort(np.asarray(start_time_constants_s, dtype=float))), low + 1e-6, high - 1e-6)

    last: dict = {}

    def solved(log_taus):
        key = tuple(log_taus)
        if last.get("key") != key:
            last.clear()                      # the previous evaluation's arrays go before the next are made
            design, target = channel.design(np.exp(log_taus), masks)
            solution, basis = least_squares_solution(design, target, overwrite_design=True)
            del design
            # the residual is what the design's columns leave of the target: its projection off them
            target -= basis @ (basis.T @ target)
            last.update(key=key, residual=target, solution=solution, basis=basis)
        return last

    def residual(log_taus):
        return solved(log_taus)["residual"] * 1e3           # mK: scaled for the tolerances

    def jacobian(log_taus):
        # variable projection (Kaufman): d r / d log tau_k = -P (d D / d tau_k) c tau_k, P the projection
        # off the design's columns
        found = solved(log_taus)
        taus = np.exp(log_taus)
        basis = found["basis"]
        columns = np.empty((basis.shape[0], taus.size), order="F")
        for k in range(taus.size):
            change = channel.prediction_derivative(taus, found["solution"], k, masks) * taus[k]
            change -= basis @ (basis.T @ change)
            columns[:, k] = change * -1e3
        return columns

    result = optimize.least_squares(residual, start, jac=jacobian, bounds=(low, high), method="trf", x_scale=1.0,
                                    max_nfev=MAX_EVALUATIONS_PER_PARAMETER * (start.size + 1))
    if not np.all(np.isfinite(result.x)):
        raise StepFitError(f"{channel.name}: the fit of {start.size} term(s) did not converge: {result.message}")
    order = np.argsort(result.x)
    taus = np.exp(result.x[order])
    design, target, solution = _solve(channel, taus, masks)
    rss = float(np.sum((target - design @ solution) ** 2))
    degenerate = ""
    if taus.size > 1 and np.min(taus[1:] / taus[:-1]) < MERGED_RATIO:
        degenerate = "two time constants merge"
    elif np.any(result.x <= low + 1e-3) or np.any(result.x >= high - 1e-3):
        degenerate = "a time constant ran to the bound of the search"
    return TermFit(taus, solution, rss, target.size, design.shape[1], degenerate)


def _starts(previous: np.ndarray | None, base_time_constants_s) -> list[np.ndarray]:
    """Starting time constants for one more term than ``previous``."""
    if previous is None:
        seeds = list(base_time_constants_s or []) + [10.0, 100.0, 1000.0]
        return [np.array([s]) for s in seeds]
    candidates = [previous[0] / 5.0, previous[-1] * 5.0]
    return [np.sort(np.append(previous, c)) for c in candidates]


@dataclass
class TermSelection:
    """The fits tried and the one chosen.

    Attributes
    ----------
    fits : list of TermFit
        The best fit for each count tried (1, 2, ...).
    chosen : TermFit
    reason : str
    """

    fits: list[TermFit]
    chosen: TermFit
    reason: str
    table: list[dict] = field(default_factory=list)


def _best_fit(channel, starts, masks=None) -> TermFit | None:
    """The best of the fits from each start; stops early when two starts reach the same time constants."""
    best = None
    for start in starts:
        try:
            fit = fit_terms(channel, start, masks)
        except (StepFitError, np.linalg.LinAlgError):
            continue
        if best is not None and not best.degenerate and fit.count == best.count and \
                np.allclose(fit.time_constants_s, best.time_constants_s, rtol=1e-3):
            return best if best.residual_sum_of_squares <= fit.residual_sum_of_squares else fit
        if best is None or (bool(fit.degenerate), fit.residual_sum_of_squares) < \
                (bool(best.degenerate), best.residual_sum_of_squares):
            best = fit
    return best


def select_terms(channel: StepChannel, *, max_terms: int = MAX_TERMS, base_time_constants_s=None,
                 noise_floor_K: float | None = None, held_out: bool = True) -> TermSelection:
    """Fit 1, 2, ... terms and choose the count by the BIC.

    Parameters
    ----------
    channel : StepChannel
    max_terms : int
    base_time_constants_s : sequence of float, optional
        Where to start the one-term search besides the default seeds (a base model's).
    noise_floor_K : float, optional
        The thermometer's white noise; the search stops once the residual rms
        is within 0.1 % of it (nothing left for another term to explain).
    held_out : bool
        Also fit each count on the fit blocks and report its held-out rms.

    Returns
    -------
    TermSelection

    Raises
    ------
    StepFitError
        The heater never changes, or no fit converged.
    """
    if not channel.has_heater_change():
        raise StepFitError(f"{channel.name}: the heater never changes in these records: the heater path cannot be "
                           "identified (record a heater step)")
    fits: list[TermFit] = []
    chosen: TermFit | None = None
    reason = ""
    previous = None
    for count in range(1, max_terms + 1):
        fit = _best_fit(channel, _starts(previous, base_time_constants_s))
        if fit is None:
            reason = f"no fit of {count} terms converged"
            break
        fits.append(fit)
        if chosen is None:
            chosen, reason = fit, "one term"
        elif fit.degenerate:
            reason = f"{count} terms: {fit.degenerate}; {chosen.count} kept"
            break
        elif fit.bic < chosen.bic - BIC_MARGIN:
            chosen, reason = fit, f"{count} terms lower the BIC by {chosen.bic - fit.bic:.0f}"
        else:
            reason = (f"{count} terms change the BIC by {fit.bic - chosen.bic:+.0f} (more than -{BIC_MARGIN:g} "
                      f"needed): {chosen.count} kept")
            break
        previous = fit.time_constants_s
        if noise_floor_K is not None and chosen is fit and fit.residual_rms_K <= noise_floor_K * 1.001:
            reason += "; the residual is at the noise floor"
            break
    if chosen is None:
        raise StepFitError(f"{channel.name}: no fit converged")
    if held_out:
        masks = [fit_block_mask(r.time_s) for r in channel.records]
        others = [~m for m in masks]
        for fit in fits:
            trial = _best_fit(channel, [fit.time_constants_s], masks)
            if trial is None:
                continue
            design, target = channel.design(trial.time_constants_s, others)
            rss = float(np.sum((target - design @ trial.coefficients) ** 2))
            fit.held_out_rms_K = math.sqrt(rss / max(target.size, 1))
    table = [{"terms": f.count, "time_constants_s": [float(t) for t in f.time_constants_s],
              "residual_rms_K": f.residual_rms_K, "bic": f.bic, "held_out_rms_K": f.held_out_rms_K,
              "degenerate": f.degenerate or None} for f in fits]
    return TermSelection(fits, chosen, reason, table)


__all__ = ["ChannelRecord", "StepChannel", "StepFitError", "TermFit", "TermSelection", "fit_terms",
           "heater_response", "select_terms", "TIME_CONSTANT_BOUNDS_S"]
