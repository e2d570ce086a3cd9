"""Uncertainties of a heater-path fit: the fit's covariance, checked by a block bootstrap of its residuals.

Covariance. At the solution the prediction is linear in every parameter to
first order; with J the derivatives of the prediction by the parameters (the
time constants by central differences, the linear coefficients exactly: the
design's columns) and ``s^2 = RSS / (N - p)`` the residual variance, the
covariance is ``s^2 (J^T J)^-1``. It is right when the residual is white noise.

Check. A thermometer's residual is not always white (a drift, an effect the
model lacks, noise that is not): then the covariance is too small. The moving
block bootstrap keeps the residual's correlation over a block: new records are
made of the fitted prediction plus the residual cut into blocks (``block_s``
long, drawn with replacement) and refitted; the spread of the refits is the
bootstrap's standard uncertainty. Each parameter's stated uncertainty is the
covariance's, unless the bootstrap's is larger by more than its own sampling
error (two standard errors of a standard deviation from B refits,
``sqrt(2 / (B - 1))``); then it is the bootstrap's, and the covariance of that
parameter is scaled up to match.

Examples
--------
>>> stated_uncertainty(covariance_sigma=1.0, bootstrap_sigma=1.1, replicates=40)
1.0
>>> stated_uncertainty(covariance_sigma=1.0, bootstrap_sigma=2.0, replicates=40)
2.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cryod.identification.step_terms import StepChannel, StepFitError, TermFit, fit_terms

#: Default number of bootstrap refits and block length (s).
BOOTSTRAP_REPLICATES = 30
BOOTSTRAP_BLOCK_S = 20.0
#: Relative step of the time constants' central differences.
DIFFERENCE_STEP = 1e-5


def stated_uncertainty(covariance_sigma: float, bootstrap_sigma: float | None, replicates: int) -> float:
    """The covariance's sigma, or the bootstrap's when that is larger beyond its own sampling error."""
    if bootstrap_sigma is None or not math.isfinite(bootstrap_sigma) or replicates < 2:
        return covariance_sigma
    threshold = covariance_sigma * (1.0 + 2.0 * math.sqrt(2.0 / (replicates - 1)))
    return bootstrap_sigma if bootstrap_sigma > threshold else covariance_sigma


@dataclass
class FitUncertainty:
    """Uncertainties of a :class:`~cryod.identification.step_terms.TermFit`'s parameters.

    The parameter vector is ``[tau_1 .. tau_n, coefficients ...]`` (the time
    constants in s, then the design's linear coefficients).

    Attributes
    ----------
    covariance : numpy.ndarray
        The stated covariance (units squared).
    fit_covariance : numpy.ndarray
        The fit's covariance, before the bootstrap check.
    bootstrap_sigma : numpy.ndarray or None
        The bootstrap's standard uncertainty of each parameter (None: not run).
    replicates : int
        Bootstrap refits that converged.
    block_s : float
    residual_variance_K2 : float
    """

    covariance: np.ndarray
    fit_covariance: np.ndarray
    bootstrap_sigma: np.ndarray | None
    replicates: int
    block_s: float
    residual_variance_K2: float

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def fit_sigma(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.fit_covariance), 0.0, None))

    def bootstrap_ratio(self, count: int) -> np.ndarray | None:
        """Bootstrap over covariance sigma of the first ``count`` parameters (None without a bootstrap)."""
        if self.bootstrap_sigma is None:
            return None
        fit = self.fit_sigma[:count]
        return np.where(fit > 0.0, self.bootstrap_sigma[:count] / np.where(fit > 0.0, fit, 1.0), np.nan)


def parameter_vector(fit: TermFit) -> np.ndarray:
    return np.concatenate([fit.time_constants_s, fit.coefficients])


def prediction_jacobian(channel: StepChannel, fit: TermFit) -> np.ndarray:
    """Derivatives of the prediction (valid rows) by ``[taus, coefficients]``."""
    taus = fit.time_constants_s
    design, _ = channel.design(taus)
    jacobian = np.empty((design.shape[0], taus.size + design.shape[1]), order="F")
    jacobian[:, taus.size:] = design
    del design
    for i, tau in enumerate(taus):
        step = DIFFERENCE_STEP * tau
        upper, lower = taus.copy(), taus.copy()
        upper[i] += step
        lower[i] -= step
        difference = channel.design(upper)[0]
        difference -= channel.design(lower)[0]
        difference /= 2.0 * step
        jacobian[:, i] = difference @ fit.coefficients
    return jacobian


def fit_covariance(channel: StepChannel, fit: TermFit) -> tuple[np.ndarray, float]:
    """``s^2 (J^T J)^-1`` and ``s^2`` (K^2)."""
    jacobian = prediction_jacobian(channel, fit)
    count, parameters = jacobian.shape
    variance = fit.residual_sum_of_squares / max(count - parameters, 1)
    scale = np.linalg.norm(jacobian, axis=0)
    scale[scale == 0.0] = 1.0
    scaled = jacobian / scale
    inverse = np.linalg.pinv(scaled.T @ scaled, rcond=1e-13, hermitian=True)
    return variance * inverse / np.outer(scale, scale), variance


def _resampled(residual: np.ndarray, block: int, generator: np.random.Generator) -> np.ndarray:
    """The residual cut into blocks of ``block`` samples, drawn with replacement, to its length."""
    size = residual.size
    block = max(1, min(block, size))
    starts = generator.integers(0, size - block + 1, size=int(math.ceil(size / block)))
    return np.concatenate([residual[s:s + block] for s in starts])[:size]


def block_bootstrap(channel: StepChannel, fit: TermFit, replicates: int = BOOTSTRAP_REPLICATES,
                    block_s: float = BOOTSTRAP_BLOCK_S, seed: int | None = 0) -> np.ndarray:
    """Parameter vectors refitted on ``replicates`` records made of the prediction plus resampled residual blocks.

    Returns
    -------
    numpy.ndarray
        (converged refits) x (taus + coefficients).
    """
    generator = np.random.default_rng(seed)
    design, target = channel.design(fit.time_constants_s)
    prediction = design @ fit.coefficients
    pieces, start = [], 0
    for record in channel.records:
        count = int(np.count_nonzero(record.rows))
        pieces.append((record, slice(start, start + count)))
        start += count
    residual = target - prediction
    refits = []
    for _ in range(replicates):
        records = []
        for record, rows in pieces:
            interval = float(np.median(np.diff(record.time_s))) if record.time_s.size > 1 else 1.0
            made = prediction[rows] + _resampled(residual[rows], int(round(block_s / interval)), generator)
            target_K = np.full(record.time_s.size, np.nan)
            target_K[record.rows] = made
            records.append(record.with_target(target_K))
        trial = StepChannel(channel.name, records, channel.other_names)
        try:
            refit = fit_terms(trial, fit.time_constants_s)
        except (StepFitError, np.linalg.LinAlgError, ValueError):
            continue
        refits.append(parameter_vector(refit))
    return np.array(refits)


def fit_uncertainty(channel: StepChannel, fit: TermFit, *, replicates: int = BOOTSTRAP_REPLICATES,
                    block_s: float = BOOTSTRAP_BLOCK_S, seed: int | None = 0) -> FitUncertainty:
    """The fit's covariance, checked (and where needed enlarged) by the block bootstrap.

    Parameters
    ----------
    channel : StepChannel
    fit : TermFit
    replicates : int
        Bootstrap refits (0: covariance only).
    block_s : float
        Length of the residual blocks (s).
    seed : int, optional

    Returns
    -------
    FitUncertainty
    """
    covariance, variance = fit_covariance(channel, fit)
    sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    bootstrap_sigma = None
    converged = 0
    stated = covariance.copy()
    if replicates > 1:
        refits = block_bootstrap(channel, fit, replicates, block_s, seed)
        converged = len(refits)
        if converged > 1:
            bootstrap_sigma = np.std(refits, axis=0, ddof=1)
            factor = np.ones_like(sigma)
            for index, (fit_sigma, boot_sigma) in enumerate(zip(sigma, bootstrap_sigma)):
                chosen = stated_uncertainty(fit_sigma, boot_sigma, converged)
                if fit_sigma > 0.0 and chosen > fit_sigma:
                    factor[index] = chosen / fit_sigma
            stated = covariance * np.outer(factor, factor)
    return FitUncertainty(stated, covariance, bootstrap_sigma, converged, block_s, variance)


__all__ = ["FitUncertainty", "block_bootstrap", "fit_covariance", "fit_uncertainty", "prediction_jacobian",
           "stated_uncertainty", "BOOTSTRAP_REPLICATES", "BOOTSTRAP_BLOCK_S"]
