"""The paper's PI findings (Figs. 6-8) reproduced on the simulated cryostat, for docs/control.md.

Run: PYTHONPATH=. python3 docs/figures/control_study.py
Writes docs/figures/control_study.png and prints the tables of docs/control.md.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from scipy import optimize

from cryod.control.pi import PiGains
from cryod.cooler.line_fit import fit_line
from cryod.model import load_model
from cryod.control.closed_loop import Segment, run_program

HERE = Path(__file__).resolve().parent
MODEL = load_model(HERE.parent.parent / "config" / "model.yaml")
MAX_CURRENT_A = 0.1
SETPOINT_K = 5.0
DURATION_S = 600.0


def run(resistance_ohm, gains, current_output=False, duration_s=DURATION_S):
    return run_program(MODEL, [Segment(0.0, setpoint_K=SETPOINT_K)], duration_s, gains=gains,
                       heater_max_w=resistance_ohm * MAX_CURRENT_A ** 2, seed=1,
                       current_output_resistance_ohm=resistance_ohm if current_output else None)


def figures_of_merit(result) -> dict:
    t, flange = result.time_s, result.flange_K
    smooth = np.convolve(flange, np.ones(29) / 29, mode="same")     # 2.32 s: 4.0 PTC periods
    reached = np.flatnonzero(flange >= SETPOINT_K - 0.001)
    outside = np.flatnonzero(np.abs(smooth[14:-14] - SETPOINT_K) > 0.001) + 14
    late = t > DURATION_S - 200.0
    return {
        "rise_s": float(t[reached[0]]) if reached.size else float("nan"),
        "overshoot_mK": float(max(smooth[14:-14].max() - SETPOINT_K, 0.0) * 1e3),
        "settle_s": float(t[outside[-1]]) if outside.size else 0.0,
        "line_mK": fit_line(t[late], flange[late], MODEL.ptc.angular_frequency_rad_s).amplitude[0] * 1e3,
        "heater_mean_mW": float(np.mean(result.heater_w[late]) * 1e3),
        "heater_at_limit_percent": float(np.mean((result.heater_w[late] <= 0.0)
                                                 | (result.heater_w[late] >= result.heater_w.max() - 1e-12)) * 100),
    }


def main() -> None:
    paper = PiGains(80.0, 4.0)
    resistance = optimize.brentq(lambda r: figures_of_merit(run(r, paper))["rise_s"] - 150.0, 12.0, 30.0, xtol=0.05)
    print(f"heater resistance giving the paper's 150 s rise with Kp = 80 W/K, Ki = 4 W/(K s): {resistance:.1f} ohm "
          f"(limit R I_max^2 = {resistance * MAX_CURRENT_A ** 2 * 1e3:.0f} mW)\n")
    open_loop = run_program(MODEL, [Segment(0.0, heater_power_w=0.0)], 300.0, gains=paper, heater_max_w=1.0, seed=1)
    open_line = fit_line(open_loop.time_s, open_loop.flange_K, MODEL.ptc.angular_frequency_rad_s).amplitude[0] * 1e3

    print("| reading of Kp = 80, I = 4 | rise 4.23 -> 5.00 K (s) | overshoot (mK) | within 1 mK after (s) "
          "| PTC line on T2 (mK) |")
    print("|---|---|---|---|---|")
    readings = [("Kp = 80 W/K, Ki = 4 W/(K s) (taken)", run(resistance, paper)),
                ("Kp = 80 mA/K, Ki = 4 mA/(K s), output current", run(resistance, PiGains(0.08, 0.004), True)),
                ("Kp = 80 mA/K, Ti = 4 s, output current", run(resistance, PiGains(0.08, 0.02), True))]
    for name, result in readings:
        m = figures_of_merit(result)
        print(f"| {name} | {m['rise_s']:.0f} | {m['overshoot_mK']:.1f} | {m['settle_s']:.0f} | {m['line_mK']:.3f} |")
    print(f"| open loop, heater off (4.23 K) | - | - | - | {open_line:.3f} |\n")

    print("| Kp (W/K) | Ki (W/(K s)) | rise (s) | overshoot (mK) | within 1 mK after (s) | PTC line (mK) "
          "| heater at 0 or limit (% of time) |")
    print("|---|---|---|---|---|---|---|")
    grid, amplitudes = {}, []
    for kp in (20.0, 40.0, 80.0, 160.0):
        for ki in (2.0, 4.0, 8.0):
            result = run(resistance, PiGains(kp, ki))
            m = figures_of_merit(result)
            grid[(kp, ki)] = (result, m)
            amplitudes.append(m["line_mK"])
            print(f"| {kp:g} | {ki:g} | {m['rise_s']:.0f} | {m['overshoot_mK']:.1f} | {m['settle_s']:.0f} "
                  f"| {m['line_mK']:.3f} | {m['heater_at_limit_percent']:.0f} |")
    spread = (max(amplitudes) - min(amplitudes)) / min(amplitudes) * 100
    print(f"\nline amplitude across the grid: {min(amplitudes):.3f} to {max(amplitudes):.3f} mK "
          f"({spread:.1f} % spread); open loop {open_line:.3f} mK\n")

    default = run(resistance, PiGains(10.0, 0.2))
    m = figures_of_merit(default)
    print(f"cryod example gains Kp = 10 W/K, Ki = 0.2 W/(K s): rise {m['rise_s']:.0f} s, overshoot "
          f"{m['overshoot_mK']:.1f} mK, within 1 mK after {m['settle_s']:.0f} s, line {m['line_mK']:.3f} mK, "
          f"heater at 0 or limit {m['heater_at_limit_percent']:.0f} % of the time")

    print("\nexample config heater (50 ohm, 0.5 W limit): gains scan, fastest settling within 1 mK")
    scan = []
    for kp in (0.5, 1.0, 2.0, 5.0, 10.0, 20.0):
        for ki in (0.005, 0.01, 0.02, 0.05, 0.1, 0.2):
            m = figures_of_merit(run(50.0, PiGains(kp, ki)))
            scan.append((m["settle_s"], kp, ki, m))
    print("| Kp (W/K) | Ki (W/(K s)) | rise (s) | overshoot (mK) | within 1 mK after (s) | PTC line (mK) |")
    print("|---|---|---|---|---|---|")
    for settle, kp, ki, m in sorted(scan, key=lambda item: item[0])[:5]:
        print(f"| {kp:g} | {ki:g} | {m['rise_s']:.0f} | {m['overshoot_mK']:.1f} | {settle:.0f} | {m['line_mK']:.3f} |")

    figure, (a_rise, a_line, a_heater) = plt.subplots(1, 3, figsize=(15, 4.6))
    for kp, color in zip((20.0, 40.0, 80.0, 160.0), ("tab:orange", "tab:green", "tab:blue", "tab:purple")):
        result, _ = grid[(kp, 4.0)]
        a_rise.plot(result.time_s, result.flange_K, color=color, lw=1, label=f"Kp = {kp:g} W/K, Ki = 4 W/(K s)")
    a_rise.plot(readings[1][1].time_s, readings[1][1].flange_K, color="gray", lw=1, ls="--",
                label="Kp = 80 mA/K, Ki = 4 mA/(K s) (current output)")
    a_rise.plot(default.time_s, default.flange_K, color="black", lw=1, label="cryod example: 10 W/K, 0.2 W/(K s)")
    a_rise.axhline(SETPOINT_K, color="red", lw=0.6)
    a_rise.set(title=f"4.23 K to 5.00 K, heater limit 100 mA x {resistance:.1f} ohm", xlabel="time (s)",
               ylabel="T2 (K)", ylim=(4.2, 5.12))
    for ki, marker in zip((2.0, 4.0, 8.0), ("o", "s", "^")):
        kps = (20.0, 40.0, 80.0, 160.0)
        a_line.plot(kps, [grid[(kp, ki)][1]["line_mK"] for kp in kps], marker=marker, label=f"Ki = {ki:g} W/(K s)")
    a_line.axhline(open_line, color="gray", ls=":", label="open loop")
    a_line.set(xscale="log", title="PTC line on T2 at 5 K (last 200 s)", xlabel="Kp (W/K)", ylabel="amplitude (mK)",
               ylim=(0.0, 2.2))
    window = (default.time_s > 500.0) & (default.time_s < 503.0)
    a_heater.plot(default.time_s[window] - 500, grid[(80.0, 4.0)][0].heater_w[window] * 1e3, color="tab:blue",
                  label="Kp = 80 W/K")
    a_heater.plot(default.time_s[window] - 500, default.heater_w[window] * 1e3, color="black",
                  label="Kp = 10 W/K (cryod example)")
    a_heater.set(title="heater power at 5 K", xlabel="time (s)", ylabel="heater (mW)")
    for axis in (a_rise, a_line, a_heater):
        axis.grid(alpha=0.3)
        axis.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(HERE / "control_study.png", dpi=110)


if __name__ == "__main__":
    main()
