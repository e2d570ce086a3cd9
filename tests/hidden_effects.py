"""Analyses of records with hidden effects, cached for the tests (catalog: simulated_hw.hidden_effects)."""

from __future__ import annotations

from functools import lru_cache

from cryod.analysis.cause_search.results import Analysis
from cryod.analysis.pipeline import analyze
from cryod.analysis.record_data import RecordData
from cryod.model import load_model
from cryod.records.record import Record
from simulated_hw import hidden_effects
from simulated_hw.hidden_effects import DISTURBANCES, EFFECT_GROUPS, MAGNITUDES, other_day, within  # noqa: F401
from simulated_hw.measurement_programs import make_record

from tests.conftest import CONFIG

DURATIONS_S = {"identification": 1200.0, "pi_only": 900.0}
SLOW_DURATIONS_S = {"identification": 3600.0, "pi_only": 1800.0}


def base_model():
    return load_model(CONFIG / "model.yaml")


def hidden_model(cause: str, magnitude: int, variant: int = 0):
    return hidden_effects.hidden_model(base_model(), cause, magnitude, variant)


def analysed(model, protocol: str, duration_s: float, seed: int, **disturbance) -> Analysis:
    record = make_record(model, protocol, duration_s=duration_s, seed=seed, **disturbance)
    data = RecordData.from_record(Record(record.metadata, record.columns, source=f"{protocol} record"))
    return analyze(data, base_model())


def real_model(cause: str, magnitude: int, variant: int = 0, perturbation: int | None = 0):
    """(model, truth): a hidden cause (or ``"none"``) on another day's cryostat whose base parameters are off
    by up to 5 % and 0.05 rad (``perturbation`` seeds the draw; None keeps the shipped parameters)."""
    if cause == "none":
        model, truth = other_day(base_model(), variant), {}
    else:
        model, truth = hidden_model(cause, magnitude, variant=variant)
    if perturbation is not None:
        model, _ = hidden_effects.perturbed_base(model, perturbation)
    return model, truth


@lru_cache(maxsize=None)
def analysed_case(cause: str, magnitude: int, protocol: str, duration_s: float, seed: int = 1,
                  perturbation: int | None = 0) -> Analysis:
    """A record of ``cause`` at a magnitude, on a cryostat with its base parameters off (``perturbation``)."""
    variant = magnitude if cause == "none" else magnitude + seed
    model, _ = real_model(cause, magnitude, variant, None if perturbation is None else perturbation + 17 * seed)
    return analysed(model, protocol, duration_s, seed)


def named_parameters(analysis: Analysis, cause: str) -> dict:
    """The fitted parameters of a cause the analysis named (refitted with the recalibration)."""
    for named in analysis.causes:
        if named.cause == cause:
            return named.fit.parameters
    raise AssertionError(f"{cause} is not named: {analysis.decision.reason}")


def parameter_errors(analysis: Analysis, cause: str, truth: dict) -> dict:
    """{parameter: (fitted, true)} for the truth's parameters, from the named cause's fit."""
    fitted = named_parameters(analysis, cause)
    return {name: (fitted.get(name), true) for name, true in truth.items()}


#: Every pair of causes from different groups (heater path, link and thermometers, cooler).
CROSS_GROUP_PAIRS = [(first, second) for index, group in enumerate(EFFECT_GROUPS.values())
                     for later in list(EFFECT_GROUPS.values())[index + 1:] for first in group for second in later]


def two_effect_model(causes, magnitude: int = 1, variant: int = 0, perturbation: int | None = 0):
    """(model, {cause: truth}): two hidden causes at one magnitude, base parameters off (``perturbation``)."""
    model, truths = hidden_effects.combined_model(base_model(), {cause: magnitude for cause in causes}, variant)
    if perturbation is not None:
        model, _ = hidden_effects.perturbed_base(model, perturbation)
    return model, truths
