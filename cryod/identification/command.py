"""``cryod identify RECORD [RECORD...] [--base MODEL] --out MODEL.yaml``.

Fits the model's transfer functions, operating point and PTC source to the
records (:mod:`cryod.identification.fit`) and writes a model file that
:func:`cryod.model.load_model` reads. An existing file is not overwritten
unless ``--force`` is given.

Exit status: 0 done; 2 a record, the base model or the output path cannot be
used; 1 the records do not determine the model.
"""

from __future__ import annotations

import argparse
import cmath
import dataclasses
import json
import sys
from pathlib import Path

from cryod.analysis.record_data import RecordData
from cryod.analysis.summary import plain
from cryod.identification.fit import Identification, IdentificationError, identify
from cryod.model import DEFAULT_MODEL_PATH, load_model, save_model
from cryod.records.record import RecordFormatError, read_record
from cryod.yaml_source import FileFormatError


def configure_parser(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Arguments of ``cryod identify``."""
    parser.description = ("Fit the cryostat model (heater to T2 and T5 transfer functions, the PTC line's path to "
                          "T2, operating point, PTC source, sensor noise) to measured records and write a model file.")
    parser.add_argument("records", nargs="+", help="records of one cryostat (cryod-log v1 CSV)")
    parser.add_argument("--base", default=str(DEFAULT_MODEL_PATH),
                        help="model to start from; also gives the PTC heat capacity (default: the shipped model)")
    parser.add_argument("--out", required=True, help="model file to write (YAML)")
    parser.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    parser.add_argument("--no-harmonics", action="store_true", help="do not put T5's harmonics into the model")
    parser.add_argument("--json", action="store_true", help="print a summary as one JSON object on stdout")
    return parser


def summary(result: Identification, out: Path) -> dict:
    model = result.model
    return plain({
        "model": str(out),
        "heater_to_thermometer_time_constants_s": list(result.flange_time_constants_s),
        "heater_to_thermometer_dc_gain_K_per_W": model.heater_to_thermometer.dc_gain,
        "heater_to_ptc_stage_gain_K_per_W": result.stage_gain_K_per_W,
        "heater_to_ptc_stage_time_constant_s": result.stage_time_constant_s,
        "ptc_line_gain_T2_over_T5": abs(result.ptc_gain_at_line),
        "ptc_line_T2_lag_behind_T5_rad": -cmath.phase(result.ptc_gain_at_line),
        "operating_point_K": dataclasses.asdict(model.operating_point),
        "ptc_angular_frequency_rad_s": model.ptc.angular_frequency_rad_s,
        "ptc_stage_amplitude_K": model.ptc.ptc_stage_amplitude_K,
        "noise_rms_K": list(result.noise_rms_K),
        "residual_rms_in_noise_units": [list(pair) for pair in result.residual_rms_in_noise],
    })


def run(args: argparse.Namespace) -> int:
    """Run the identification; returns the exit status."""
    out = Path(args.out)
    if out.exists() and not args.force:
        print(f"cryod identify: {out} exists; give --force to overwrite it", file=sys.stderr)
        return 2
    try:
        base = load_model(args.base)
        records = [RecordData.from_record(read_record(path)) for path in args.records]
    except (RecordFormatError, FileFormatError) as error:
        print(f"cryod identify: {error}", file=sys.stderr)
        return 2
    try:
        result = identify(records, base, harmonics=not args.no_harmonics)
    except (IdentificationError, ValueError, ArithmeticError) as error:
        print(f"cryod identify: {error}", file=sys.stderr)
        return 1
    model = dataclasses.replace(result.model, name=f"identified from {len(records)} record(s)",
                                description=f"Identified by cryod identify from {', '.join(args.records)}, "
                                            f"starting from {args.base}.")
    header = "\n".join([f"Written by cryod identify from: {', '.join(args.records)}", f"Base model: {args.base}"]
                       + [f"Residual rms / noise, {path}: T2 {f:.3f}, T5 {s:.3f}"
                          for path, (f, s) in zip(args.records, result.residual_rms_in_noise)])
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        save_model(model, out, header=header)
    except OSError as error:
        print(f"cryod identify: cannot write {out}: {error}", file=sys.stderr)
        return 2
    for path, (flange, stage) in zip(args.records, result.residual_rms_in_noise):
        if flange > 2.0 or stage > 2.0:
            print(f"cryod identify: warning: the identified model leaves {flange:.3g} x the noise on T2 and "
                  f"{stage:.3g} x on T5 in {path}: these records are not all explained by the model's form "
                  "(different cryostats, or an effect: run cryod analyze on them)", file=sys.stderr)
    text = summary(dataclasses.replace(result, model=model), out)
    print(json.dumps(text) if args.json else "\n".join(f"{key}: {value}" for key, value in text.items()))
    return 0
