"""How the cryostat changes with temperature: heat capacity, conductances, the cooler's line.

The model file's optional ``temperature_dependence`` section states three laws
(the physics and the assumptions behind them are in ``docs/explanation/cryostat-model.md``,
section "The cryostat from 4 K to 25 K"):

* the heat capacities on the flange side scale as copper's specific heat,
  ``c(T) = gamma T + beta T**3`` (per mole);
* the flange's thermal conductances (the link to the cooler, the joints within
  the flange) scale as ``K(T) = K(T0) (T / T0)**m``: metallic conduction,
  ``m = 1`` (Wiedemann-Franz with the residual resistivity);
* the cooler's oscillation at its second stage scales as ``(T5_0 / T5)**p``
  with the stage's mean temperature T5: a stated assumption, not a measurement.

With one conductance law for every link of the flange, heat flows are linear
in the conduction potential ``U(T) = integral from T0 to T of (T'/T0)**m dT'``
(Kirchhoff's transform), so the identified linear model holds in U at every
temperature, with its time constants multiplied by :meth:`TemperatureDependence.flange_time_scale`.

Examples
--------
>>> laws = TemperatureDependence()
>>> round(float(laws.specific_heat_J_per_mol_K(4.23)) * 1e3, 3)       # mJ/(mol K), copper at 4.23 K
6.573
>>> round(float(laws.flange_time_scale(24.0, 4.23)), 1)               # flange time constants, 24 K against 4.23 K
18.2
>>> round(float(laws.temperature_K(laws.conduction_potential_K(12.0, 4.23), 4.23)), 12)
12.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Copper's electronic heat capacity coefficient, J/(mol K^2): Kittel, Introduction to Solid State
#: Physics, 8th ed., ch. 6, table 2 (observed gamma of Cu, 0.695 mJ mol^-1 K^-2).
COPPER_GAMMA_J_PER_MOL_K2 = 0.695e-3
#: Copper's lattice coefficient, J/(mol K^4): 12 pi^4 R / (5 theta_D^3) with theta_D = 343 K (Kittel,
#: ch. 5, table 1), 4.82e-5, taken as 0.048 mJ mol^-1 K^-4 (copper then has 0.1034 J/(kg K) at 4.23 K).
COPPER_BETA_J_PER_MOL_K4 = 0.048e-3


@dataclass(frozen=True)
class TemperatureDependence:
    """The laws by which the cryostat's parameters change with temperature.

    Attributes
    ----------
    gamma_J_per_mol_K2, beta_J_per_mol_K4 : float
        Specific heat ``gamma T + beta T**3`` of the flange side's material (copper's by default).
    conductance_exponent : float
        m in ``K(T) = K(T0) (T / T0)**m`` for the flange's conductances (1: metallic conduction).
    stage_line_exponent : float
        p in ``B(T5) = B(T5_0) (T5_0 / T5)**p``: the cooler's oscillation at its stage against the
        stage's mean temperature (an assumption of the model, 0 for no change).
    """

    gamma_J_per_mol_K2: float = COPPER_GAMMA_J_PER_MOL_K2
    beta_J_per_mol_K4: float = COPPER_BETA_J_PER_MOL_K4
    conductance_exponent: float = 1.0
    stage_line_exponent: float = 1.0

    def __post_init__(self):
        for name in ("gamma_J_per_mol_K2", "beta_J_per_mol_K4"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        if not self.gamma_J_per_mol_K2 + self.beta_J_per_mol_K4 > 0.0:
            raise ValueError("gamma_J_per_mol_K2 and beta_J_per_mol_K4 cannot both be 0 (no heat capacity)")
        if not (math.isfinite(self.conductance_exponent) and 0.0 <= self.conductance_exponent <= 4.0):
            raise ValueError(f"conductance_exponent must be within 0..4, got {self.conductance_exponent!r}")
        if not (math.isfinite(self.stage_line_exponent) and -4.0 <= self.stage_line_exponent <= 4.0):
            raise ValueError(f"stage_line_exponent must be within -4..4, got {self.stage_line_exponent!r}")

    # -- the laws ----------------------------------------------------------------------
    def specific_heat_J_per_mol_K(self, temperature_K):
        """``gamma T + beta T**3`` (J/(mol K)); scalar or array."""
        temperature = np.asarray(temperature_K, dtype=float)
        return self.gamma_J_per_mol_K2 * temperature + self.beta_J_per_mol_K4 * temperature ** 3

    def conductance_ratio(self, temperature_K, reference_K: float):
        """``K(T) / K(T0) = (T / T0)**m``."""
        return (np.asarray(temperature_K, dtype=float) / reference_K) ** self.conductance_exponent

    def flange_time_scale(self, temperature_K, reference_K: float):
        """Factor on the flange's time constants at T against T0: ``[c(T)/c(T0)] / [K(T)/K(T0)]``."""
        capacity = self.specific_heat_J_per_mol_K(temperature_K) / self.specific_heat_J_per_mol_K(reference_K)
        return capacity / self.conductance_ratio(temperature_K, reference_K)

    def stage_line_factor(self, ptc_stage_temperature_K, reference_K: float):
        """Factor on the cooler's oscillation at the stage: ``(T5_0 / T5)**p``."""
        ratio = reference_K / np.maximum(np.asarray(ptc_stage_temperature_K, dtype=float), 1e-3)
        return ratio ** self.stage_line_exponent

    # -- Kirchhoff's transform ---------------------------------------------------------------
    def conduction_potential_K(self, temperature_K, reference_K: float):
        """``U(T) = integral from T0 to T of (T'/T0)**m dT'`` (K): heat flows are linear in U."""
        power = self.conductance_exponent + 1.0
        ratio = np.asarray(temperature_K, dtype=float) / reference_K
        return reference_K / power * (ratio ** power - 1.0)

    def temperature_K(self, conduction_potential_K, reference_K: float):
        """The temperature whose conduction potential is U (K), the inverse of :meth:`conduction_potential_K`."""
        power = self.conductance_exponent + 1.0
        inside = 1.0 + power * np.asarray(conduction_potential_K, dtype=float) / reference_K
        return reference_K * np.maximum(inside, 1e-12) ** (1.0 / power)

    def temperature_per_potential(self, temperature_K, reference_K: float):
        """dT/dU at T: ``(T0 / T)**m``."""
        return 1.0 / self.conductance_ratio(temperature_K, reference_K)
