"""Whether the heater can hold a setpoint: the steady-state power it needs against 0 W and R I_max^2.

The heater only heats (P >= 0) and saturates at R I_max^2, and the mean power
at a setpoint is set by the thermal balance there: (T_set - T2_0) / DC gain of
the heater path, in the controller's model. A setpoint that needs more than the
top, or less than 0 W, cannot be held: the loop would sit at the heater's top
(or at 0 W) with T2 short of the setpoint. Such a setpoint is still taken (the
model can be wrong); the command's reply, the journal and the status say so,
with the numbers.

With zones (``control.zones``) the setpoint is judged in the zone that holds it:
that zone's feedforward model (else ``control.feedforward``'s) and its heater
limit when it has one (else R I_max^2), the model and the top the regulator
will run on there.

Examples
--------
>>> from cryod.model import load_model
>>> reach = setpoint_reach(load_model(), 16.0, 0.5)
>>> round(reach.power_needed_W, 2), round(reach.highest_K, 2)
(1.73, 7.64)
>>> print(reach.warning())
setpoint 16 K needs about 1726 mW of heater power in steady state (shipped model), above the heater's top, R I_max^2 = 500 mW: it holds the flange at about 7.64 K at most, where the heater stays at its top
>>> setpoint_reach(load_model(), 5.0, 0.5).warning() is None
True
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from cryod.model import CryostatModel


@dataclass(frozen=True)
class SetpointReach:
    """The heater power a setpoint needs and the range of setpoints the heater can hold.

    Attributes
    ----------
    setpoint_K : float
    power_needed_W : float
        Mean heater power that holds the flange at the setpoint in steady state (W; negative: below
        the flange's heater-off temperature).
    max_power_W : float
        The heater's top, R I_max^2 (W).
    lowest_K, highest_K : float
        The flange's temperature with the heater at 0 W and at its top (K).
    model_source : str
        Which model says so.
    top_source : str
        What sets the top (R I_max^2, or a zone's heater limit).
    """

    setpoint_K: float
    power_needed_W: float
    max_power_W: float
    lowest_K: float
    highest_K: float
    model_source: str
    top_source: str = "the heater's top, R I_max^2"

    @property
    def holdable(self) -> bool:
        return 0.0 <= self.power_needed_W <= self.max_power_W

    def warning(self) -> str | None:
        """Why the heater cannot hold the setpoint, with the numbers; None when it can."""
        if self.power_needed_W > self.max_power_W:
            return (f"setpoint {self.setpoint_K:g} K needs about {self.power_needed_W * 1e3:.0f} mW of heater power in "
                    f"steady state ({self.model_source}), above {self.top_source} = "
                    f"{self.max_power_W * 1e3:.0f} mW: it holds the flange at about {self.highest_K:.2f} K at most, "
                    f"where the heater stays at its top")
        if self.power_needed_W < 0.0:
            return (f"setpoint {self.setpoint_K:g} K is below the flange's {self.lowest_K:.2f} K with the heater at "
                    f"0 W ({self.model_source}): the heater cannot cool, it stays at 0 W with the flange above the "
                    f"setpoint")
        return None


def setpoint_reach(model, setpoint_K: float, max_power_W: float, model_source: str = "shipped model",
                   top_source: str = "the heater's top, R I_max^2") -> SetpointReach:
    """The power ``setpoint_K`` needs in ``model`` against a heater whose top is ``max_power_W``.

    Parameters
    ----------
    model : cryod.model.CryostatModel
    setpoint_K : float
    max_power_W : float
        The heater's top (W): R I_max^2, or a zone's heater limit.
    model_source : str
        Named in the warning.
    top_source : str
        What sets the top, named in the warning.
    """
    from cryod.control.feedforward.limit import mean_heater_power_w

    lowest = model.operating_point.flange_temperature_K
    gain = model.heater_to_thermometer.dc_gain
    return SetpointReach(setpoint_K, mean_heater_power_w(model, setpoint_K), max_power_W, lowest,
                         lowest + gain * max_power_W, model_source, top_source)


def controller_model(control) -> tuple[CryostatModel, str]:
    """The controller's model and where it comes from: the feedforward's when configured, else the shipped one.

    Parameters
    ----------
    control : cryod.config.ControlConfig
    """
    for name, settings in control.terms:
        if name == "feedforward" and getattr(settings, "model", None) is not None:
            return settings.model, settings.model_source
    from cryod.model import DEFAULT_MODEL_PATH

    return _load(DEFAULT_MODEL_PATH), "shipped model"


@functools.lru_cache(maxsize=4)
def _load(path):
    from cryod.model import load_model

    return load_model(path)


def reach_at(control, setpoint_K: float, max_power_W: float) -> SetpointReach:
    """What the heater can do at ``setpoint_K`` with the model and top the regulator runs on there.

    Without zones: the controller's model (:func:`controller_model`) against R I_max^2. With zones: the
    zone holding ``setpoint_K``, its feedforward model (else the controller's) and its heater limit (else
    R I_max^2).

    Parameters
    ----------
    control : cryod.config.ControlConfig
    setpoint_K : float
    max_power_W : float
        R I_max^2 (W).
    """
    model, source = controller_model(control)
    top_source = "the heater's top, R I_max^2"
    zones = control.zones
    if zones is not None:
        index = zones.index_for(setpoint_K)
        zone = zones.zones[index]
        if zone.feedforward_model is not None:
            model, source = zone.feedforward_model, zone.feedforward_model_source or "the zone's model"
        source = f"zone {index + 1}: {source}"
        if zone.max_heater_power_W is not None and zone.max_heater_power_W < max_power_W:
            max_power_W, top_source = zone.max_heater_power_W, f"zone {index + 1}'s heater limit, max_heater_power_W"
    return setpoint_reach(model, setpoint_K, max_power_W, source, top_source)


def setpoint_warning(control, setpoint_K: float | None, max_power_W: float) -> str | None:
    """The warning for ``setpoint_K`` (None: holdable, or no setpoint), judged as :func:`reach_at` says."""
    if setpoint_K is None:
        return None
    return reach_at(control, setpoint_K, max_power_W).warning()
