"""Where each cause shows in a residual: its signature, and how much of a residual lies there.

A cause changes a record in its own place. The causes on the cooler's line's path (a thermometer's lag, a link
that differs, the cooler's harmonics, its frequency or amplitude wandering) change the line and its harmonics on
each thermometer; the causes on the heater's path (a dead time, a heater nonlinearity, a heat capacity that
depends on temperature, the cold end's drift) change how the temperatures follow the heater, slowly against the
line: the steps, the modulated stretches, the warm-ups. So a residual is cut into two *bands*, on the held-out
blocks, each thermometer in units of its noise:

* ``line``: in each held-out block, the least-squares fit of cos and sin of k times the cooler's phase, k each
  order the sampling can tell (up to 5); its sum of squares. Noise alone gives 2 per order, block and
  thermometer. A block where the heater itself moves at the line by more than :data:`HEATER_AT_LINE_W` (a
  modulation at the line, a feedforward's waveform) is left out: there a heater-path cause changes the line too
  (a 45 s dead time on an identification record moved the line band enough for a link of gain 62 to take it).
* ``slow``: in each held-out block, the means over windows of two line periods (which cancel the line and its
  harmonics), each squared times its number of samples. Noise alone gives 1 per window and thermometer.

A band's *excess* is its sum of squares less what noise gives, its significance that over the square root of
twice the noise's (:class:`BandExcess`). A cause's share of what is left at its signature is how much of its band's
excess the model with it removes (:func:`share_at_signature`).

Examples
--------
>>> band_of("sensor_lag"), band_of("dead_time")
('line', 'slow')
>>> BandExcess(band="line", sum_of_squares=500.0, terms=200).excess
300.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cryod.cooler.line import PtcLine, measurable_orders

#: Causes whose signature is the cooler's line and its harmonics on each thermometer.
LINE_PATH_CAUSES = ("sensor_lag", "link_dynamics", "ptc_harmonics", "ptc_frequency_drift", "ptc_amplitude_modulation")
#: Causes whose signature is how the temperatures follow the heater, slowly against the line.
HEATER_PATH_CAUSES = ("dead_time", "heater_nonlinearity", "heat_capacity_temperature", "ptc_stage_drift")
BANDS = ("line", "slow")
#: Line periods in one window of the slow band.
SLOW_WINDOW_PERIODS = 2.0
#: A held-out block whose heater moves at the line by more than this amplitude (W) is left out of the line band:
#: through the heater's path to T2 at the line (7.13 mK/W on the shipped model) 5 mW is 36 µK, 2 % of the
#: cooler's 1.73 mK line on T2; a PI holding 5 K moves the heater there by about 0.7 mW (0.4 W/K times 1.7 mK),
#: the identification protocol's modulation by 15 mW, a feedforward by tens of mW.
HEATER_AT_LINE_W = 5e-3


def band_of(cause: str) -> str:
    """The band of a cause's signature: ``line`` or ``slow``."""
    return "line" if cause in LINE_PATH_CAUSES else "slow"


@dataclass(frozen=True, kw_only=True)
class BandExcess:
    """A residual's sum of squares in one band (both thermometers, noise units) and what noise alone gives."""

    band: str
    sum_of_squares: float
    terms: int

    @property
    def excess(self) -> float:
        return self.sum_of_squares - self.terms

    @property
    def significance(self) -> float:
        return self.excess / math.sqrt(2.0 * max(self.terms, 1))

    def as_dict(self) -> dict:
        return {"band": self.band, "excess": self.excess, "significance": self.significance, "terms": self.terms}


@dataclass(frozen=True, kw_only=True)
class BandLayout:
    """What a band's sums are taken over: the held-out blocks' samples, an orthonormal basis of the line's orders
    at the cooler's phase in each (None where the heater moves at the line), the slow band's windows."""

    blocks: tuple[np.ndarray, ...]
    line_bases: tuple[np.ndarray, ...]
    #: Per block, its windows' sample indexes (windows x samples).
    windows: tuple[np.ndarray, ...]
    noise_rms_K: tuple[float, float]

    @classmethod
    def of(cls, data, held_out_mask: np.ndarray, line: PtcLine, noise_rms_K: tuple[float, float]) -> "BandLayout":
        """The layout of a record's held-out blocks (``held_out_mask``), its line and its noise."""
        indexes = np.flatnonzero(held_out_mask)
        if indexes.size == 0:
            return cls(blocks=(), line_bases=(), windows=(), noise_rms_K=noise_rms_K)
        breaks = np.flatnonzero(np.diff(indexes) > 1) + 1
        blocks = tuple(part for part in np.split(indexes, breaks) if part.size > 8)
        phase = line.phase_rad(data.elapsed_s)
        orders = measurable_orders(line.angular_frequency_rad_s, data.sample_interval_s)
        line_bases = tuple(
            None if _heater_at_line(data.heater_w[block], phase[block]) > HEATER_AT_LINE_W else
            np.linalg.qr(np.column_stack([f(order * phase[block]) for order in orders for f in (np.cos, np.sin)]))[0]
            for block in blocks)
        samples = max(2, int(round(SLOW_WINDOW_PERIODS * 2.0 * math.pi / line.angular_frequency_rad_s
                                   / data.sample_interval_s)))
        windows = tuple(block[:block.size // samples * samples].reshape(-1, samples) for block in blocks
                        if block.size >= samples)
        return cls(blocks=blocks, line_bases=line_bases, windows=windows, noise_rms_K=noise_rms_K)

    def band(self, replay, band: str) -> BandExcess:
        """``replay``'s residual in ``band`` (``line`` or ``slow``)."""
        residuals = (replay.flange_residual_K / self.noise_rms_K[0], replay.ptc_stage_residual_K / self.noise_rms_K[1])
        total, terms = 0.0, 0
        if band == "line":
            for block, basis in zip(self.blocks, self.line_bases):
                if basis is None:
                    continue
                for residual in residuals:
                    projection = basis.T @ residual[block]
                    total += float(projection @ projection)
                    terms += basis.shape[1]
        else:
            for windows in self.windows:
                for residual in residuals:
                    sums = residual[windows].sum(axis=1)
                    total += float(sums @ sums) / windows.shape[1]
                    terms += windows.shape[0]
        return BandExcess(band=band, sum_of_squares=total, terms=terms)

    def bands(self, replay) -> dict[str, BandExcess]:
        return {band: self.band(replay, band) for band in BANDS}


def _heater_at_line(heater_w: np.ndarray, phase: np.ndarray) -> float:
    """The amplitude (W) of the heater's fundamental at the cooler's line in one block."""
    columns = np.column_stack([np.cos(phase), np.sin(phase), np.ones(phase.size)])
    solution = np.linalg.lstsq(columns, heater_w, rcond=None)[0]
    return float(np.hypot(solution[0], solution[1]))


def share_at_signature(cause: str, before: dict[str, BandExcess], after: dict[str, BandExcess]) -> float:
    """How much of the excess at ``cause``'s signature (its band) the model ``after`` removes from the model
    ``before`` (a fraction; 0 when the band shows no excess before)."""
    band = band_of(cause)
    excess = before[band].excess
    if excess <= 0.0:
        return 0.0
    return (excess - after[band].excess) / excess


__all__ = ["BANDS", "HEATER_PATH_CAUSES", "LINE_PATH_CAUSES", "BandExcess", "BandLayout", "band_of",
           "share_at_signature"]
