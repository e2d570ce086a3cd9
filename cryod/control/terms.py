"""Control terms: the additive parts of the heater power, and the one place that builds them.

A control term is a subclass of :class:`ControlTerm` with

* ``name``: its name, also its configuration section under ``control:``;
* ``required``: whether that section must be given;
* ``columns``: the record columns it writes (:class:`cryod.records.columns.Column`);
* ``settings_from(section)``: its validated settings from its section (a
  static method; called with None when an optional section is absent);
* ``__init__(settings, output_max)`` and ``reconfigure(settings, output_max)``
  (a reload: bumpless);
* ``start``, ``update``, ``limit``, ``column_values``: the cycle, below.

:class:`ControlTerm` declares every hook the regulator calls; those a term
may leave out have defaults there: ``condition(tick)`` (what the following
terms see), ``rides_on_feedback`` (the term is added after the feedback
terms' sum has been held within the heater's range: the feedforward),
``take_events()`` (what the term has to say since the last tick, as
(logging level, text) pairs, which the loop logs and writes into the record
as events named after the term), ``enter_zone(index)`` (the setpoint in use
moved into another zone of ``control.zones``: what the term learned of the
cryostat at the previous operating point), ``follow_timing(on_time)`` (the
loop's cycles keep their deadlines, or have been late many in a row) and
``close()`` (release what it holds).

A new term is one module with such a class and one line in :data:`TERM_TYPES`.
The regulator (:mod:`cryod.control.regulator`) adds the terms' outputs, holds
the sum within the heater's limits and tells every term what was applied.
"""

from __future__ import annotations

import functools
import importlib
from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple

if TYPE_CHECKING:
    from cryod.records.columns import Column
    from cryod.yaml_source import Section


class TickInputs(NamedTuple):
    """What a control term sees each tick.

    Attributes
    ----------
    time_s : float
        Clock time of the readings' trigger (s).
    dt_s : float
        Time since the previous tick's readings (s).
    flange_K, ptc_stage_K : float
        T2 and T5 (K).
    setpoint_K : float
        Setpoint now, after the ramp (K).
    flange_time_s, ptc_stage_time_s : float
        The instants T2 and T5 stand for (s; the middle of their integration).
    output_time_s : float
        When this tick's output takes effect (s; the heater is set after the readings).
    flange_feedback_K : float
        T2 for feedback terms: T2 less what a term before them explained away
        (the feedforward takes out T2's part synchronous with the cooler).
    """

    time_s: float
    dt_s: float
    flange_K: float
    ptc_stage_K: float
    setpoint_K: float
    flange_time_s: float
    ptc_stage_time_s: float
    output_time_s: float
    flange_feedback_K: float

    def with_feedback(self, flange_feedback_K: float) -> "TickInputs":
        """The same inputs with another T2 for the feedback terms."""
        return TickInputs(*self[:8], flange_feedback_K)

    def with_setpoint(self, setpoint_K: float) -> "TickInputs":
        """The same inputs with another setpoint."""
        return TickInputs(*self[:4], setpoint_K, *self[5:])

    @classmethod
    def at(cls, time_s: float, dt_s: float, flange_K: float, ptc_stage_K: float, setpoint_K: float,
           flange_time_s: float | None = None, ptc_stage_time_s: float | None = None,
           output_time_s: float | None = None) -> "TickInputs":
        """Inputs with the instants defaulting to the trigger and the feedback T2 to T2."""
        return cls(time_s, dt_s, flange_K, ptc_stage_K, setpoint_K,
                   time_s if flange_time_s is None else flange_time_s,
                   time_s if ptc_stage_time_s is None else ptc_stage_time_s,
                   time_s if output_time_s is None else output_time_s, flange_K)


class ControlTerm(ABC):
    """One additive part of the regulator's output (W, or A for a current-output study).

    Every hook the regulator calls is declared here; a term overrides the
    abstract ones and those of the others it needs.
    """

    #: Its name, also its configuration section under ``control:``.
    name: ClassVar[str]
    #: Whether its section must be given.
    required: ClassVar[bool]
    #: The record columns it writes, in the order of :meth:`column_values`.
    columns: ClassVar[tuple["Column", ...]]
    #: Added after the feedback terms' sum has been held within the heater's range and
    #: told so (a waveform clipped at 0 W then does not stop PI integrating).
    rides_on_feedback: ClassVar[bool] = False

    @staticmethod
    @abstractmethod
    def settings_from(section: "Section | None") -> Any:
        """Its validated settings from its section (None: an optional section that is absent)."""

    @abstractmethod
    def reconfigure(self, settings: Any, output_max: float) -> None:
        """New settings from a reload, without a bump in the output."""

    def condition(self, tick: TickInputs) -> TickInputs:
        """What the following terms see this tick (by default, what this one sees).

        Called for every term, in every mode, before any :meth:`update`: the
        feedforward takes the cooler's line out of ``flange_feedback_K``.
        """
        return tick

    @abstractmethod
    def start(self, tick: TickInputs, present_output: float) -> None:
        """The loop closes: continue from ``present_output`` without a bump."""

    @abstractmethod
    def update(self, tick: TickInputs) -> float:
        """This term's output for the coming period."""

    @abstractmethod
    def limit(self, requested: float, applied: float) -> None:
        """The total requested and what was applied after the heater limits (anti-windup)."""

    @abstractmethod
    def column_values(self) -> tuple[float, ...]:
        """This tick's values of :attr:`columns`, in order."""

    def take_events(self) -> tuple[tuple[int, str], ...]:
        """What the term has to say since the last tick: (logging level, text) pairs (by default, nothing)."""
        return ()

    def enter_zone(self, index: int) -> None:
        """The setpoint in use moved into zone ``index`` of ``control.zones`` (counted from 0), another operating
        point of the cryostat; called after :meth:`reconfigure` has given the term the zone's settings, never for
        a reload (the setpoint, and so the cryostat, stayed where it was). By default, nothing: the zone's
        settings are all the term needs."""

    def follow_timing(self, on_time: bool) -> None:
        """Whether the loop's cycles keep their deadlines (True) or have been late many in a row (False): a
        term that relies on the ticks' timing (the feedforward's phase and its learning) holds back while
        they do not. By default, nothing: PI takes each tick's own ``dt_s``."""

    def close(self) -> None:
        """Release what the term holds (a worker thread); by default, nothing."""


#: Every control term: name -> its class, in the order their outputs are added and their columns
#: written. One line per term.
TERM_TYPES: dict[str, str] = {
    "pi": "cryod.control.pi.PiTerm",
    "feedforward": "cryod.control.feedforward.FeedforwardTerm",
}


@functools.cache
def term_type(name: str):
    """The class of the term called ``name`` in :data:`TERM_TYPES`."""
    module, _, attribute = TERM_TYPES[name].rpartition(".")
    return getattr(importlib.import_module(module), attribute)


def term_settings_from(control: "Section") -> tuple[tuple[str, Any], ...]:
    """Each term's validated settings from its section under ``control:``.

    Returns
    -------
    tuple of (name, settings)
        In :data:`TERM_TYPES` order; optional terms without a section get
        their defaults.
    """
    settings = []
    for name in TERM_TYPES:
        term = term_type(name)
        section = control.section(name) if term.required else control.section(name, None)
        settings.append((name, term.settings_from(section)))
    return tuple(settings)


def term_columns(settings: tuple[tuple[str, Any], ...]) -> tuple["Column", ...]:
    """The record columns of the control terms for these settings, in order."""
    return tuple(column for name, _ in settings for column in term_type(name).columns)


def build_terms(settings: tuple[tuple[str, Any], ...], output_max: float) -> list[ControlTerm]:
    """The control terms for these settings (from :func:`term_settings_from`)."""
    return [term_type(name)(term_settings, output_max) for name, term_settings in settings]
