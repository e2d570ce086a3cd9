"""The commissioning report (markdown): the model, its uncertainties, the feedforward's limit and the PI gains.

Written by ``cryod identify --report DIR`` (and by ``--acquire``) beside the
figures of :mod:`cryod.identification.figures`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from cryod.identification.model_fit import ModelIdentification

if TYPE_CHECKING:
    from cryod.control.feedforward.limit import FeedforwardLimit
    from cryod.control.feedforward.limit_range import LimitRange

#: Parameter names as the report writes them: (label, unit, scale to the unit).
LABELS = {
    "operating_point.flange_temperature_K": ("T2_0, flange at zero heater", "K", 1.0),
    "operating_point.ptc_stage_temperature_K": ("T5_0, PTC stage at zero heater", "K", 1.0),
    "ptc_line.T2_over_T5_real": ("line gain T2/T5, real part", "", 1.0),
    "ptc_line.T2_over_T5_imaginary": ("line gain T2/T5, imaginary part", "", 1.0),
    "ptc.angular_frequency_rad_s": ("cooler angular frequency", "rad/s", 1.0),
    "ptc.ptc_stage_amplitude_K": ("cooler line at T5, amplitude", "mK", 1e3),
    "ptc.phase_rad": ("cooler line at T5, phase at the record's start", "rad", 1.0),
}
#: The report's file name.
REPORT_NAME = "report.md"


def _label(name: str) -> tuple[str, str, float]:
    if name in LABELS:
        return LABELS[name]
    path, quantity, index = name.rsplit(".", 2)
    where = "G2 G1 (heater to T2)" if path == "heater_to_thermometer" else "G3 (heater to T5)"
    if quantity == "time_constant_s":
        return f"{where}, term {index}: time constant", "s", 1.0
    return f"{where}, term {index}: gain", "mK/W", 1e3


def _number(value: float, sigma: float) -> tuple[str, str]:
    """Value and uncertainty with the uncertainty to two significant figures."""
    if not (math.isfinite(sigma) and sigma > 0.0):
        return f"{value:.6g}", "-"
    decimals = max(0, 1 - int(math.floor(math.log10(sigma))))
    return f"{value:.{decimals}f}", f"{sigma:.{decimals}f}"


@dataclass
class FeedforwardSection:
    """What the report says about the feedforward: the limit and its range."""

    setpoint_K: float
    heater_resistance_ohm: float
    max_current_A: float
    limit: FeedforwardLimit | None = None
    spread: LimitRange | None = None
    problem: str = ""


def feedforward_section(model, setpoint_K: float, heater_resistance_ohm: float, max_current_A: float,
                        period_s: float) -> FeedforwardSection:
    """The limit at the setpoint for the identified model, with its range over the model's uncertainty."""
    from cryod.control.feedforward.limit import FeedforwardLimitError, feedforward_limit
    from cryod.control.feedforward.limit_range import limit_range

    section = FeedforwardSection(setpoint_K, heater_resistance_ohm, max_current_A)
    try:
        section.limit = feedforward_limit(model, setpoint_K, heater_resistance_ohm, max_current_A, period_s)
    except FeedforwardLimitError as error:
        section.problem = str(error)
        return section
    section.spread = limit_range(model, setpoint_K, heater_resistance_ohm, max_current_A, period_s)
    return section


def write_report(result: ModelIdentification, out: Path, *, model_path: Path, record_paths: list,
                 figures: dict | None = None, acquisition=None, feedforward: FeedforwardSection | None = None,
                 tuning_text: str | None = None, warnings: list[str] | None = None) -> Path:
    """Write ``report.md`` into ``out``; returns its path."""
    out = Path(out)
    lines = ["# Commissioning report", ""]
    lines += [f"- model written: `{model_path}`", "- records: " + ", ".join(f"`{p}`" for p in record_paths)]
    if acquisition is not None:
        runner = acquisition.runner
        lines.append(f"- experiment: {acquisition.outcome}; phases "
                     + ", ".join(f"{name} {end - start:.0f} s" for name, start, end in runner.phase_log))
        lines.append(f"- settling criterion: {runner.plan.criterion()}")
        if runner.unsettled:
            lines.append(f"- **not settled within --max-settle: {', '.join(runner.unsettled)}**")
    for warning in warnings or []:
        lines.append(f"- **warning**: {warning}")
    lines += ["", "## The model", ""]
    model = result.model
    flange, stage = result.flange, result.stage
    lines.append(f"Heater to T2 (G2 G1): **{flange.fit.count} first-order term(s)** ({flange.selection.reason}). "
                 f"Heater to T5 (G3): **{stage.fit.count} term(s)** ({stage.selection.reason}). "
                 "G2 is the shortest term's lag; G1 the rest.")
    lines += ["", "| transfer function | numerator | denominator |", "|---|---|---|"]
    for key, label in (("heater_to_flange", "G1 heater to flange (K/W)"),
                       ("flange_to_thermometer", "G2 flange to T2 (K/K)"),
                       ("heater_to_ptc_stage", "G3 heater to T5 (K/W)"),
                       ("ptc_to_flange", "G_link cooler heat to flange (K/W)")):
        function = getattr(model, key)
        lines.append(f"| {label} | {', '.join(f'{c:.6g}' for c in function.numerator)} | "
                     f"{', '.join(f'{c:.6g}' for c in function.denominator)} |")
    lines += ["", "## Parameters and their uncertainties", "",
              "Standard uncertainty (1 sigma): the fit's covariance, checked by a moving-block bootstrap of the "
              "residuals (the ratio bootstrap / covariance is shown; where the bootstrap is larger beyond its "
              "sampling error it is the one stated). The 95 % interval is value +- 2 sigma.", "",
              "| parameter | value | 1 sigma | unit | bootstrap / covariance |", "|---|---|---|---|---|"]
    stated = result.uncertainty
    for name, value, sigma in zip(stated.names, stated.values, stated.standard_uncertainties):
        label, unit, scale = _label(name)
        shown, shown_sigma = _number(value * scale, sigma * scale)
        ratio = result.bootstrap_ratio.get(name)
        lines.append(f"| {label} | {shown} | {shown_sigma} | {unit} | "
                     f"{f'{ratio:.2f}' if ratio is not None and math.isfinite(ratio) else '-'} |")
    derived = result.derived()
    lines += ["", "Derived:", ""]
    for key, label, unit, scale in (
            ("heater_to_thermometer_dc_gain_K_per_W", "heater to T2 DC gain", "K/W", 1.0),
            ("heater_to_ptc_stage_dc_gain_K_per_W", "heater to T5 DC gain", "K/W", 1.0),
            ("ptc_line_gain_T2_over_T5", "line gain |T2/T5|", "", 1.0),
            ("ptc_line_T2_lag_behind_T5_rad", "T2's lag behind T5 at the line", "rad", 1.0)):
        value, sigma = derived[key]
        shown, shown_sigma = _number(value * scale, sigma * scale)
        lines.append(f"- {label}: {shown} +- {shown_sigma} {unit}")
    lines += ["", "## How well it fits", "",
              f"Noise (white floor of the residuals): T2 {result.noise_rms_K[0] * 1e6:.1f} µK, "
              f"T5 {result.noise_rms_K[1] * 1e6:.1f} µK rms.", "",
              "| record | T2 residual rms / noise | T5 residual rms / noise |", "|---|---|---|"]
    for path, (f, s) in zip(record_paths, result.residual_rms_in_noise):
        lines.append(f"| `{Path(str(path)).name}` | {f:.3f} | {s:.3f} |")
    lines += ["", "Number of terms (BIC: lower is better; held-out: fitted on every other block, rms on the "
              "others):", "", "| path | terms | time constants (s) | rms (µK) | held-out rms (µK) | BIC |",
              "|---|---|---|---|---|---|"]
    for name, channel in (("G2 G1", flange), ("G3", stage)):
        for row in channel.selection.table:
            mark = " (chosen)" if row["terms"] == channel.fit.count else ""
            lines.append(f"| {name} | {row['terms']}{mark} | {', '.join(f'{t:.4g}' for t in row['time_constants_s'])}"
                         f" | {row['residual_rms_K'] * 1e6:.2f} | {row['held_out_rms_K'] * 1e6:.2f} | "
                         f"{row['bic']:.0f}" + (f" ({row['degenerate']})" if row["degenerate"] else "") + " |")
    if feedforward is not None:
        lines += ["", f"## The feedforward at {feedforward.setpoint_K:g} K", ""]
        if feedforward.problem or feedforward.limit is None:
            lines.append(f"No limit: {feedforward.problem}")
        else:
            limit = feedforward.limit
            lines += [
                f"Heater {feedforward.heater_resistance_ohm:g} ohm, {feedforward.max_current_A:g} A "
                f"(0 to {limit.max_heater_power_W * 1e3:.0f} mW); the setpoint needs {limit.mean_heater_power_W * 1e3:.1f} "
                f"mW on average.", "",
                f"- open line on T2 (no feedforward): {limit.open_line_K * 1e3:.3f} mK",
                f"- best sinusoid: {limit.best_sinusoid_K * 1e3:.3f} mK",
                f"- **limit (best heater waveform): {limit.ptc_periodic_limit_K * 1e3:.3f} mK**, limited by "
                f"{limit.limited_by} (authority {limit.authority:.2f})",
                "- with the model's uncertainty: " + (feedforward.spread.describe() if feedforward.spread is not None
                                                      else "not stated"),
            ]
    lines += ["", "## PI gains (cryod tune)", ""]
    lines.append(tuning_text if tuning_text else "Not run (--no-tune). Run `cryod tune --model <this model> "
                                                 "--setpoint K` for the suggestion.")
    if figures:
        lines += ["", "## Figures", ""]
        for name, path in figures.items():
            lines.append(f"![{name}]({Path(path).name})")
    path = out / REPORT_NAME
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


__all__ = ["REPORT_NAME", "FeedforwardSection", "feedforward_section", "write_report"]
