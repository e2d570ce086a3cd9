"""T2's response to the heater power the loop asked for but the heater could not play.

When the feedforward's waveform plus the feedback terms' power leaves the
heater's range (0 W .. R*I_max^2), the regulator holds the total at the bound:
the heater plays less (or more) than the waveform the feedforward's estimator
assumes. :class:`UnplayedPower` follows that difference through the
controller's heater-to-T2 model, exact for a power held between settings, so
that the estimator can take every reading, clipped or not, with T2 as it would
have been had the heater played what was asked.

Examples
--------
>>> from cryod.model import load_model
>>> unplayed = UnplayedPower(load_model())
>>> unplayed.at(0.0)                        # nothing clipped: no effect, no cost
0.0
>>> unplayed.set(0.0, -0.010)              # the total held 10 mW below what was asked
>>> unplayed.set(0.08, 0.0)                # played in full again
>>> round(unplayed.at(0.5) * 1e6, 2) < 0   # T2 a little cooler than the estimator's model says (µK)
True
"""

from __future__ import annotations

from cryod.model import CryostatModel
from cryod.model.dynamics import flange_transfer_functions
from cryod.model.heater_path import HeaterPath

#: Below this (K, on every mode of the path) the response has died away and is no longer followed.
QUIET_K = 1e-10


class UnplayedPower:
    """The heater power not played (applied minus requested, W) and its effect on T2's readings (K).

    Parameters
    ----------
    model : CryostatModel
        The controller's model: its heater-to-flange-thermometer path is used.
    """

    def __init__(self, model: CryostatModel):
        self.path = HeaterPath(flange_transfer_functions(model)[0])
        self.time_s = 0.0
        self.active = False

    def at(self, time_s: float) -> float:
        """The effect on T2 at ``time_s`` (K): what the reading holds beyond the requested power's effect."""
        if not self.active:
            return 0.0
        self._advance(time_s)
        value = self.path.output()
        if self.path.input == 0.0 and all(abs(residue * state) < QUIET_K
                                          for residue, state in zip(self.path.residues, self.path.state)):
            self.reset()
        return value

    def set(self, time_s: float, unplayed_w: float) -> None:
        """From ``time_s`` the heater plays ``unplayed_w`` (W) more than requested (negative: less)."""
        if not self.active:
            if unplayed_w == 0.0:
                return
            self.active = True
            self.time_s = time_s
        self._advance(time_s)
        self.path.input = float(unplayed_w)

    def reset(self) -> None:
        """Forget (after a gap in the loop: the readings that follow are left out anyway)."""
        self.path.settle(0.0)
        self.active = False

    def _advance(self, time_s: float) -> None:
        self.path.hold(time_s - self.time_s)
        self.time_s = max(self.time_s, time_s)
