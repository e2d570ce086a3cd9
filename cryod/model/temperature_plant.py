"""The cryostat from 4 K to 25 K: the identified model carried across temperature by physical laws.

A model with a ``temperature_dependence`` section (:class:`~cryod.model.temperature_laws.TemperatureDependence`)
is simulated by :class:`TemperatureDependentPlant`; the equations are in ``docs/explanation/cryostat-model.md``, section
"The cryostat from 4 K to 25 K". In short, with U the conduction potential of the flange's links:

* the PTC stage's mean temperature is the model's: ``T5 = T5_0 + G3 P`` (the cooler's load line and the
  stage's time constant as identified);
* the flange hangs on the stage through links that all follow one conductance law, so heat flows are
  linear in U: ``U(T2) = G2 [U(T5) - U(T5_0)] + L P`` with ``L = G2 (G1 - U'(T5_0) G3)``, the flange's
  paths (G2, L) with their time constants multiplied by the flange's time scale
  ``[c(T2)/c(T2_0)] / [K(T2)/K(T2_0)]``;
* the cooler's line reaches T2 through the model's G2 G_link C s with the same time scale, and its
  amplitude at the stage follows ``(T5_0 / T5)**p``.

At the model's operating point this is exactly the linear model (the tests hold it to it);
:func:`linearised_at` gives the linear model at any flange temperature, the plant a zone's controller
should know.

Examples
--------
>>> from cryod.model import load_model
>>> model = load_model(TEMPERATURE_MODEL_PATH)
>>> power_w, stage_K = steady_state(model, 24.0)
>>> round(power_w, 2), round(stage_K, 2)                  # heater power (W) and T5 (K) holding T2 at 24 K
(5.56, 18.75)
>>> plant = TemperatureDependentPlant(model, 0.0, power_w)
>>> plant.advance_to(100.0)
>>> round(plant.temperatures()[0], 3)                     # T2 (K): the line is 0.1 mK at 24 K
24.0
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

from cryod.model.dynamics import CryostatPlant, SimulatedRecord, flange_transfer_functions
from cryod.model.heater_path import HeaterPath
from cryod.model.parameters import CryostatModel, OperatingPoint
from cryod.model.transfer_function import TransferFunction

#: The shipped temperature-dependent cryostat (``config/model-4-25K.yaml``).
TEMPERATURE_MODEL_PATH = Path(__file__).resolve().parent.parent / "data" / "model-4-25K.yaml"
#: Longest hold with one time scale (s): the scale follows T2 at least this often.
MAX_HOLD_S = 0.25
#: Heater powers searched for a steady state (W).
MAX_STEADY_POWER_W = 1000.0


def link_transfer_function(model: CryostatModel) -> TransferFunction:
    """L = G2 (G1 - U'(T5_0) G3): heater power to the flange's conduction potential above what the stage's
    warming gives it (K/W)."""
    laws = model.temperature_dependence
    point = model.operating_point
    weight = float(laws.conductance_ratio(point.ptc_stage_temperature_K, point.flange_temperature_K))
    return model.flange_to_thermometer * (model.heater_to_flange - weight * model.heater_to_ptc_stage)


class TemperatureDependentPlant(CryostatPlant):
    """T2 and T5 of a model with a ``temperature_dependence`` section (same interface as CryostatPlant).

    Parameters
    ----------
    model : CryostatModel
        With ``temperature_dependence`` set and no effects.
    start_time_s : float
    initial_heater_power_w : float
        Heater power the cryostat has settled at before the start (W).
    ptc_cycle : optional
        The cooler's phase and frequency over time, instead of the model's own.
    """

    def __init__(self, model: CryostatModel, start_time_s: float = 0.0, initial_heater_power_w: float = 0.0,
                 ptc_cycle=None):
        if model.temperature_dependence is None:
            raise ValueError("the model has no temperature_dependence section: use CryostatPlant")
        super().__init__(model, start_time_s, initial_heater_power_w, ptc_cycle)
        self.laws = model.temperature_dependence
        point = model.operating_point
        self.flange_reference_K = point.flange_temperature_K
        self.stage_reference_K = point.ptc_stage_temperature_K
        self._stage_potential_K = float(self.laws.conduction_potential_K(self.stage_reference_K,
                                                                         self.flange_reference_K))
        delivered = self.delivered_power_w(self.commanded_power_w)
        self.flange_heater = HeaterPath(link_transfer_function(model))
        self.flange_heater.settle(delivered)
        #: The stage's warming, in the flange's conduction potential, reaching T2 through G2.
        self.stage_to_flange = HeaterPath(model.flange_to_thermometer)
        self.stage_to_flange.settle(self._stage_potential_above_rest(self.stage_heater.output()))

    def _stage_potential_above_rest(self, stage_rise_K) -> float:
        stage = self.stage_reference_K + stage_rise_K
        return float(self.laws.conduction_potential_K(stage, self.flange_reference_K)) - self._stage_potential_K

    # -- temperatures without the cooler's line ------------------------------------------
    def _mean_part(self, flange_potential_K, stage_rise_K) -> tuple[float, float]:
        """(T2, T5) without the line, from the flange's conduction potential (K of U) and the stage's rise (K)."""
        return (float(self.laws.temperature_K(flange_potential_K, self.flange_reference_K)),
                self.stage_reference_K + stage_rise_K)

    def mean_part(self) -> tuple[float, float]:
        """(T2, T5) in K now without the cooler's oscillation."""
        return self._mean_part(self.flange_heater.output() + self.stage_to_flange.output(),
                               self.stage_heater.output())

    def time_scale(self) -> float:
        """Factor on the flange's time constants now (from T2 without the line)."""
        return float(self.laws.flange_time_scale(self.mean_part()[0], self.flange_reference_K))

    def _hold_until(self, time_s: float) -> None:
        while time_s - self.time_s > 0.0:
            step = min(time_s - self.time_s, MAX_HOLD_S)
            scale = self.time_scale()
            self.stage_to_flange.input = self._stage_potential_above_rest(self.stage_heater.output())
            self.flange_heater.hold(step, scale)
            self.stage_to_flange.hold(step, scale)
            self.stage_heater.hold(step)
            self.time_s = time_s if step == time_s - self.time_s else self.time_s + step

    # -- outputs ------------------------------------------------------------------------
    def _with_line(self, flange_K: float, stage_K: float, flange_line, stage_line) -> tuple[float, float]:
        scale = float(self.laws.flange_time_scale(flange_K, self.flange_reference_K))
        factor = float(self.laws.stage_line_factor(stage_K, self.stage_reference_K))
        return flange_K + factor * scale * flange_line(scale), stage_K + factor * stage_line()

    def temperatures(self) -> tuple[float, float]:
        """(T2, T5) in K at the current instant, noise-free."""
        rotor, frequency = self.drive.cycle.rotor(self.time_s - self.start_time_s)
        flange, stage = self.mean_part()
        return self._with_line(flange, stage, lambda scale: self.flange_ptc.value_at(rotor, frequency, scale),
                               lambda: self.stage_ptc.value_at(rotor, frequency))

    def mean_temperatures(self, duration_s: float) -> tuple[float, float]:
        """(T2, T5) in K averaged over the next ``duration_s`` with the heater held (a DMM's window).

        The time scale is taken at the window's start; the mean of U is converted to T (the
        window is tens of ms, T2 moves by far less than its curvature matters over it).
        """
        elapsed = self.time_s - self.start_time_s
        scale = self.time_scale()
        flange, stage = self._mean_part(self.flange_heater.mean_output(duration_s, scale)
                                        + self.stage_to_flange.mean_output(duration_s, scale),
                                        self.stage_heater.mean_output(duration_s))
        return self._with_line(flange, stage, lambda scale: self.flange_ptc.mean_value(elapsed, duration_s, scale),
                               lambda: self.stage_ptc.mean_value(elapsed, duration_s))


def cryostat_plant(model: CryostatModel, start_time_s: float = 0.0, initial_heater_power_w: float = 0.0,
                   ptc_cycle=None) -> CryostatPlant:
    """The stepping plant for ``model``: temperature-dependent when the model says so."""
    kind = CryostatPlant if model.temperature_dependence is None else TemperatureDependentPlant
    return kind(model, start_time_s, initial_heater_power_w, ptc_cycle)


def simulate_stepping(model: CryostatModel, time_s: np.ndarray, heater_power_w: np.ndarray,
                      initial_heater_power_w: float, heater_change_s: np.ndarray | None = None,
                      ptc_cycle=None) -> SimulatedRecord:
    """A whole record, instant by instant (the temperature-dependent cryostat has no whole-array form)."""
    plant = cryostat_plant(model, float(time_s[0]) if time_s.size else 0.0, initial_heater_power_w, ptc_cycle)
    changes = time_s if heater_change_s is None else heater_change_s
    flange, stage = np.empty(time_s.size), np.empty(time_s.size)
    for index, (instant, power, change) in enumerate(zip(time_s, heater_power_w, changes)):
        plant.advance_to(float(instant))
        flange[index], stage[index] = plant.temperatures()
        plant.set_heater_power(float(power), float(change))
    return SimulatedRecord(time_s=time_s, flange_K=flange, ptc_stage_K=stage)


# ---------------------------------------------------------------------------
# steady states and the linear model at a temperature
# ---------------------------------------------------------------------------
def flange_temperature_at(model: CryostatModel, heater_power_w: float) -> tuple[float, float]:
    """(T2, T5) in K, steady, without the line, for a heater power held for ever (W)."""
    plant = TemperatureDependentPlant(model, 0.0, heater_power_w)
    return plant.mean_part()


def steady_state(model: CryostatModel, flange_temperature_K: float) -> tuple[float, float]:
    """The heater power (W) holding T2 at ``flange_temperature_K`` for ever, and T5 then (K).

    Raises
    ------
    ValueError
        Below the heater-off temperature, or beyond :data:`MAX_STEADY_POWER_W`.
    """
    if model.temperature_dependence is None:
        raise ValueError("the model has no temperature_dependence section")
    floor = model.operating_point.flange_temperature_K
    if flange_temperature_K < floor:
        raise ValueError(f"{flange_temperature_K:g} K is below the cryostat's heater-off temperature {floor:g} K")
    if flange_temperature_at(model, MAX_STEADY_POWER_W)[0] < flange_temperature_K:
        raise ValueError(f"{flange_temperature_K:g} K needs more than {MAX_STEADY_POWER_W:g} W")
    power = brentq(lambda p: flange_temperature_at(model, p)[0] - flange_temperature_K, 0.0, MAX_STEADY_POWER_W,
                   xtol=1e-12, rtol=1e-12)
    return float(power), flange_temperature_at(model, power)[1]


def linearised_at(model: CryostatModel, flange_temperature_K: float) -> CryostatModel:
    """The linear model of the temperature-dependent cryostat about T2 = ``flange_temperature_K``, steady.

    Small changes of the heater about the power holding that temperature, and the cooler's line there:
    ``flange_to_thermometer`` is 1, ``heater_to_flange`` the whole heater path
    ``U'(T2)^-1 [U'(T5) G3(s) G2(s s_F) + L(s s_F)]``, ``ptc_to_flange`` the line path ``s_F G2 G_link(s s_F)``,
    the stage's oscillation scaled by its law; the operating point is where the tangent meets 0 W.

    Parameters
    ----------
    model : CryostatModel
        With a ``temperature_dependence`` section.
    flange_temperature_K : float

    Returns
    -------
    CryostatModel
        A linear model (no ``temperature_dependence``), usable as a controller's model.
    """
    laws = model.temperature_dependence
    point = model.operating_point
    power_w, stage_K = steady_state(model, flange_temperature_K)
    scale = float(laws.flange_time_scale(flange_temperature_K, point.flange_temperature_K))
    factor = float(laws.stage_line_factor(stage_K, point.ptc_stage_temperature_K))
    stage_weight = float(laws.conductance_ratio(stage_K, point.flange_temperature_K))
    per_potential = float(laws.temperature_per_potential(flange_temperature_K, point.flange_temperature_K))
    heater = per_potential * (stage_weight * model.heater_to_ptc_stage * model.flange_to_thermometer.time_scaled(scale)
                              + link_transfer_function(model).time_scaled(scale))
    _, line = flange_transfer_functions(model)
    flange_off_K = flange_temperature_K - heater.dc_gain * power_w
    if not flange_off_K > 0.0:
        raise ValueError(f"the tangent at {flange_temperature_K:g} K meets 0 W at {flange_off_K:g} K")
    ptc = dataclasses.replace(
        model.ptc, ptc_stage_amplitude_K=model.ptc.ptc_stage_amplitude_K * factor,
        harmonics=tuple(dataclasses.replace(h, ptc_stage_amplitude_K=h.ptc_stage_amplitude_K * factor)
                        for h in model.ptc.harmonics))
    return dataclasses.replace(
        model, operating_point=OperatingPoint(flange_off_K, stage_K - model.heater_to_ptc_stage.dc_gain * power_w),
        heater_to_flange=heater, flange_to_thermometer=TransferFunction((1.0,), (1.0,)),
        ptc_to_flange=scale * line.time_scaled(scale), ptc=ptc, temperature_dependence=None, uncertainty=None,
        name=f"{model.name} at {flange_temperature_K:g} K".strip(),
        description=f"linearised at T2 = {flange_temperature_K:g} K, heater {power_w:.6g} W, T5 {stage_K:.6g} K")
