"""Figure for docs/model.md: the paper's measurements (Table 1) against the printed and shipped models.

Run: python3 docs/figures/model_vs_table1.py   (writes docs/figures/model_vs_table1.png and prints the numbers)
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from cryod.analysis import paper_table1 as table1
from cryod.cooler.line_fit import fit_line, wrap_phase
from cryod.model import load_model, simulate

HERE = Path(__file__).resolve().parent
CONFIG = HERE.parent.parent / "config"


def step(model, times):
    on = simulate(model, times, np.full(times.size, table1.STEP_POWER_W), initial_heater_power_w=0.0)
    off = simulate(model, times, np.zeros(times.size))
    return on.flange_K - off.flange_K + 4.23, on.ptc_stage_K - off.ptc_stage_K + 3.34


def line(model, times):
    record = simulate(model, times, np.zeros(times.size))
    flange = fit_line(times, record.flange_K, 10.83)
    stage = fit_line(times, record.ptc_stage_K, 10.83)
    return record, flange.amplitude[0], wrap_phase(stage.phase_rad[0] - flange.phase_rad[0])


def main() -> None:
    models = {"printed (eqs. 3, 9-11)": load_model(CONFIG / "model-paper-printed.yaml"),
              "shipped (config/model.yaml)": load_model(CONFIG / "model.yaml")}
    styles = {"printed (eqs. 3, 9-11)": dict(color="tab:red", ls="--"),
              "shipped (config/model.yaml)": dict(color="tab:blue", ls="-")}
    t_step = np.arange(0.0, 1200.0, 0.08)
    t_line = np.arange(0.0, 600.0, 0.01)
    measured_flange = table1.flange_step_response_K(t_step)
    measured_stage = table1.ptc_stage_step_response_K(t_step)

    figure, axes = plt.subplots(2, 2, figsize=(11, 7.5))
    (a_step, a_stage), (a_err, a_line) = axes
    a_step.plot(t_step, measured_flange, color="black", lw=3, alpha=0.35, label="measured (Table 1)")
    a_stage.plot(t_step, measured_stage, color="black", lw=3, alpha=0.35, label="measured (Table 1, sign as eq. 3)")
    window = (t_line >= 500.0) & (t_line <= 502.0)
    a_line.plot(t_line[window] - 500.0, (table1.open_loop_flange_K(t_line[window]) - 4.26) * 1e3,
                color="black", lw=3, alpha=0.35, label="measured T2 (Table 1)")
    print("| model | T2 step: worst deviation / step height | T5 step height (K) | "
          "T2 line amplitude (mK) | T2 lag behind T5 (rad) |")
    print("|---|---|---|---|---|")
    print(f"| measured (Table 1) | - | 0.024 | {table1.FLANGE_LINE_AMPLITUDE_K * 1e3:.2f} | "
          f"{table1.FLANGE_LAG_BEHIND_PTC_STAGE_RAD:.3f} |")
    for name, model in models.items():
        flange, stage = step(model, t_step)
        record, amplitude, lag = line(model, t_line)
        deviation = np.max(np.abs(flange - measured_flange)) / 0.06
        print(f"| {name} | {deviation * 100:.2f} % | {stage[-1] - 3.34 + 0.0:.4f} (at 1200 s; final "
              f"{model.heater_to_ptc_stage.dc_gain * table1.STEP_POWER_W:.4f}) | {amplitude * 1e3:.3f} | {lag:.3f} |")
        a_step.plot(t_step, flange, lw=1.5, label=name, **styles[name])
        a_stage.plot(t_step, stage, lw=1.5, label=name, **styles[name])
        a_err.plot(t_step, (flange - measured_flange) * 1e3, lw=1.5, label=name, **styles[name])
        a_line.plot(t_line[window] - 500.0, (record.flange_K[window] - 4.23) * 1e3, lw=1.5,
                    label=f"{name}: {amplitude * 1e3:.2f} mK, lag {lag:.3f} rad", **styles[name])
    a_line.plot(t_line[window] - 500.0, (table1.open_loop_ptc_stage_K(t_line[window]) - 3.33) * 1e3 / 50.0,
                color="gray", lw=1, ls=":", label="measured T5 / 50 (phase reference)")
    a_step.set(title="T2 after an 8.8 mW heater step", xlabel="time (s)", ylabel="T2 (K)")
    a_stage.set(title="T5 after the same step", xlabel="time (s)", ylabel="T5 (K)")
    a_err.axhspan(-0.6, 0.6, color="green", alpha=0.08, label="1 % of the step height")
    a_err.set_ylim(-0.7, 0.7)
    a_err.set(title="T2 step: model minus measured", xlabel="time (s)", ylabel="difference (mK)")
    a_line.set(title="Open loop, heater off: the PTC line on T2", xlabel="time (s)", ylabel="T2 - mean (mK)")
    for axis in axes.flat:
        axis.grid(alpha=0.3)
        axis.legend(fontsize=7, loc="lower right", framealpha=0.85)
    figure.tight_layout()
    figure.savefig(HERE / "model_vs_table1.png", dpi=110)


if __name__ == "__main__":
    main()
