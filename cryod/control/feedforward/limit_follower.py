"""The physical limit at the setpoint in use, from the model until the plant is learned, then from what was learned.

Why, and how well it works: docs/explanation/feedforward.md ("The limit from what was learned").

The feedforward reports the limit (``ff_limit_K``, ``ff_authority``,
``cryod ctl feedforward status``) and what would change it. It is computed off
the loop's thread (some 60 ms with what would change it) and taken a fixed
time after it was asked for (:data:`TAKEN_AFTER_S`: in service long done; on
virtual time the loop waits for it, so runs stay deterministic):

* **from the model** (:func:`cryod.control.feedforward.limit.limit_for_heater_power`)
  once the setpoint has been steady for :data:`MODEL_AFTER_S`, once per
  setpoint, heater and setting delay (none where the model says the heater
  cannot hold the setpoint);
* **from what was learned** (:mod:`cryod.control.feedforward.learned_limit`) once the plant
  at the fundamental is learned and T2 has settled at the setpoint (the mean
  power PI has found is then the one the setpoint needs), again every
  :data:`LEARNED_EVERY_S` while it is; also where the model said the setpoint
  was out of reach and this cryostat holds it.

:attr:`LimitFollower.limit` is the learned one while there is one, else the
model's; :attr:`LimitFollower.source` says which.
"""

from __future__ import annotations

import math
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable

from cryod.control.feedforward.limit import FeedforwardLimitError, limit_changes, limit_for_heater_power
from cryod.control.feedforward.learned_limit import LearnedLimitInputs, learned_limit, learned_limit_changes
from cryod.model import CryostatModel
from cryod.thread_priority import at_normal_priority

#: The model's limit is computed once the setpoint has been steady this long (s) ...
MODEL_AFTER_S = 5.0
#: ... and taken this long after it was asked for (s).
TAKEN_AFTER_S = 2.0
#: The learned limit is computed again this often while the plant is learned and T2 at the setpoint (s).
LEARNED_EVERY_S = 30.0
#: A setting delay that moved by more than this asks for the model's limit again (s).
DELAY_TOLERANCE_S = 0.002
#: While a learned limit is due but the plant or T2 is not ready for it, they are looked at this often (s).
RECHECK_S = 1.0


class LimitFollower:
    """The physical limit at the setpoint in use (module notes).

    Parameters
    ----------
    model : CryostatModel
        The controller's model.
    """

    def __init__(self, model: CryostatModel):
        self.model = model
        self.model_limit = None
        self.model_changes: tuple = ()
        self.learned_limit = None
        self.learned_changes: tuple = ()
        self._wanted: tuple[float, float] | None = None        # (setpoint, steady since)
        self._learned_at_s = -math.inf
        self._executor: ThreadPoolExecutor | None = None
        self._asked: tuple[Future, str, float, float] | None = None     # (result, kind, setpoint, take at)
        self._quiet: tuple[float, float, float, float] = (-math.inf, math.nan, math.nan, math.nan)
        self._out_of_reach: tuple[float, float] | None = None     # (setpoint, R I_max^2) the model cannot hold
        #: (limit (K), authority, source) for the record's columns, as they stand.
        self.columns: tuple = (math.nan, math.nan, None)

    @property
    def limit(self):
        """The learned limit while there is one, else the model's (None before either is computed)."""
        return self.learned_limit if self.learned_limit is not None else self.model_limit

    @property
    def changes(self) -> tuple:
        """What would change :attr:`limit` (LimitChange)."""
        return self.learned_changes if self.learned_limit is not None else self.model_changes

    @property
    def source(self) -> str | None:
        """``"learned"``, ``"model"``, or None before either is computed."""
        if self.learned_limit is not None:
            return "learned"
        return "model" if self.model_limit is not None else None

    def use_model(self, model: CryostatModel) -> None:
        """A new controller's model: its limit is computed again."""
        if model != self.model:
            self.model = model
            self.model_limit, self.model_changes = None, ()
            self._changed()

    def forget_learned(self) -> None:
        """The learned plant was reset: the model's limit until it is learned again."""
        self.learned_limit, self.learned_changes = None, ()
        self._learned_at_s = -math.inf
        if self._asked is not None and self._asked[1] == "learned":
            self._asked = None
        self._changed()

    def _changed(self) -> None:
        limit = self.limit
        self.columns = (math.nan, math.nan, None) if limit is None else \
            (limit.ptc_periodic_limit_K, limit.authority, self.source)
        self._quiet = (-math.inf, math.nan, math.nan, math.nan)

    def follow(self, time_s: float, setpoint_K: float, max_power_w: float, period_s: float, delay_s: float,
               learned: Callable[[float], LearnedLimitInputs | None]) -> None:
        """One tick: take a limit that is due, or ask for one that is wanted.

        ``learned(setpoint_K)`` gives the learned inputs when the plant is learned and T2 has settled at the
        setpoint, else None; it is called only when a learned limit is due.
        """
        until, quiet_setpoint, quiet_power, quiet_delay = self._quiet
        if time_s < until and setpoint_K == quiet_setpoint and max_power_w == quiet_power and delay_s == quiet_delay:
            return                                      # nothing due before then
        if self._asked is not None:
            result, kind, setpoint, take_at_s = self._asked
            if time_s < take_at_s:
                return
            self._asked = None
            limit, changes = result.result()
            if kind == "model":
                self.model_limit, self.model_changes = limit, changes
                if limit is None:      # out of reach by the model: not again for this setpoint and heater
                    self._out_of_reach = (setpoint, max_power_w)
            elif limit is not None:
                self.learned_limit, self.learned_changes = limit, changes
            self._changed()
            return
        setpoint = round(setpoint_K, 4)
        if self._wanted is None or self._wanted[0] != setpoint:
            self._wanted = (setpoint, time_s)
            self.forget_learned()
            return
        if time_s - self._wanted[1] < MODEL_AFTER_S:
            return
        known = self.model_limit
        if not (known is not None and known.setpoint_K == setpoint
                and abs(known.heater_delay_s - delay_s) < DELAY_TOLERANCE_S and known.max_heater_power_W == max_power_w) \
                and self._out_of_reach != (setpoint, max_power_w):
            self._ask("model", _model_report, time_s, setpoint, self.model, setpoint, max_power_w, period_s, delay_s)
            return
        # the learned limit also where the model says the setpoint is out of reach: the cryostat may differ
        if time_s - self._learned_at_s >= LEARNED_EVERY_S:
            inputs = learned(setpoint)
            if inputs is None:
                self._quiet = (time_s + RECHECK_S, setpoint_K, max_power_w, delay_s)
                return
            self._learned_at_s = time_s
            self._ask("learned", _learned_report, time_s, setpoint, inputs,
                      self.model.operating_point.flange_temperature_K, self.model.ptc.angular_frequency_rad_s,
                      self.model.sensor_noise.flange_thermometer_rms_K)
        else:
            self._quiet = (self._learned_at_s + LEARNED_EVERY_S, setpoint_K, max_power_w, delay_s)

    def _ask(self, kind: str, function, time_s: float, setpoint: float, *arguments) -> None:
        if self._executor is None:
            self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="cryod-feedforward-limit",
                                                initializer=at_normal_priority)
        self._asked = (self._executor.submit(function, *arguments), kind, setpoint, time_s + TAKEN_AFTER_S)

    def close(self) -> None:
        """End the limit's thread."""
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None
            self._asked = None


def _model_report(model: CryostatModel, setpoint_K: float, max_power_w: float, period_s: float,
                  delay_s: float) -> tuple:
    """(the model's limit, what would change it) at a setpoint, or (None, ()) when it is out of reach."""
    try:
        limit = limit_for_heater_power(model, setpoint_K, max_power_w, period_s, heater_delay_s=delay_s,
                                       certify=False)
    except FeedforwardLimitError:
        return None, ()
    return limit, limit_changes(model, setpoint_K, max_power_w, period_s, heater_delay_s=delay_s)


def _learned_report(inputs: LearnedLimitInputs, flange_base_K: float, cooler_rad_s: float, noise_K: float) -> tuple:
    """(the learned limit, what would change it), or (None, ()) when the mean power leaves no room."""
    noise = {"cooler_angular_frequency_rad_s": cooler_rad_s, "sensor_noise_rms_K": noise_K}
    try:
        limit = learned_limit(inputs, **noise)
    except FeedforwardLimitError:
        return None, ()
    return limit, learned_limit_changes(inputs, flange_base_K=flange_base_K, **noise)


__all__ = ["LEARNED_EVERY_S", "LimitFollower", "MODEL_AFTER_S", "TAKEN_AFTER_S"]
