"""Figures and numbers of docs/explanation/analysis-method.md.

Run: PYTHONPATH=. python3 docs/figures/analysis_examples.py

1. The walk-through: a one-hour identification-style record of a cryostat whose
   flange thermometer lags by 0.3 s and whose base parameters are a few percent
   off the shipped model's (another day: PTC phase and line of its own),
   analysed with the shipped model; ``cryod analyze`` output goes to
   docs/figures/analysis-example/.
2. The paper's own measurements: Table 1 regenerated as a record, analysed with
   the printed model (docs/figures/analysis-paper-printed/) and the shipped one.
3. The paper's section 4.1 (the simulation settles more slowly than the
   experiment): PI from 4.23 K to 5 K with candidate causes, their settling
   times (docs/figures/analysis_settling.png) and what the analysis names on
   each record.
4. ``cryod identify`` on two records of the shipped model (one hour
   identification-style, 30 min PI-only), starting from the printed model.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import math
import shutil
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy import ndimage  # noqa: E402

from cryod import cli  # noqa: E402
from cryod.model import (  # noqa: E402
    DeadTime, HeatCapacityTemperature, HeaterNonlinearity, OperatingPoint, SensorLag, load_model,
)
from cryod.analysis.paper_table1 import regenerated_record  # noqa: E402
from cryod.records.record import write_record  # noqa: E402
from simulated_hw.hidden_effects import perturbed_base  # noqa: E402
from simulated_hw.measurement_programs import make_record  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent


def analyze(record_path: Path, out: Path, model: Path | None = None, figures: bool = True) -> dict:
    argv = ["analyze", str(record_path), "--out", str(out), "--json"]
    if model is not None:
        argv += ["--model", str(model)]
    if not figures:
        argv.append("--no-figures")
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        status = cli.main(argv)
    if status != 0:
        raise SystemExit(f"cryod analyze failed on {record_path}")
    return json.loads(buffer.getvalue())


def relative_paths(directory: Path, *prefixes: Path) -> None:
    """Take the machine's folders out of the texts written into ``directory``."""
    for name in ("report.md", "analysis.json", "extended-model.yaml"):
        path = directory / name
        text = path.read_text()
        for prefix in prefixes:
            text = text.replace(f"{prefix}/", "")
        path.write_text(text)


def summary(title: str, result: dict) -> None:
    print(f"\n== {title}: cause {result['cause']}, causes {[c['cause'] for c in result['causes']]}, "
          f"gain {result['gain']['ratio']:.4g} (base {result['gain']['base']:.4g}, "
          f"extended {result['gain']['extended']:.4g})")
    recalibrated = result["recalibrated"]
    print(f"   recalibration applied: {recalibrated['applied']}, gain {recalibrated['gain']['ratio']:.4g}")
    for row in recalibrated["parameters"]:
        print(f"   {row['parameter']:40s} shipped {row['shipped']:.6g} fitted {row['fitted']:.6g} "
              f"+- {row['uncertainty']:.2g} ({row['significance']:.3g} sigma){' at tolerance' if row['at_tolerance'] else ''}")
    for row in result["causes"]:
        print(f"   cause {row['cause']}: {row['parameters']}, explains {100 * row['explained_fraction']:.1f} %, "
              f"gain {row['gain']['ratio']:.4g}")
    for row in result["discrepancies"][:6]:
        print(f"   {row['significance']:12.4g} sigma  model {row['model']:.6g}  measured {row['measured']:.6g}  "
              f"{row['quantity']}")
    for row in sorted(result["candidates"], key=lambda c: -c["score"])[:3]:
        print(f"   candidate {row['cause']}: score {row['score']:.4g}, {row['significance']:.3g} sigma, "
              f"{row['parameters']}")


def walk_through(work: Path, model) -> None:
    day = dataclasses.replace(model, operating_point=OperatingPoint(4.215, 3.331)).with_ptc(
        phase_rad=-1.2, angular_frequency_rad_s=10.78, ptc_stage_amplitude_K=0.118)
    truth, changes = perturbed_base(day.with_effects(sensor_lag=SensorLag(0.3)), seed=21)
    print("\n== walk-through: base parameters of the truth: " + ", ".join(f"{k} {v:.4f}" for k, v in changes.items()))
    record = make_record(truth, "identification", duration_s=3600.0, seed=21)
    path = work / "lagging-thermometer.csv"
    write_record(path, record.columns, record.metadata)
    out = HERE / "analysis-example"
    shutil.rmtree(out, ignore_errors=True)
    summary("walk-through (sensor lag 0.3 s hidden)", analyze(path, out))
    relative_paths(out, work, ROOT, HERE)
    print(f"   record: {path.stat().st_size / 1e6:.1f} MB, {len(record.columns['time_s'])} rows")


def paper(work: Path) -> None:
    path = work / "table1.csv"
    write_record(path, regenerated_record(), {"source": "Pan et al. Part 1, Table 1, regenerated"})
    out = HERE / "analysis-paper-printed"
    shutil.rmtree(out, ignore_errors=True)
    result = analyze(path, out, ROOT / "config" / "model-paper-printed.yaml")
    summary("Table 1, printed model", result)
    relative_paths(out, work, ROOT, HERE)
    extended = load_model(result["extended_model"])
    print(f"   refitted link: {extended.ptc_to_flange}")
    shipped = analyze(path, work / "table1-shipped", None, figures=False)
    summary("Table 1, shipped model", shipped)


def settling_time(time_s, flange_K, setpoint_K, period_samples, tolerance_K=1e-3) -> float:
    smooth = ndimage.uniform_filter1d(flange_K, period_samples, mode="nearest")
    outside = np.flatnonzero(np.abs(smooth - setpoint_K) > tolerance_K)
    return float(time_s[outside[-1] + 1]) if outside.size and outside[-1] + 1 < time_s.size else math.nan


def settling(work: Path, model) -> None:
    variants = {
        "shipped model": model,
        "heat capacity, exponent -1.5": model.with_effects(
            heat_capacity_temperature=HeatCapacityTemperature(-1.5, 4.23)),
        "heater nonlinearity, +1.0 /W": model.with_effects(heater_nonlinearity=HeaterNonlinearity(1.0)),
        "sensor lag 0.3 s": model.with_effects(sensor_lag=SensorLag(0.3)),
        "dead time 2 s": model.with_effects(dead_time=DeadTime(2.0)),
    }
    figure, axis = plt.subplots(figsize=(9, 4.5))
    print("\n== settling, PI from 4.23 K to 5 K (Kp 0.4 W/K, Ki 0.01 W/(K s), 0.25 W limit)")
    print("| cryostat | time to stay within 1 mK of 5 K (s) | cause named on its PI-only record |")
    print("|---|---|---|")
    for index, (name, variant) in enumerate(variants.items()):
        record = make_record(variant, "pi_only", duration_s=1200.0, seed=30 + index)
        t, flange = record.columns["time_s"], record.columns["T2_K"]
        period = int(round(2 * math.pi / 10.83 / 0.08))
        settle = settling_time(t, flange, 5.0, period)
        path = work / f"settling-{index}.csv"
        write_record(path, record.columns, record.metadata)
        cause = analyze(path, work / f"settling-{index}", figures=False)["cause"]
        print(f"| {name} | {settle:.0f} | {cause} |")
        axis.plot(t, ndimage.uniform_filter1d(flange, period, mode="nearest"), lw=1.0,
                  label=f"{name}: settles in {settle:.0f} s")
    axis.set_xlim(0, 600)
    axis.set_ylim(4.2, 5.15)
    axis.axhline(5.0, color="k", lw=0.5)
    axis.set_xlabel("time (s)")
    axis.set_ylabel("T2 (K), line averaged out")
    axis.set_title("PI from 4.23 K to 5 K: what could make a cryostat settle faster than the model")
    axis.legend(fontsize=8, loc="lower right")
    figure.tight_layout()
    figure.savefig(HERE / "analysis_settling.png", dpi=110)
    plt.close(figure)


def identification(work: Path, model) -> None:
    paths = []
    for protocol, duration, seed in (("identification", 3600.0, 41), ("pi_only", 1800.0, 42)):
        record = make_record(model.with_ptc(phase_rad=0.9), protocol, duration_s=duration, seed=seed)
        paths.append(work / f"identify-{protocol}.csv")
        write_record(paths[-1], record.columns, record.metadata)
    out = work / "identified.yaml"
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        status = cli.main(["identify", *map(str, paths), "--base", str(ROOT / "config" / "model-paper-printed.yaml"),
                           "--out", str(out), "--json"])
    if status != 0:
        raise SystemExit("cryod identify failed")
    identified = load_model(out)
    printed = load_model(ROOT / "config" / "model-paper-printed.yaml")
    print("\n== cryod identify, records of the shipped model, started from the printed model")
    print("| quantity | printed (start) | identified | shipped (truth) |")
    print("|---|---|---|---|")
    rows = [
        ("G2 G1 time constants (s)", lambda m: m.heater_to_thermometer.time_constants_s[::-1], "{:.3f}"),
        ("G1 numerator", lambda m: m.heater_to_flange.numerator, "{:.4g}"),
        ("G3 gain (K/W), time constant (s)", lambda m: (m.heater_to_ptc_stage.dc_gain,
                                                        m.heater_to_ptc_stage.time_constants_s[0]), "{:.4g}"),
        ("G_link", lambda m: m.ptc_to_flange.numerator + m.ptc_to_flange.denominator, "{:.4g}"),
        ("gain of G2 G_link at 10.83 rad/s (K/W)", lambda m: (abs(m.ptc_heat_to_thermometer.frequency_response(10.83)),),
         "{:.5f}"),
        ("operating point (K)", lambda m: (m.operating_point.flange_temperature_K,
                                           m.operating_point.ptc_stage_temperature_K), "{:.5f}"),
        ("PTC line (rad/s, K)", lambda m: (m.ptc.angular_frequency_rad_s, m.ptc.ptc_stage_amplitude_K), "{:.5f}"),
    ]
    for label, get, form in rows:
        cells = [", ".join(form.format(v) for v in get(m)) for m in (printed, identified, model)]
        print(f"| {label} | {cells[0]} | {cells[1]} | {cells[2]} |")


def main() -> None:
    model = load_model(ROOT / "config" / "model.yaml")
    with tempfile.TemporaryDirectory() as directory:
        work = Path(directory)
        walk_through(work, model)
        paper(work)
        settling(work, model)
        identification(work, model)


if __name__ == "__main__":
    main()
