"""The feedforward's physical limit, for docs/feedforward.md: the best waveforms and the limit
against setpoint for three heaters.

Run: PYTHONPATH=. python3 docs/figures/feedforward_limit.py
Writes docs/figures/feedforward_limit.png.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from cryod.control.feedforward.limit import feedforward_limit, limit_sweep
from cryod.model import load_model

HERE = Path(__file__).resolve().parent
MODEL = load_model(HERE.parent.parent / "config" / "model.yaml")
MAX_CURRENT_A = 0.1


def main() -> None:
    figure, (waveforms, setpoints) = plt.subplots(1, 2, figsize=(12, 4.6))
    for setpoint, resistance, style in ((5.0, 50.0, "C0-"), (5.0, 17.0, "C1-"), (6.0, 50.0, "C2-")):
        limit = feedforward_limit(MODEL, setpoint, resistance, MAX_CURRENT_A, certify=False)
        phase = np.append(limit.waveform_phase_rad, 2 * np.pi)
        power = np.append(limit.waveform_power_w, limit.waveform_power_w[0])
        waveforms.plot(phase, power * 1e3, style,
                       label=f"{setpoint:g} K, {resistance:g} ohm: leaves {limit.ptc_periodic_limit_K * 1e3:.2f} mK")
        waveforms.axhline(limit.max_heater_power_W * 1e3, color=style[:2], lw=0.6, ls=":")
    scale = waveforms.get_ylim()[1] / 2
    grid = np.linspace(0, 2 * np.pi, 400)
    waveforms.plot(grid, scale + 0.3 * scale * np.sin(grid), color="0.6", lw=0.8, label="T5's oscillation (shape)")
    waveforms.set(xlabel="cooler phase (rad; T5 ~ sin)", ylabel="heater power (mW)",
                  title="Best heater waveform over one cooler period (dotted: R I_max^2)")
    waveforms.legend(fontsize=8, loc="upper right")

    values = np.round(np.arange(4.4, 7.65, 0.1), 2)
    for resistance, color in ((17.0, "C1"), (50.0, "C0"), (100.0, "C3")):
        rows = [row for row in limit_sweep(MODEL, "setpoint", values, setpoint_K=5.0, heater_resistance_ohm=resistance,
                                           max_current_A=MAX_CURRENT_A) if row.limit is not None]
        kelvin = [row.value for row in rows]
        setpoints.plot(kelvin, [row.limit.ptc_periodic_limit_K * 1e3 for row in rows], color=color, lw=2,
                       label=f"limit, {resistance:g} ohm")
        setpoints.plot(kelvin, [row.limit.best_sinusoid_K * 1e3 for row in rows], color=color, lw=1, ls="--",
                       label=f"best sinusoid, {resistance:g} ohm")
    open_line = feedforward_limit(MODEL, 5.0, 50.0, MAX_CURRENT_A, certify=False).open_line_K
    setpoints.axhline(open_line * 1e3, color="k", lw=0.8, ls=":", label="open line")
    setpoints.set(xlabel="setpoint (K)", ylabel="T2 PTC-synchronous amplitude, harmonics 1-6 (mK)",
                  title=f"Limit against setpoint, current limit {MAX_CURRENT_A:g} A")
    setpoints.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(HERE / "feedforward_limit.png", dpi=110)


if __name__ == "__main__":
    main()
