"""Zones: temperature ranges, each with its own PI gains, feedforward model and heater limit.

A cryostat regulated from 4 K to 25 K is a different plant at each end (docs/explanation/cryostat-model.md: 18 times
slower at 24 K than at 4.23 K), so one set of gains and one controller model cannot serve the
whole range. As on a Lake Shore 336, the configuration may give a table of zones,
``control.zones``, each up to an upper temperature; the zone in use is the one holding the
setpoint in use (where a ramp has got to), and crossing into another zone changes the gains,
the feedforward's model and the heater's limit bumplessly (the PI integral takes the
difference). Without the table the regulator runs on ``control.pi`` and ``control.feedforward``
alone, as before.

Configuration, ``control.zones``: a list, or the name of a file holding ``zones:`` with the list
(as ``cryod tune --zones`` writes it), relative to the configuration's folder::

    zones:
      - upper_K: 6.5                      # this zone: setpoints up to 6.5 K (above the previous zone's)
        pi: {proportional_W_per_K: 12.0, integral_W_per_K_s: 4.0}
        feedforward_model: model-5K.yaml  # optional: the feedforward's model in this zone
        max_heater_power_W: 1.0           # optional: the heater's range in this zone, at most R * I_max**2
      - upper_K: 25.0
        pi: {proportional_W_per_K: 30.0, integral_W_per_K_s: 2.0}

Examples
--------
>>> from cryod.control.pi import MAX_GAIN, PiGains
>>> table = ZoneTable((Zone(6.5, PiGains(12.0, 4.0)), Zone(25.0, PiGains(30.0, 2.0), max_heater_power_W=8.0)))
>>> table.index_for(5.0), table.index_for(6.5), table.index_for(6.51)
(0, 0, 1)
>>> table.zones[1].describe(1)
'zone 2 (up to 25 K): Kp 30 W/K, Ki 2 W/(K s), feedforward model of control.feedforward, heater up to 8 W'
"""

from __future__ import annotations

import bisect
import dataclasses
from dataclasses import dataclass
from pathlib import Path

from cryod.control.pi import MAX_GAIN, PiGains
from cryod.model import CryostatModel, load_model
from cryod.yaml_source import FileFormatError, Section

#: Most zones a table may have (a Lake Shore 336 has ten).
MAX_ZONES = 20


@dataclass(frozen=True)
class Zone:
    """One zone: setpoints up to ``upper_K`` (above the previous zone's).

    Attributes
    ----------
    upper_K : float
        The zone's upper temperature (K); a setpoint exactly at it is in this zone.
    gains : PiGains
        The PI gains in the zone (W/K, W/(K s)).
    feedforward_model : CryostatModel, optional
        The feedforward's controller model in the zone (None: the one of ``control.feedforward``).
    feedforward_model_source : str
        Where that model came from.
    max_heater_power_W : float, optional
        The heater's range in the zone, 0 to this (W; None: R * I_max**2).
    """

    upper_K: float
    gains: PiGains
    feedforward_model: CryostatModel | None = None
    feedforward_model_source: str = ""
    max_heater_power_W: float | None = None

    def describe(self, index: int) -> str:
        """One line for the record's events and the journal (``index`` counts from 0)."""
        model = self.feedforward_model_source or "of control.feedforward"
        heater = f"heater up to {self.max_heater_power_W:g} W" if self.max_heater_power_W is not None \
            else "heater up to R * I_max^2"
        return (f"zone {index + 1} (up to {self.upper_K:g} K): Kp {self.gains.proportional_w_per_K:g} W/K, "
                f"Ki {self.gains.integral_w_per_K_s:g} W/(K s), feedforward model {model}, {heater}")

    def settings_for(self, term_name: str, settings):
        """A control term's settings in this zone: the zone's gains for ``pi``, its model for ``feedforward``
        (when it has one); any other term's as configured."""
        if term_name == "pi":
            return self.gains
        if term_name == "feedforward" and self.feedforward_model is not None:
            return dataclasses.replace(settings, model=self.feedforward_model,
                                       model_source=self.feedforward_model_source)
        return settings

    def to_dict(self) -> dict:
        """The zone as written in a table (``feedforward_model`` only when it came from a file)."""
        data = {"upper_K": self.upper_K, "pi": {"proportional_W_per_K": self.gains.proportional_w_per_K,
                                                "integral_W_per_K_s": self.gains.integral_w_per_K_s}}
        if self.feedforward_model_source and self.feedforward_model is not None:
            data["feedforward_model"] = self.feedforward_model_source
        if self.max_heater_power_W is not None:
            data["max_heater_power_W"] = self.max_heater_power_W
        return data


@dataclass(frozen=True)
class ZoneTable:
    """The zones in increasing order of their upper temperatures."""

    zones: tuple[Zone, ...]
    source: str = ""

    def __post_init__(self):
        if not self.zones:
            raise ValueError("a zone table needs at least one zone")
        uppers = [zone.upper_K for zone in self.zones]
        if any(high <= low for low, high in zip(uppers, uppers[1:])):
            raise ValueError(f"the zones' upper temperatures must increase, got {uppers}")

    def index_for(self, setpoint_K: float) -> int:
        """The zone holding ``setpoint_K`` (K): the first whose upper temperature is at or above it;
        the last one above them all."""
        index = bisect.bisect_left([zone.upper_K for zone in self.zones], setpoint_K)
        return min(index, len(self.zones) - 1)

    def lower_K(self, index: int, floor_K: float) -> float:
        """The zone's lower temperature (the previous zone's upper; ``floor_K`` for the first)."""
        return floor_K if index == 0 else self.zones[index - 1].upper_K


def zone_table_from(control: Section, setpoint_min_K: float, setpoint_max_K: float,
                    heater_max_power_w: float) -> ZoneTable | None:
    """The ``control.zones`` table, checked, or None when absent.

    Checked: at least one zone and at most :data:`MAX_ZONES`; upper temperatures increasing (contiguous
    ranges, no overlap) and the last at or above ``control.setpoint_max_K`` (every setpoint allowed has a
    zone); gains above 0; every feedforward model loadable; a heater limit above 0 and at most
    R * I_max**2. Errors name the file, line and key (the table's own file when it is included).
    """
    value = control.data.get("zones")
    if value is None:
        control.section("zones", None)          # taken: null means no zones
        return None
    holder = control
    if isinstance(value, str):
        path = _relative(control.text("zones"), control.source)
        holder = Section.from_file(path)
    items = holder.sections("zones")
    if not items:
        raise holder.error("zones", "give at least one zone, or null for none")
    if len(items) > MAX_ZONES:
        raise holder.error("zones", f"{len(items)} zones: at most {MAX_ZONES}")
    zones = []
    for item in items:
        upper = item.number("upper_K", minimum=0.0, exclusive_minimum=True)
        if zones and not upper > zones[-1].upper_K:
            raise item.error("upper_K", f"{upper:g} K is not above the previous zone's {zones[-1].upper_K:g} K: "
                                        f"give the zones in increasing order of their upper temperatures, without "
                                        f"overlap")
        pi = item.section("pi")
        gains = PiGains(pi.number("proportional_W_per_K", minimum=0.0, exclusive_minimum=True, maximum=MAX_GAIN),
                        pi.number("integral_W_per_K_s", minimum=0.0, exclusive_minimum=True, maximum=MAX_GAIN))
        pi.finish()
        model, model_source = None, ""
        model_path = item.text("feedforward_model", None)
        if model_path is not None:
            try:
                model = load_model(_relative(model_path, item.source))
            except FileFormatError as error:
                raise item.error("feedforward_model", f"controller model not usable: {error}") from None
            if model.temperature_dependence is not None:
                raise item.error("feedforward_model", f"{model_path} is a temperature-dependent cryostat, not a "
                                                      f"controller's model: give the linear model of the zone "
                                                      f"(cryod identify, or cryod tune --zones)")
            model_source = model_path
        limit = item.number("max_heater_power_W", None, minimum=0.0, exclusive_minimum=True)
        if limit is not None and limit > heater_max_power_w:
            raise item.error("max_heater_power_W", f"{limit:g} W is above the heater's R * I_max^2 = "
                                                   f"{heater_max_power_w:g} W (heater section)")
        item.finish()
        zones.append(Zone(upper, gains, model, model_source, limit))
    if zones[0].upper_K <= setpoint_min_K:
        raise items[0].error("upper_K", f"{zones[0].upper_K:g} K: the first zone ends at or below "
                                        f"control.setpoint_min_K {setpoint_min_K:g} K and would hold no setpoint")
    if zones[-1].upper_K < setpoint_max_K:
        raise items[-1].error("upper_K", f"{zones[-1].upper_K:g} K: the last zone ends below "
                                         f"control.setpoint_max_K {setpoint_max_K:g} K; setpoints up to it would "
                                         f"have no zone (raise this upper temperature or lower setpoint_max_K)")
    if holder is not control:
        holder.finish()
    return ZoneTable(tuple(zones), source=holder.source)


def _relative(path: str, source: str) -> Path:
    candidate = Path(path).expanduser()
    if not candidate.is_absolute() and source and not source.startswith("<"):
        candidate = Path(source).resolve().parent / candidate
    return candidate
