"""The PTC paths: the cooler's steady oscillation and a thermometer's response to it, as phasors.

The cooler has been running for ever, so its contribution to a thermometer is
the steady-state response, evaluated at the exact instant asked for, so it
never aliases. Each harmonic k of the T5 oscillation,
``B_k sin(k theta(t) + alpha_k)``, drives the heat ``q = C dT5_osc/dt`` into
the flange (paper eq. 4); a path H (heat to flange thermometer, or the T5
thermometer's own lag) answers with
``Re(H(j k omega) Q_k exp(j (k theta(t) + alpha_k))``, with theta and omega
the cooler's cycle (:class:`~cryod.model.cooler_cycle.CoolerCycle`) and
``H(j k omega)`` from :meth:`~cryod.model.transfer_function.TransferFunction.frequency_response`.

Examples
--------
>>> from cryod.model import load_model
>>> from cryod.model.dynamics import flange_transfer_functions
>>> model = load_model()
>>> drive = CoolerDrive(model)
>>> flange = CoolerPath(drive, flange_transfer_functions(model)[1], input_is_heat=True)
>>> round(abs(flange.output_phasors(model.ptc.angular_frequency_rad_s)[0]), 5)   # T2's line, K
0.00173
"""

from __future__ import annotations

import cmath
from dataclasses import dataclass

import numpy as np

from cryod.model.cooler_cycle import CoolerCycle, MeasuredCoolerCycle
from cryod.model.kept_results import KeptResults, digest
from cryod.model.parameters import CryostatModel
from cryod.model.transfer_function import TransferFunction

#: The last phase terms made (the cycle's frequency, each component's ``exp(j (order theta + phase))``), by the
#: cycle, the instants and the components' orders and phases: every simulation of a record has a drive of its own,
#: and most share the cycle (the phase measured once, or the model's own frequency).
_PHASE_TERMS = KeptResults(8)


#: The last paths' outputs over a record, by the path, the components, the cycle, the instants and the time scale:
#: a cause on the heater's paths (a dead time, a heater's nonlinearity) leaves both thermometers' cooler paths as
#: they were.
_PATH_VALUES = KeptResults(8)


@dataclass(frozen=True)
class _CoolerComponent:
    order: int
    heat_phasor: complex      # q_k = Re(heat_phasor * exp(j theta)) for omega = omega_0, in W per (rad/s)
    stage_phasor: complex     # T5 oscillation = Re(stage_phasor * exp(j theta)), K
    phase_rad: float


class CoolerDrive:
    """The cooler's oscillation: its cycle, and the heat it drives into the flange.

    ``cycle`` replaces the model's own (a :class:`~cryod.model.cooler_cycle.MeasuredCoolerCycle`
    when a record is replayed with the phase measured in it).
    """

    def __init__(self, model: CryostatModel, cycle=None):
        ptc = model.ptc
        self.cycle = cycle if cycle is not None else CoolerCycle(ptc.angular_frequency_rad_s,
                                                              model.effects.ptc_frequency_drift)
        self.components = [
            _CoolerComponent(
                order=order,
                # q = C d/dt [B sin(theta)] = Re(C k omega B exp(j theta)); omega applied later
                heat_phasor=complex(ptc.heat_capacity_J_per_K * order * amplitude),
                # B sin(theta) = Re(-j B exp(j theta))
                stage_phasor=complex(-1j * amplitude),
                phase_rad=phase,
            )
            for order, amplitude, phase in ptc.components()
        ]
        self._terms_at: np.ndarray | None = None
        self._terms: tuple = ()

    def phase_terms(self, elapsed_s: np.ndarray) -> tuple:
        """(angular frequency, ``exp(j (order theta + phase))`` of each component) at the instants ``elapsed_s``.

        The last instants' are kept: both thermometers' paths ask for the same ones.
        """
        if self._terms_at is None or self._terms_at.shape != elapsed_s.shape \
                or not np.array_equal(self._terms_at, elapsed_s):
            components = [(component.order, component.phase_rad) for component in self.components]

            def made():
                phase, frequency = self.cycle.phase_and_frequency(elapsed_s)
                return frequency, tuple(np.exp(1j * (order * phase + phase_rad)) for order, phase_rad in components)

            key = _cycle_key(self.cycle)
            if key is None:
                frequency, terms = made()
            else:
                frequency, terms = _PHASE_TERMS.get_or_make(digest("phase terms", *key, elapsed_s, components), made)
            self._terms_at, self._terms = np.array(elapsed_s, dtype=float), (frequency, list(terms))
        return self._terms


def _cycle_key(cycle) -> tuple | None:
    """What a cycle's phase and frequency depend on (for :data:`_PHASE_TERMS`), or None for a cycle of another
    kind (its terms are then made every time)."""
    if type(cycle) is CoolerCycle:
        return ("model", repr(cycle))             # floats by repr: exact
    if type(cycle) is MeasuredCoolerCycle:
        return ("measured", cycle.elapsed_s, cycle.phase_values_rad, cycle.frequency_values_rad_s)
    return None


class CoolerPath:
    """Response of one thermometer to the PTC oscillation, evaluated as phasors.

    Parameters
    ----------
    drive : CoolerDrive
    transfer_function : TransferFunction
        From the PTC heat q (W) to the thermometer (K), or from the T5
        oscillation (K) to the T5 thermometer (K).
    input_is_heat : bool
        True for the heat path to the flange, False for the stage oscillation.
    """

    def __init__(self, drive: CoolerDrive, transfer_function: TransferFunction, input_is_heat: bool):
        self.drive = drive
        self.transfer_function = transfer_function
        self.input_is_heat = input_is_heat
        self._components_and_rotations = [(c, cmath.exp(1j * c.phase_rad)) for c in drive.components]
        self._cache_key: tuple[float, float] | None = None
        self._cache: list[tuple[int, complex]] = []
        self._window_key: tuple[float, float, float] | None = None
        self._window: list[tuple] = []

    def output_phasors(self, frequency, time_scale=1.0) -> list:
        """Complex output amplitude of each component (K), for the angular frequency given.

        ``frequency`` may be an array (one phasor per instant) or a float.
        """
        return [self._output_phasor(component, frequency, time_scale) for component in self.drive.components]

    def _output_phasor(self, component: _CoolerComponent, frequency, time_scale):
        gain = self.transfer_function.frequency_response(component.order * frequency * time_scale)
        return gain * (component.heat_phasor * frequency if self.input_is_heat else component.stage_phasor)

    def _rotated_phasors(self, frequency: float, time_scale: float) -> list[tuple[int, complex]]:
        """(order, phasor * exp(j component phase)) at one frequency, cached."""
        key = (frequency, time_scale)
        if key != self._cache_key:
            phasors = []      # a loop: a comprehension would make the arguments cells, slowing every cache hit
            for component, rotation in self._components_and_rotations:
                phasors.append((component.order, self._output_phasor(component, frequency, time_scale) * rotation))
            self._cache_key, self._cache = key, phasors
        return self._cache

    def value_at(self, rotor: complex, frequency: float, time_scale: float = 1.0) -> float:
        """Output at one instant given the cycle's rotor and frequency there (K)."""
        total = 0.0
        for order, phasor in self._rotated_phasors(frequency, time_scale):
            total += (phasor * (rotor if order == 1 else rotor ** order)).real
        return total

    def value(self, elapsed_s: float, time_scale: float = 1.0) -> float:
        """Output at one instant, ``elapsed_s`` after the plant started (K)."""
        rotor, frequency = self.drive.cycle.rotor(elapsed_s)
        return self.value_at(rotor, frequency, time_scale)

    def values(self, elapsed_s: np.ndarray, time_scale=1.0) -> np.ndarray:
        """Output at many instants (K).

        ``time_scale`` multiplies the path's time constants: a float, or one
        factor per instant (heat-capacity effect).
        """
        elapsed_s = np.asarray(elapsed_s, dtype=float)

        def made():
            frequency, terms = self.drive.phase_terms(elapsed_s)
            total = np.zeros(elapsed_s.shape)
            for term, phasor in zip(terms, self.output_phasors(frequency, time_scale)):
                total += np.real(phasor * term)
            return total

        cycle = _cycle_key(self.drive.cycle)
        if cycle is None or not isinstance(time_scale, float):
            return made()
        components = [(c.order, c.heat_phasor, c.stage_phasor, c.phase_rad) for c in self.drive.components]
        return _PATH_VALUES.get_or_make(digest(
            "cooler path", self.transfer_function.numerator, self.transfer_function.denominator, self.input_is_heat,
            components, *cycle, elapsed_s, time_scale), made)

    def mean_value(self, elapsed_s: float, duration_s: float, time_scale: float = 1.0) -> float:
        """Mean output over ``[elapsed_s, elapsed_s + duration_s]``, frequency frozen at the start."""
        if duration_s <= 0.0:
            return self.value(elapsed_s, time_scale)
        rotor, frequency = self.drive.cycle.rotor(elapsed_s)
        total = 0.0
        for order, phasor, turn, divisor in self._window_factors(frequency, time_scale, duration_s):
            start = phasor * rotor ** order
            total += (start * turn / divisor).real
        return total / duration_s

    def _window_factors(self, frequency: float, time_scale: float, duration_s: float) -> list[tuple]:
        """(order, rotated phasor, exp(j w duration) - 1, j w) of each component, for :meth:`mean_value`;
        kept while the frequency, the time scale and the window stay (a DMM's window is the same every reading)."""
        key = (frequency, time_scale, duration_s)
        if key != self._window_key:
            factors = []
            for order, phasor in self._rotated_phasors(frequency, time_scale):
                angular = order * frequency
                factors.append((order, phasor, cmath.exp(1j * angular * duration_s) - 1.0, 1j * angular))
            self._window_key, self._window = key, factors
        return self._window
