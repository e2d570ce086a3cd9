"""The example configuration (config/cryod.yaml) as the tests edit and run it.

The text and edits of it written to a test's folder (its calibration paths made absolute, so that
the file reads from anywhere), the line a fragment is on (the errors name it), and the loaded
configuration moved into a test's folder on the in-process simulated bench.
"""

import dataclasses
import shutil

from cryod.config import load_config
from tests.conftest import CONFIG

EXAMPLE = (CONFIG / "cryod.yaml").read_text()
PI_SECTION = "  pi:                             # PI feedback on T2"      # a zone table goes right above it


def usable_anywhere(text):
    """A configuration's text with the example's calibration paths made absolute."""
    return text.replace("calibration: calibration/", f"calibration: {CONFIG}/calibration/")


def config_file(tmp_path, text=None):
    """``text`` (the example's by default) written as tmp_path/cryod.yaml, usable anywhere."""
    path = tmp_path / "cryod.yaml"
    path.write_text(usable_anywhere(text or EXAMPLE))
    return path


def written(tmp_path, old, new):
    """The example with its first ``old`` replaced by ``new``, written: the path and the text written."""
    assert old in EXAMPLE, old
    text = usable_anywhere(EXAMPLE.replace(old, new, 1))
    return config_file(tmp_path, text), text


def with_zone_table(tmp_path, table, *replacements):
    """The example with ``table`` under ``control:`` and each (old, new) of ``replacements`` made, written
    as tmp_path/cryod.yaml beside a copy of the shipped model (zone-model.yaml): (path, text)."""
    text = usable_anywhere(EXAMPLE).replace(PI_SECTION, table + PI_SECTION, 1)
    for old, new in replacements:
        assert old in text, old
        text = text.replace(old, new, 1)
    shutil.copy(CONFIG / "model.yaml", tmp_path / "zone-model.yaml")
    path = tmp_path / "cryod.yaml"
    path.write_text(text)
    return path, text


def line_of(text, fragment):
    """The number of the first line of ``text`` that holds ``fragment`` (1 for the first)."""
    return next(number for number, line in enumerate(text.splitlines(), 1) if fragment in line)


def in_tmp(config, tmp_path, **control):
    """``config`` with its data and socket in tmp_path, on the in-process simulated bench (control changed)."""
    return dataclasses.replace(
        config,
        data=dataclasses.replace(config.data, directory=tmp_path / "data"),
        control_socket=dataclasses.replace(config.control_socket, path=tmp_path / "control.sock"),
        simulation=dataclasses.replace(config.simulation, transport="in-process"),
        control=dataclasses.replace(config.control, **control),
    )


def simulated_config(tmp_path, **control):
    """The example configuration in tmp_path on the in-process simulated bench (``control`` changed)."""
    return in_tmp(load_config(CONFIG / "cryod.yaml"), tmp_path, **control)


def simulate_args(tmp_path, *extra):
    """``cryod --simulate --speed max`` arguments with the data and the socket in tmp_path."""
    return ["--simulate", "--speed", "max", "--data-dir", str(tmp_path / "data"),
            "--socket", str(tmp_path / "c.sock"), *extra]
