"""Loading any supported calibration file, recognising its format.

Examples
--------
>>> from pathlib import Path
>>> curve = load_calibration(Path("config/calibration/X186279.340"))
>>> curve.serial_number, curve.sensor_model
('X186279', 'CX-1050-SD-HT-1.4L')
>>> round(curve.temperature_K(1000.0), 4)
12.2692
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from cryod.thermometry.curve import CalibrationCurve
from cryod.thermometry.lakeshore_340 import read_340
from cryod.thermometry.lakeshore_cof import read_cof
from cryod.thermometry.raw_table import read_raw_table
from cryod.thermometry.source_text import CalibrationText, label_and_value

#: Format names accepted by :func:`load_calibration`, with their readers.
READERS: dict[str, Callable[[CalibrationText], CalibrationCurve]] = {
    "lakeshore-340": read_340,
    "chebyshev-cof": read_cof,
    "raw-table": read_raw_table,
}
EXTENSIONS = {".340": "lakeshore-340", ".cof": "chebyshev-cof"}


def load_calibration(path: str | Path, format: str | None = None) -> CalibrationCurve:
    """Read a calibration file.

    Parameters
    ----------
    path : str or pathlib.Path
    format : {'lakeshore-340', 'chebyshev-cof', 'raw-table'}, optional
        When None: ``.340`` and ``.cof`` files by their extension; any other
        file by its content (a ``Number of fit ranges`` line makes it a
        Chebyshev file, a ``Data Format`` header line a .340 curve, anything
        else a raw R-T table).

    Returns
    -------
    CalibrationCurve

    Raises
    ------
    CalibrationFileError
        The file is missing, unreadable or malformed (file and line named).
    ValueError
        An unknown ``format``.
    """
    if format is not None and format not in READERS:
        raise ValueError(f"unknown calibration format {format!r}; known: {', '.join(READERS)}")
    text = CalibrationText.read(path)
    return READERS[format or detect_format(text)](text)


def detect_format(text: CalibrationText) -> str:
    """The format name for a file, from its extension or else its content."""
    by_extension = EXTENSIONS.get(Path(text.source).suffix.lower())
    if by_extension:
        return by_extension
    for line in text.content_lines():
        label, _ = label_and_value(line.text)
        if label.replace(" ", "").startswith("numberoffitranges"):
            return "chebyshev-cof"
        if label == "data format":
            return "lakeshore-340"
    return "raw-table"
