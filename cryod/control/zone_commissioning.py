"""Commissioning across the range: a zone per identified model, its gains, the table, the limit at each setpoint.

A lab identifies its cryostat at a list of setpoints (``cryod identify --acquire --setpoints``: one
model per setpoint); each model becomes a zone. :func:`zone_uppers` puts the boundaries half-way
between the setpoints; :func:`tune_zones` suggests the gains of each zone on its own model, for the
move the lab makes into it (from the previous setpoint, at the configured ramp);
:func:`zone_table_text` writes the table a configuration pastes under ``control:`` or names as
``control.zones: FILE``; :func:`limits_across_range` gives the feedforward's physical limit at each
setpoint, with the model that holds there, so a lab sees where active suppression helps.

Examples
--------
>>> zone_uppers([5.0, 8.0, 12.0], setpoint_max_K=20.0)
[6.5, 10.0, 20.0]
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import yaml

from cryod.control.feedforward.limit import FeedforwardLimitError, feedforward_limit
from cryod.control.pi import MAX_GAIN, PiGains
from cryod.control.tuning import Tolerances, Tuning, TuningError, suggest_gains
from cryod.control.zones import Zone, ZoneTable
from cryod.model import CryostatModel, linearised_at

#: The search over each zone's gains (:func:`cryod.control.tuning.suggest_gains`): the plant slows and weakens
#: by two orders of magnitude across 4-25 K, and so do the gains it needs, up to what a configuration takes.
ZONE_SEARCH = {"proportional_range_w_per_K": (0.5, MAX_GAIN), "integral_time_range_s": (10.0, 5000.0),
               "grid": (4, 4), "refine_evaluations": 8}
#: The finer search a zone gets when the coarse one finds no gains within the tolerances: the gains that meet
#: them can lie between the coarse grid's points (a 1000 ohm heater at 5 K: only Kp near 80 W/K holds the
#: cooler's line within 1.05x), and a zone is refused only when this one finds none either.
FINE_ZONE_SEARCH = {**ZONE_SEARCH, "grid": (5, 5), "refine_evaluations": 10}


def zone_uppers(setpoints_K: Sequence[float], setpoint_max_K: float) -> list[float]:
    """Each zone's upper temperature (K): half-way to the next setpoint; the last at ``setpoint_max_K``
    (or at its setpoint, when higher)."""
    ordered = list(setpoints_K)
    if not ordered or any(high <= low for low, high in zip(ordered, ordered[1:])):
        raise ValueError(f"give the setpoints in increasing order, got {ordered}")
    uppers = [0.5 * (low + high) for low, high in zip(ordered, ordered[1:])]
    return uppers + [max(setpoint_max_K, ordered[-1])]


def start_heater_w(model: CryostatModel, start_K: float) -> float:
    """The heater power holding ``start_K`` on a zone's (linear) model, 0 below its heater-off temperature (W)."""
    gain = model.heater_to_thermometer.dc_gain
    return max((start_K - model.operating_point.flange_temperature_K) / gain, 0.0)


@dataclass(frozen=True)
class ZoneTuning:
    """One zone's commissioning: its setpoint, model, the move it was tuned for and the search's result."""

    setpoint_K: float
    upper_K: float
    model: CryostatModel
    model_source: str
    start_K: float
    tuning: Tuning

    @property
    def gains(self) -> PiGains:
        return self.tuning.best.gains


def tune_zones(zone_models: Sequence[tuple[float, CryostatModel, str]], heater_max_w: float, *,
               setpoint_max_K: float, ramp_K_per_min: float = 0.0, tolerances: Tolerances = Tolerances(),
               duration_s: Callable[[CryostatModel], float] | float = 900.0, period_s: float = 0.08,
               first_start_K: float | None = None, progress: Callable[[str], None] | None = None,
               **search) -> list[ZoneTuning]:
    """Suggest each zone's gains on its own model, for the move into it from the previous setpoint.

    Parameters
    ----------
    zone_models : sequence of (setpoint_K, model, source)
        One identified model per setpoint, setpoints increasing; ``source`` is how the table names it.
    heater_max_w : float
        R * I_max**2 (W).
    setpoint_max_K : float
        The last zone's upper temperature (``control.setpoint_max_K``).
    ramp_K_per_min : float
        The ramp the moves are made at (``control.ramp_K_per_min``).
    tolerances : Tolerances
    duration_s : float or callable
        Length of each zone's run (s), or a function of the zone's model giving it.
    first_start_K : float, optional
        Where the first zone's move starts (default: its model's heater-off temperature).
    progress : callable, optional
        Told each zone's result as a line of text.
    **search
        Passed to :func:`cryod.control.tuning.suggest_gains` (ranges, grid, refinement), in place of
        :data:`ZONE_SEARCH`'s.

    Returns
    -------
    list of ZoneTuning

    Raises
    ------
    cryod.control.tuning.TuningError
        A zone where no gains meet the tolerances (names the zone).
    """
    search = {**ZONE_SEARCH, **search}
    finer = {**search, "grid": FINE_ZONE_SEARCH["grid"], "refine_evaluations": FINE_ZONE_SEARCH["refine_evaluations"]}
    searches = [search] if search.get("grid") == FINE_ZONE_SEARCH["grid"] else [search, finer]
    setpoints = [setpoint for setpoint, _, _ in zone_models]
    uppers = zone_uppers(setpoints, setpoint_max_K)
    results = []
    for index, ((setpoint, model, source), upper) in enumerate(zip(zone_models, uppers)):
        start = setpoints[index - 1] if index else (first_start_K if first_start_K is not None
                                                    else model.operating_point.flange_temperature_K)
        length = duration_s(model) if callable(duration_s) else duration_s
        for attempt, zone_search in enumerate(searches, start=1):
            try:
                tuning = suggest_gains(model, setpoint, heater_max_w, tolerances=tolerances,
                                       start_heater_w=start_heater_w(model, start), duration_s=length,
                                       period_s=period_s, ramp_K_per_min=ramp_K_per_min, **zone_search)
                break
            except ValueError as error:     # no gains found (TuningError): the finer search, if there is one
                if not isinstance(error, TuningError) or attempt == len(searches):
                    raise type(error)(f"zone {index + 1} (setpoint {setpoint:g} K, model {source}): {error}") \
                        from None
        results.append(ZoneTuning(setpoint, upper, model, source, start, tuning))
        if progress is not None:
            best = tuning.best
            progress(f"zone {index + 1} (up to {upper:g} K, {start:g} -> {setpoint:g} K): Kp "
                     f"{best.gains.proportional_w_per_K:.4g} W/K, Ki {best.gains.integral_w_per_K_s:.4g} W/(K s), "
                     f"within 1 mK after {best.settle_s:.0f} s, overshoot {best.overshoot_K * 1e3:.2f} mK")
    return results


def zone_table(tunings: Sequence[ZoneTuning], *, with_models: bool = True,
               max_heater_power_W: float | None = None) -> ZoneTable:
    """The zone table of a commissioning (each zone's model as the feedforward's when ``with_models``)."""
    return ZoneTable(tuple(Zone(item.upper_K, item.gains, item.model if with_models else None,
                                item.model_source if with_models else "", max_heater_power_W)
                           for item in tunings))


def zone_table_text(table: ZoneTable, header: str = "") -> str:
    """The table as YAML: ``zones:`` and its list, to paste under ``control:`` (indented) or to name as
    ``control.zones: FILE``; ``header`` goes first as comment lines."""
    comments = "".join(f"# {line}".rstrip() + "\n" for line in header.splitlines())
    body = yaml.safe_dump({"zones": [_plain(zone.to_dict()) for zone in table.zones]}, sort_keys=False,
                          default_flow_style=None, width=110)
    return comments + body


def _plain(value):
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, float):
        return float(f"{value:.6g}")
    return value


@dataclass(frozen=True)
class RangeLimit:
    """The feedforward's limit at one setpoint (K, W), or why there is none."""

    setpoint_K: float
    model_name: str
    open_line_K: float = math.nan
    ptc_periodic_limit_K: float = math.nan
    authority: float = math.nan
    mean_heater_power_W: float = math.nan
    limited_by: str = ""
    predicted_best_residual_K: float = math.nan
    problem: str = ""

    def to_dict(self) -> dict:
        return {key: (None if isinstance(value, float) and not math.isfinite(value) else value)
                for key, value in self.__dict__.items()}


def limits_across_range(setpoints_K: Sequence[float], model_at: Callable[[float], CryostatModel],
                        heater_resistance_ohm: float, max_current_A: float, period_s: float = 0.08,
                        heater_delay_s: float = 0.0, **options) -> list[RangeLimit]:
    """The feedforward's physical limit at each setpoint, with the model that holds there.

    ``model_at(setpoint_K)`` gives it: :func:`model_at_temperature` for a temperature-dependent
    cryostat, or a zone table's model (:func:`model_of_zone`). ``options`` go to
    :func:`cryod.control.feedforward.limit.feedforward_limit` (``averaging_time_s``: the noise floor's).
    """
    rows = []
    for setpoint in setpoints_K:
        model = model_at(setpoint)
        try:
            limit = feedforward_limit(model, setpoint, heater_resistance_ohm, max_current_A, period_s,
                                      heater_delay_s=heater_delay_s, certify=False, **options)
        except (FeedforwardLimitError, ValueError) as error:
            rows.append(RangeLimit(setpoint, model.name, problem=str(error)))
            continue
        rows.append(RangeLimit(setpoint, model.name, limit.open_line_K, limit.ptc_periodic_limit_K, limit.authority,
                               limit.mean_heater_power_W, limit.limited_by, limit.predicted_best_residual_K))
    return rows


def model_at_temperature(model: CryostatModel) -> Callable[[float], CryostatModel]:
    """``model_at`` for :func:`limits_across_range`: the model itself, or its tangent model at each setpoint
    when it depends on temperature."""
    if model.temperature_dependence is None:
        return lambda setpoint_K: model
    return lambda setpoint_K: linearised_at(model, setpoint_K)


def model_of_zone(table: ZoneTable, default: CryostatModel) -> Callable[[float], CryostatModel]:
    """``model_at`` for :func:`limits_across_range`: the feedforward's model of the zone holding each setpoint."""
    return lambda setpoint_K: table.zones[table.index_for(setpoint_K)].feedforward_model or default
