"""A cryod-log record in the form the analysis uses, and its split into fit and held-out blocks.

The analysis fits on some of the samples and judges on the others. The record
is cut into blocks of equal length (a twentieth of it, between 10 s and 120 s),
alternately *fit* and *held out*: every kind of segment (holds, steps,
modulation, PI) lands in both, and the simulation still runs over the whole
record, because the heater is an input known everywhere. Only the comparison
with the measured temperatures is split.

Examples
--------
>>> import numpy as np
>>> time_s = np.arange(0.0, 1200.0, 0.08)
>>> fit = fit_block_mask(time_s)
>>> round(float(fit.mean()), 2), bool(fit[0]), bool(fit[-1])
(0.5, True, False)
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cryod.analysis.record_window import busiest_stretch
from cryod.records.record import Record, RecordFormatError, read_record

#: Shortest record the analysis accepts (s) and fewest samples.
MINIMUM_DURATION_S = 120.0
MINIMUM_SAMPLES = 500
#: Fit/held-out blocks: this fraction of the record, within these bounds (s).
BLOCK_FRACTION = 1.0 / 20.0
BLOCK_BOUNDS_S = (10.0, 120.0)

#: Metadata keys that may state the heater's resistance (ohm), current limit (A), power limit (W).
RESISTANCE_KEYS = ("heater_resistance_ohm", "heater_resistance", "heater_resistance_Ohm")
CURRENT_LIMIT_KEYS = ("heater_current_limit_A", "heater_max_current_A", "heater_current_max_A",
                      "heater_current_limit")
POWER_LIMIT_KEYS = ("heater_max_W", "heater_limit_W", "heater_power_limit_W", "heater_max_power_W")
#: Columns the analysis reads besides the required ones (the others are skipped unread).
ANALYSED_COLUMNS = ("T2_sample_s", "T5_sample_s", "heater_set_s")


@dataclass(frozen=True)
class RecordData:
    """The columns the analysis needs, checked.

    Attributes
    ----------
    time_s : numpy.ndarray
        Sample instants (s): the instants the readings stand for where the
        record has them (``T2_sample_s``: the middle of each reading's
        integration, which an autozero can move from row to row), else the
        trigger instants (``time_s``).
    flange_K, ptc_stage_K : numpy.ndarray
        T2 and T5 (K); NaN where a reading is missing.
    heater_w : numpy.ndarray
        Heater power applied from each sample to the next (W).
    setpoint_K : numpy.ndarray
        NaN where the loop is open.
    heater_limit_w : float or None
        Heater power limit from the metadata (R I_max^2, or stated), if given.
    heater_change_s : numpy.ndarray or None
        When each row's heater power took effect (s), where the record says
        (``heater_set_s``); None: at the sample instants.
    source : str
    notes : list of str
        What was noticed while reading (limits found, rows left out).
    """

    time_s: np.ndarray
    flange_K: np.ndarray
    ptc_stage_K: np.ndarray
    heater_w: np.ndarray
    setpoint_K: np.ndarray
    heater_limit_w: float | None = None
    source: str = ""
    notes: list[str] = field(default_factory=list)
    heater_change_s: np.ndarray | None = None

    @functools.cached_property
    def elapsed_s(self) -> np.ndarray:
        """Seconds since the first sample (the simulator's PTC phase reference; made once, read-only)."""
        return _read_only(self.time_s - self.time_s[0])

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0])

    @functools.cached_property
    def sample_interval_s(self) -> float:
        """Median interval between samples (s)."""
        return float(np.median(np.diff(self.time_s)))

    @functools.cached_property
    def valid(self) -> np.ndarray:
        """Samples with both temperatures present (made once, read-only)."""
        return _read_only(np.isfinite(self.flange_K) & np.isfinite(self.ptc_stage_K))

    def stretch(self, start: int, stop: int) -> "RecordData":
        """The samples ``[start, stop)`` alone, with a note saying which they are."""
        part = slice(start, stop)          # copies, so that the rest of the record can be freed
        note = (f"analysed {(self.time_s[stop - 1] - self.time_s[start]) / 3600.0:.2f} h of the record's "
                f"{self.duration_s / 3600.0:.2f} h: t = {self.time_s[start]:.1f} s to {self.time_s[stop - 1]:.1f} s")
        return dataclasses.replace(
            self, time_s=self.time_s[part].copy(), flange_K=self.flange_K[part].copy(),
            ptc_stage_K=self.ptc_stage_K[part].copy(), heater_w=self.heater_w[part].copy(),
            setpoint_K=self.setpoint_K[part].copy(), notes=self.notes + [note],
            heater_change_s=None if self.heater_change_s is None else self.heater_change_s[part].copy())

    @classmethod
    def from_record(cls, record: Record) -> "RecordData":
        """Check a record for analysis.

        Raises
        ------
        cryod.records.record.RecordFormatError
            Naming the record and what is wrong: too short, a heater value
            missing or negative, no temperatures.
        """
        source = record.source or "<record>"
        time_s, notes = sample_instants(record)
        heater = np.asarray(record.heater_w, dtype=float)
        notes = list(record.warnings) + notes
        if time_s.size < MINIMUM_SAMPLES or time_s[-1] - time_s[0] < MINIMUM_DURATION_S:
            raise RecordFormatError(source, None, f"too short to analyse: {time_s.size} samples over "
                                    f"{time_s[-1] - time_s[0] if time_s.size else 0.0:.1f} s (need at least "
                                    f"{MINIMUM_SAMPLES} samples and {MINIMUM_DURATION_S:.0f} s)")
        if not np.all(np.isfinite(heater)):
            row = int(np.flatnonzero(~np.isfinite(heater))[0])
            raise RecordFormatError(source, None, f"column 'heater_W' is empty or not finite at data row {row + 1} "
                                    f"(t = {time_s[row]:.3f} s): the heater is the model's input and must be known")
        if np.any(heater < 0.0):
            row = int(np.flatnonzero(heater < 0.0)[0])
            raise RecordFormatError(source, None, f"column 'heater_W' is negative at data row {row + 1} "
                                    f"(t = {time_s[row]:.3f} s, {heater[row]} W): a heater cannot cool")
        flange = np.asarray(record.flange_K, dtype=float)
        stage = np.asarray(record.ptc_stage_K, dtype=float)
        valid = np.isfinite(flange) & np.isfinite(stage)
        if np.count_nonzero(valid) < MINIMUM_SAMPLES:
            raise RecordFormatError(source, None, "too few rows with both 'T2_K' and 'T5_K' present")
        if not valid.all():
            notes.append(f"{np.count_nonzero(~valid)} rows without T2 or T5 are left out of every comparison")
        limit = heater_limit_from_metadata(record)
        if limit is not None:
            notes.append(f"heater limit {limit:.4g} W from the record's metadata")
        return cls(time_s, flange, stage, heater, np.asarray(record.setpoint_K, dtype=float), limit, source, notes,
                   heater_change_instants(record, time_s))


def read_record_data(path: str | Path, max_duration_s: float | None = None) -> RecordData:
    """Read a record file for analysis: the required columns and :data:`ANALYSED_COLUMNS`, checked.

    Parameters
    ----------
    path : str or pathlib.Path
    max_duration_s : float, optional
        A record longer than this (s) is cut to the stretch of this length
        where the heater moves most
        (:func:`cryod.analysis.record_window.busiest_stretch`), with a note
        saying which; None or 0: the whole record.

    Raises
    ------
    cryod.records.record.RecordFormatError
        The file cannot be read as a record, or cannot be analysed (the
        file, the line or row and what is wrong named).
    """
    return analysed_stretch(RecordData.from_record(read_record(path, columns=ANALYSED_COLUMNS)), max_duration_s)


def analysed_stretch(data: RecordData, max_duration_s: float | None) -> RecordData:
    """``data`` itself, or, if longer than ``max_duration_s`` (s), its stretch of that length where the
    heater moves most (:func:`cryod.analysis.record_window.busiest_stretch`), with a note saying which."""
    if not max_duration_s or data.duration_s <= max_duration_s:
        return data
    start, stop = busiest_stretch(data.time_s, data.heater_w, max_duration_s, data.valid)
    part = data.stretch(start, stop)
    part.notes[-1] += f", the {max_duration_s / 3600.0:.2f} h where the heater's 10 s means vary most"
    return part


#: Sample instants of the two thermometers further apart than this (s) are worth a note.
SAMPLE_INSTANT_TOLERANCE_S = 0.001


def sample_instants(record: Record) -> tuple[np.ndarray, list[str]]:
    """The instants the record's temperatures stand for (s), and notes on them.

    ``T2_sample_s`` where the record has it (the daemon writes the middle of
    each reading's integration: a NORMal autozero moves it by one integration
    every third reading), else the trigger instants ``time_s``.
    """
    time_s = np.asarray(record.time_s, dtype=float)
    flange = record.columns.get("T2_sample_s")
    if flange is None or not np.all(np.isfinite(flange)) or np.any(np.diff(flange) <= 0.0):
        return time_s, []
    notes = []
    delay = flange - time_s
    if np.ptp(delay) > SAMPLE_INSTANT_TOLERANCE_S:
        notes.append(f"readings stand for instants {1e3 * delay.min():.1f} to {1e3 * delay.max():.1f} ms after "
                     f"their triggers (autozero or line sync): the T2_sample_s column is used")
    stage = record.columns.get("T5_sample_s")
    if stage is not None and np.nanmax(np.abs(stage - flange)) > SAMPLE_INSTANT_TOLERANCE_S:
        notes.append(f"T5 was read up to {1e3 * np.nanmax(np.abs(stage - flange)):.1f} ms away from T2; "
                     f"both are compared at T2's instants")
    return np.asarray(flange, dtype=float), notes


def heater_change_instants(record: Record, sample_s: np.ndarray) -> np.ndarray | None:
    """When each row's heater power took effect (s): ``heater_set_s`` where the record has it and it
    lies between the row's sample instant and the next (else that sample instant); None without it."""
    set_s = record.columns.get("heater_set_s")
    if set_s is None or not np.any(np.isfinite(set_s)):
        return None
    following = np.append(sample_s[1:], np.inf)
    usable = np.isfinite(set_s) & (set_s >= sample_s) & (set_s < following)
    return np.where(usable, set_s, sample_s)


def heater_limit_from_metadata(record: Record) -> float | None:
    """Heater power limit (W): stated, or resistance times current limit squared; None if not given."""
    def first(keys):
        for key in keys:
            if key in record.metadata:
                try:
                    return record.metadata_number(key)
                except RecordFormatError:
                    return None
        return None

    stated = first(POWER_LIMIT_KEYS)
    if stated is not None and stated > 0.0:
        return float(stated)
    resistance, current = first(RESISTANCE_KEYS), first(CURRENT_LIMIT_KEYS)
    if resistance and current and resistance > 0.0 and current > 0.0:
        return float(resistance * current ** 2)
    return None


def block_length_s(duration_s: float) -> float:
    """Length of the fit / held-out blocks for a record of this duration (s)."""
    low, high = BLOCK_BOUNDS_S
    return float(min(max(duration_s * BLOCK_FRACTION, low), high))


def fit_block_mask(time_s) -> np.ndarray:
    """True on the fit blocks (the first, third, ...), False on the held-out ones."""
    time_s = np.asarray(time_s, dtype=float)
    length = block_length_s(float(time_s[-1] - time_s[0]))
    block = np.floor((time_s - time_s[0]) / length).astype(int)
    return block % 2 == 0


def saturation_fraction(heater_w: np.ndarray, limit_w: float | None) -> tuple[float, float]:
    """Fractions of samples with the heater at 0 W and at its limit (the limit part is 0 if unknown)."""
    at_zero = float(np.mean(heater_w <= 0.0))
    at_limit = float(np.mean(heater_w >= limit_w * (1.0 - 1e-6))) if limit_w else 0.0
    return at_zero, at_limit


def _read_only(array: np.ndarray) -> np.ndarray:
    """``array``, made read-only (a value the record keeps for every caller)."""
    array.setflags(write=False)
    return array


__all__ = ["ANALYSED_COLUMNS", "RecordData", "analysed_stretch", "read_record_data", "fit_block_mask", "block_length_s", "heater_limit_from_metadata",
           "saturation_fraction"]
