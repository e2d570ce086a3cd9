"""Identification at a list of setpoints: one experiment and one model per setpoint (a zone each).

At each setpoint the experiment (:mod:`cryod.identification.experiment`) regulates there until the
heater power has settled, holds (the line) and steps the setpoint a little; the model is fitted to
the hold and the step alone (:func:`part_about_setpoint`): the approach crossed the cryostat's
range, where no one linear model holds. Each model states its uncertainties as any identified model
does.

Examples
--------
>>> model_file_name(12.0), model_file_name(4.5)
('model-12K.yaml', 'model-4.5K.yaml')
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from cryod.analysis.record_data import RecordData
from cryod.identification.experiment import ExperimentPlan
from cryod.identification.fit import IdentificationError
from cryod.identification.model_fit import ModelIdentification, identify_model
from cryod.model import CryostatModel

#: A fit about a setpoint leaving more than this many times T2's noise on T2 is refused: a fit that describes
#: its record leaves about 1; the closed-loop fits about 24 K that do not describe theirs left 71 to 83.
MAX_RESIDUAL_IN_NOISE = 30.0


def model_file_name(setpoint_K: float) -> str:
    """The model file of a setpoint: ``model-<K>K.yaml``."""
    return f"model-{setpoint_K:g}K.yaml"


def part_about_setpoint(data: RecordData, line_hold_s: float) -> RecordData:
    """The samples from ``line_hold_s`` before the setpoint step to the end (the hold and the step about the
    setpoint); the whole record when its setpoint never changes once set."""
    setpoint = data.setpoint_K
    steps = np.flatnonzero(np.isfinite(setpoint[:-1]) & np.isfinite(setpoint[1:]) & (setpoint[1:] != setpoint[:-1]))
    if steps.size == 0:
        return data
    start = int(np.searchsorted(data.time_s, data.time_s[steps[-1] + 1] - line_hold_s))
    return data.stretch(start, data.time_s.size)


def records_about_setpoint(records: Sequence[RecordData], line_hold_s: float) -> list[RecordData]:
    """The hold and the step of an experiment's records (in time order, daily files): from the last record
    whose setpoint changes (the step), cut by :func:`part_about_setpoint`, and the records after it whole; the
    records before it held the approach (an experiment of hours crosses UTC midnight)."""
    changes = [index for index, data in enumerate(records) if part_about_setpoint(data, line_hold_s) is not data]
    first = changes[-1] if changes else 0
    return [part_about_setpoint(records[first], line_hold_s), *records[first + 1:]]


@dataclass
class SetpointModel:
    """The model identified at one setpoint, and the records it came from."""

    setpoint_K: float
    identification: ModelIdentification
    record_paths: list[Path]

    @property
    def model(self) -> CryostatModel:
        return self.identification.model


def plans_at(setpoints_K: Sequence[float], plan: ExperimentPlan) -> list[ExperimentPlan]:
    """The plan at each setpoint (increasing, distinct), refused with the reason when one cannot be."""
    ordered = list(setpoints_K)
    if not ordered or any(high <= low for low, high in zip(ordered, ordered[1:])):
        raise ValueError(f"give the setpoints in increasing order, each once, got {', '.join(map(str, ordered))}")
    plans = [dataclasses.replace(plan, setpoint_K=float(setpoint)) for setpoint in ordered]
    for each in plans:
        each.check(math.inf)
    return plans


def identify_at_setpoint(setpoint_K: float, records: Sequence[RecordData], record_paths: Sequence[Path],
                         base: CryostatModel, line_hold_s: float, **fit_options) -> SetpointModel:
    """Fit the model about ``setpoint_K`` to the hold and the step of its records (``fit_options`` go to
    :func:`cryod.identification.model_fit.identify_model`)."""
    parts = records_about_setpoint(records, line_hold_s)
    result = identify_model(parts, base, **fit_options)
    off = result.model.operating_point.flange_temperature_K
    gain = result.model.heater_to_thermometer.dc_gain
    left = max((flange for flange, _ in result.residual_rms_in_noise), default=0.0)
    if left > MAX_RESIDUAL_IN_NOISE:
        raise IdentificationError(
            f"about {setpoint_K:g} K the fit leaves {left:.0f} times T2's noise on T2 (more than "
            f"{MAX_RESIDUAL_IN_NOISE:g}): the model does not describe the record (its static gain "
            f"{gain:.4g} K/W); see docs/how-to/zones.md, \"Across a range of temperatures\"")
    if not gain > 0.0:
        raise IdentificationError(
            f"about {setpoint_K:g} K the fit's static gain is {gain:.4g} K/W: more heater would cool the flange; the "
            f"record does not identify the cryostat there (docs/how-to/zones.md, \"Across a range of temperatures\")")
    if not off > 0.0:
        slowest = max(result.model.heater_to_thermometer.time_constants_s, default=0.0)
        fitted = sum(part.duration_s for part in parts)
        raise IdentificationError(
            f"about {setpoint_K:g} K the fit's static gain ({result.model.heater_to_thermometer.dc_gain:.4g} K/W) puts "
            f"the cryostat at {off:.4g} K with the heater off: the records do not fix it (the slowest time constant "
            f"fitted, {slowest:.0f} s, against {fitted:.0f} s of hold and step); in closed loop a longer step does "
            f"not help where the cryostat is slow (docs/how-to/zones.md, \"Across a range of temperatures\")")
    names = ", ".join(map(str, record_paths))
    result.model = dataclasses.replace(
        result.model, name=f"identified at {setpoint_K:g} K",
        description=f"Identified by cryod identify about T2 = {setpoint_K:g} K (the hold and the step of {names}).")
    return SetpointModel(float(setpoint_K), result, list(map(Path, record_paths)))


def run_series(plans: Sequence[ExperimentPlan], acquire_one: Callable[[ExperimentPlan], object]) -> list:
    """Run ``acquire_one(plan)`` for each plan in turn; stop at the first that does not finish.

    Returns the acquisitions made (the last one not finished when the series stopped early)."""
    done = []
    for plan in plans:
        acquisition = acquire_one(plan)
        done.append(acquisition)
        if getattr(acquisition, "outcome", "finished") != "finished":
            break
    return done
