"""Calibration files: every supported format read, malformed files refused with file and line."""

import math

import numpy as np
import pytest

from cryod.thermometry import CalibrationCurve, CalibrationFileError, load_calibration
from cryod.thermometry.breakpoints import BreakpointCurve
from cryod.thermometry.chebyshev import ChebyshevCurve
from cryod.thermometry.spline_table import SplineTableCurve
from cryod.yaml_source import FileFormatError
from tests.conftest import CALIBRATION_DATA, CONFIG

X186279 = CALIBRATION_DATA / "X186279.340"
X162690_COF = CALIBRATION_DATA / "X162690.cof"


def copy_edited(source, tmp_path, edit, name=None, newline="\n"):
    """A copy of ``source`` in tmp_path after ``edit(lines) -> lines``."""
    lines = edit(source.read_text().splitlines())
    path = tmp_path / (name or source.name)
    path.write_bytes((newline.join(lines) + newline).encode())
    return path


def line_number(path, fragment):
    return next(number for number, line in enumerate(path.read_text().splitlines(), start=1) if fragment in line)


def refused(path, line, *fragments, **load_arguments):
    """Assert that loading ``path`` fails at ``line`` with every fragment in the message."""
    with pytest.raises(CalibrationFileError) as caught:
        load_calibration(path, **load_arguments)
    error = caught.value
    assert error.source == str(path)
    assert error.line == line, str(error)
    assert str(error).startswith(f"{path}:{line}: " if line is not None else f"{path}: ")
    for fragment in fragments:
        assert fragment in str(error), str(error)
    return error


def write_340(path, data_format, units, temperatures_K, coefficient=1, header_format=None):
    """A .340 file in Lake Shore's layout."""
    rows = "".join(f"{index:3d}  {value:.6g}       {temperature:.6g}\n"
                   for index, (value, temperature) in enumerate(zip(units, temperatures_K), start=1))
    path.write_text(f"Sensor Model:   TEST-{data_format}\nSerial Number:  S{data_format}\n"
                    f"Data Format:    {header_format or data_format}      (comment)\nSetPoint Limit: 375.0      (Kelvin)\n"
                    f"Temperature coefficient:  {coefficient} (Negative)\nNumber of Breakpoints:   {len(units)}\n\n"
                    f"No.   Units      Temperature (K)\n\n{rows}")
    return path


# ---------------------------------------------------------------------------
# .340 curves
# ---------------------------------------------------------------------------
def test_340_header_fields_and_breakpoints():
    curve = load_calibration(X186279)
    assert isinstance(curve, BreakpointCurve) and isinstance(curve, CalibrationCurve)
    assert (curve.sensor_model, curve.serial_number) == ("CX-1050-SD-HT-1.4L", "X186279")
    assert curve.data_format.code == 4 and curve.sensor_unit == "ohm"
    assert curve.setpoint_limit_K == 325.0
    assert curve.breakpoint_sensor_units.size == 149
    assert curve.temperature_range_K == (1.201, 330.010)
    assert curve.resistance_range_ohm == pytest.approx((10 ** 1.82643, 10 ** 4.34973), rel=1e-15)
    assert curve.source == str(X186279)
    assert "Lake Shore data format 4" in curve.method


@pytest.mark.parametrize("data_format, unit, units, temperatures, coefficient, expect_midpoint", [
    # format 1, thermocouple-like: mV rising with T, linear in (mV, T)
    (1, "mV", [-5.0, -2.0, 0.0, 3.0], [80.0, 200.0, 273.15, 350.0], 2,
     lambda u, t: (u[:-1] + u[1:]) / 2),
    # format 2, diode-like: V falling with T, linear in (V, T)
    (2, "V", [0.5, 1.0, 1.1, 1.6], [300.0, 77.0, 25.0, 1.4], 1,
     lambda u, t: (u[:-1] + u[1:]) / 2),
    # format 3, platinum-like: ohm rising with T, linear in (R, T)
    (3, "ohm", [2.0, 20.0, 60.0, 110.0], [20.0, 70.0, 170.0, 300.0], 2,
     lambda u, t: (u[:-1] + u[1:]) / 2),
])
def test_linear_formats_interpolate_straight_lines(tmp_path, data_format, unit, units, temperatures, coefficient,
                                                   expect_midpoint):
    curve = load_calibration(write_340(tmp_path / "curve.340", data_format, units, temperatures, coefficient))
    assert curve.data_format.code == data_format and curve.sensor_unit == unit
    units, temperatures = np.array(units), np.array(temperatures)
    midpoints = expect_midpoint(units, temperatures)
    np.testing.assert_allclose(curve.temperature_K_from_sensor_units(midpoints),
                               (temperatures[:-1] + temperatures[1:]) / 2, rtol=1e-13)
    np.testing.assert_allclose(curve.sensor_units_at(temperatures), units, rtol=1e-13, atol=1e-13)


def test_log_ohm_log_kelvin_format_is_straight_in_log_log(tmp_path):
    log_ohm = np.array([1.8, 2.5, 3.2, 4.3])
    temperatures = np.array([300.0, 40.0, 8.0, 1.5])
    curve = load_calibration(write_340(tmp_path / "loglog.340", 5, log_ohm, temperatures))
    assert curve.data_format.name == "log ohm/log K"
    geometric_means = np.sqrt(temperatures[:-1] * temperatures[1:])
    np.testing.assert_allclose(curve.temperature_K(10 ** ((log_ohm[:-1] + log_ohm[1:]) / 2)), geometric_means,
                               rtol=1e-13)
    np.testing.assert_allclose(curve.resistance_ohm(temperatures), 10 ** log_ohm, rtol=1e-13)


def test_voltage_curve_refuses_the_resistance_methods(tmp_path):
    curve = load_calibration(write_340(tmp_path / "diode.340", 2, [0.5, 1.0, 1.1, 1.6], [300.0, 77.0, 25.0, 1.4]))
    assert curve.temperature_K_from_sensor_units(1.05) == pytest.approx(51.0)
    for call in (lambda: curve.temperature_K(1.05), lambda: curve.resistance_ohm(77.0),
                 lambda: curve.sensitivity_ohm_per_K(77.0), lambda: curve.resistance_range_ohm):
        with pytest.raises(TypeError, match="read in V, not a resistance thermometer"):
            call()


@pytest.mark.parametrize("newline", ["\r\n", "\r"], ids=["CRLF", "CR"])
def test_crlf_and_lf_files_give_the_same_curve(tmp_path, newline):
    for source in (X186279, X162690_COF, CALIBRATION_DATA / "X162690.dat"):
        other = copy_edited(source, tmp_path, lambda lines: lines, newline=newline)
        assert newline.encode() in other.read_bytes() and b"\n" not in other.read_bytes().replace(b"\r\n", b"")
        lf, windows = load_calibration(source), load_calibration(other)
        temperatures = np.linspace(*lf.calibrated_temperature_ranges_K[0], 50)
        np.testing.assert_array_equal(windows.resistance_ohm(temperatures), lf.resistance_ohm(temperatures))
        assert windows.serial_number == lf.serial_number


def test_config_calibrations_cover_the_cryostat():
    flange = load_calibration(CONFIG / "calibration" / "X186279.340")
    ptc_stage = load_calibration(CONFIG / "calibration" / "X207058.340")
    for curve in (flange, ptc_stage):
        low, high = curve.temperature_range_K
        assert low < 3.0 and high > 30.0
    assert (flange.serial_number, ptc_stage.serial_number) == ("X186279", "X207058")


# ---------------------------------------------------------------------------
# malformed .340 files
# ---------------------------------------------------------------------------
def test_340_unknown_data_format_is_refused(tmp_path):
    path = write_340(tmp_path / "bad.340", 4, [2.0, 3.0], [40.0, 4.0], header_format=7)
    refused(path, 3, "data format 7 is not one Lake Shore defines", "4 = log ohm/K", "5 = log ohm/log K")


def test_340_missing_and_unknown_header_fields_are_refused(tmp_path):
    without_serial = copy_edited(X186279, tmp_path, lambda lines: [l for l in lines if "Serial" not in l])
    refused(without_serial, 7, "lacks 'Serial Number'")
    extra = copy_edited(X186279, tmp_path, lambda lines: lines[:2] + ["Interpolation Method:  Straight Line"]
                        + lines[2:], name="extra.340")
    refused(extra, 3, "unknown header line 'Interpolation Method:  Straight Line'")
    twice = copy_edited(X186279, tmp_path, lambda lines: lines[:2] + ["Serial Number: X1"] + lines[2:],
                        name="twice.340")
    refused(twice, 3, "'Serial Number' given twice (first on line 2)")
    blank_model = load_calibration(copy_edited(X186279, tmp_path, lambda lines: ["Sensor Model:"] + lines[1:],
                                               name="blank.340"))
    assert blank_model.sensor_model is None and blank_model.serial_number == "X186279"
    no_count = copy_edited(X186279, tmp_path, lambda lines: [l.split(":")[0] + ":" if "Number of" in l else l
                                                             for l in lines], name="count.340")
    refused(no_count, 6, "'Number of Breakpoints' has no value")
    bad_limit = copy_edited(X186279, tmp_path, lambda lines: [l.replace("325.0", "warm") for l in lines],
                            name="limit.340")
    refused(bad_limit, 4, "setpoint limit: not a number: 'warm'")


def test_340_coefficient_contradicting_the_data_is_refused(tmp_path):
    path = copy_edited(X186279, tmp_path, lambda lines: [l.replace("1 (Negative)", "2 (Positive)") for l in lines])
    refused(path, 5, "temperature coefficient 2 (positive) contradicts the breakpoints",
            "sensor units fall as the temperature rises")


def test_340_non_monotonic_breakpoints_are_refused(tmp_path):
    swapped = {" 40  2.18172 ": " 40  2.19331 ", " 41  2.19331 ": " 41  2.18172 "}
    path = copy_edited(X186279, tmp_path, lambda lines: [next((line.replace(old, new) for old, new in swapped.items()
                                                               if old in line), line) for line in lines])
    refused(path, 50, "breakpoint 41: sensor units 2.18172 break the rising order of breakpoints 1 to 40",
            "strictly monotonic")
    repeated = copy_edited(X186279, tmp_path, lambda lines: [l.replace("1.201", "1.400") for l in lines],
                           name="repeated.340")
    refused(repeated, line_number(repeated, "149 "), "breakpoint 149: temperature 1.4 break the falling order")


def test_340_wrong_field_count_and_sequence_are_refused(tmp_path):
    short = copy_edited(X186279, tmp_path, lambda lines: [l.replace(" 25  2.01673 ", " 25  ") for l in lines])
    refused(short, line_number(short, " 25  "), "breakpoint 25: expected 3 fields (number, units, temperature), got 2")
    renumbered = copy_edited(X186279, tmp_path, lambda lines: [l.replace(" 25  2.01673", " 26  2.01673")
                                                               for l in lines], name="renumbered.340")
    refused(renumbered, line_number(renumbered, "2.01673"), "breakpoint number 26 out of sequence (expected 25)")
    bad_number = copy_edited(X186279, tmp_path, lambda lines: [l.replace("2.01673", "2.0l673") for l in lines],
                             name="typo.340")
    refused(bad_number, 34, "breakpoint 25: units: not a number: '2.0l673'")


def test_340_truncated_files_are_refused(tmp_path):
    cut = copy_edited(X186279, tmp_path, lambda lines: lines[:60])
    refused(cut, 60, "the file ends after 51 of the 149 breakpoints the header announces (line 6)", "truncated")
    mid_line = tmp_path / "midline.340"
    mid_line.write_bytes(X186279.read_bytes()[:-12])          # cut inside the last breakpoint
    refused(mid_line, 158, "breakpoint 149: expected 3 fields")
    longer = copy_edited(X186279, tmp_path, lambda lines: lines + ["150  4.40000       1.150"], name="long.340")
    refused(longer, 159, "more breakpoints than the 149 the header announces (line 6)")


# ---------------------------------------------------------------------------
# Chebyshev .cof files
# ---------------------------------------------------------------------------
def test_cof_ranges_read():
    curve = load_calibration(X162690_COF)
    assert isinstance(curve, ChebyshevCurve)
    assert curve.serial_number == "X162690" and curve.sensor_model is None
    first, second = curve.fit_ranges
    assert (first.fit_type, first.z_lower, first.z_upper) == ("LOG", 2.91027046513, 4.50588986348)
    assert (first.lower_limit, first.upper_limit) == (899.154, 21279.5)
    assert first.coefficients[0] == 5.347944 and len(first.coefficients) == 10
    assert len(second.coefficients) == 8 and second.coefficients[-1] == -0.001546
    assert curve.calibrated_sensor_unit_ranges == [(63.9896, 231.849), (899.154, 21279.5)]


def test_cof_labels_are_matched_by_prefix(tmp_path):
    """Lake Shore's own example file words its labels differently and numbers every C(i) 'Equation 1'."""
    def reword(lines):
        return [line.replace("FIT RANGE:", "Fit range:").replace("Lower Resist. limit", "Lower limit")
                    .replace("Upper Resist. limit", "upper  LIMIT").replace("Equation 2", "Equation 1")
                    .replace("Zlower for", "ZLOWER  for") for line in lines]
    reworded = copy_edited(X162690_COF, tmp_path, reword)
    original = load_calibration(X162690_COF)
    assert load_calibration(reworded).fit_ranges == original.fit_ranges


def test_cof_content_is_recognised_without_the_extension(tmp_path):
    as_text = copy_edited(X162690_COF, tmp_path, lambda lines: lines, name="X162690_fit.txt")
    curve = load_calibration(as_text)
    assert isinstance(curve, ChebyshevCurve) and curve.serial_number == "X162690_fit"
    with pytest.raises(ValueError, match="unknown calibration format 'spline'"):
        load_calibration(as_text, format="spline")
    refused(as_text, 33, "a table needs at least 4 points, found 0", format="raw-table")


def test_malformed_cof_files_are_refused(tmp_path):
    def drop(fragment):
        return lambda lines: [line for line in lines if fragment not in line]
    refused(copy_edited(X162690_COF, tmp_path, drop("C(9)"), name="order.cof"), 17,
            "fit range 1: order 9 needs 10 coefficients C(0)..C(9), found 9")
    refused(copy_edited(X162690_COF, tmp_path, drop("Zupper for fit range 2"), name="zupper.cof"), 19,
            "fit range 2 lacks Zupper")
    unknown = copy_edited(X162690_COF, tmp_path, lambda l: l[:3] + ["Fit quality for range 1: good"] + l[3:],
                          name="unknown.cof")
    refused(unknown, 4, "fit range 1: unrecognised line 'Fit quality for range 1: good'")
    wide = copy_edited(X162690_COF, tmp_path, lambda l: [x.replace("21279.5", "40000") for x in l], name="wide.cof")
    refused(wide, 2, "fit range 1: limits 899.154 to 40000 reach outside Zlower..Zupper")
    swapped = copy_edited(X162690_COF, tmp_path, lambda l: [x.replace("C(3) Equation 1", "C(4) Equation 1") for x in l],
                          name="swapped.cof")
    refused(swapped, 12, "coefficient C(4) out of order (expected C(3))")
    truncated = copy_edited(X162690_COF, tmp_path, lambda l: l[:18], name="truncated.cof")
    refused(truncated, 18, "the file ends after 1 of the 2 fit ranges announced on line 1", "truncated")
    refused(copy_edited(X162690_COF, tmp_path, lambda l: l[1:], name="headless.cof"), 1,
            "expected 'Number of fit ranges: N' as the first line")


def test_cof_fit_that_turns_back_is_refused(tmp_path):
    bent = copy_edited(X162690_COF, tmp_path, lambda l: [x.replace("-0.003947", "-0.903947") for x in l])
    refused(bent, 2, "fit range 1: the fit turns back at")


# ---------------------------------------------------------------------------
# raw R-T tables
# ---------------------------------------------------------------------------
def test_lakeshore_dat_and_two_column_tables_are_read():
    for name, points, low_K in (("X162690.dat", 84, 1.20048138703863), ("X100332.dat", 71, 3.59971711260364),
                                ("X98650.txt", 99, 0.259662)):
        curve = load_calibration(CALIBRATION_DATA / name)
        assert isinstance(curve, SplineTableCurve)
        assert curve.temperatures_K.size == points and curve.temperature_range_K[0] == low_K
        assert curve.serial_number == name.split(".")[0]
        np.testing.assert_allclose(curve.temperature_K(curve.resistances_ohm), curve.temperatures_K, rtol=1e-14)


def test_column_order_and_sort_direction_do_not_matter(tmp_path):
    original = load_calibration(CALIBRATION_DATA / "X98650.txt")
    def resistance_first_rising(lines):
        pairs = [line.split() for line in lines if line.strip()]
        return [f"{r},{t}" for t, r in reversed(pairs)]
    swapped = copy_edited(CALIBRATION_DATA / "X98650.txt", tmp_path, resistance_first_rising, name="X98650.csv")
    curve = load_calibration(swapped)
    temperatures = np.geomspace(0.3, 300.0, 40)
    np.testing.assert_array_equal(curve.resistance_ohm(temperatures), original.resistance_ohm(temperatures))


def test_header_decides_columns_that_values_cannot(tmp_path):
    """A platinum-like table: both columns stay below 500, so only a header can tell them apart."""
    rows = [(30.0, 3.6), (77.0, 20.4), (150.0, 48.9), (200.0, 68.6), (273.15, 100.0), (300.0, 110.0)]
    plain = tmp_path / "pt100.txt"
    plain.write_text("".join(f"{r} {t}\n" for t, r in rows))
    refused(plain, 1, "cannot tell which column is the temperature: both could hold temperatures",
            "add a header line")
    titled = tmp_path / "pt100_titled.txt"
    titled.write_text("R_ohm T_K\n" + "".join(f"{r} {t}\n" for t, r in rows))
    assert load_calibration(titled).temperature_K(100.0) == pytest.approx(273.15)


def test_malformed_tables_are_refused(tmp_path):
    source = CALIBRATION_DATA / "X100332.dat"
    def replace(old, new):
        return lambda lines: [line.replace(old, new) for line in lines]
    bumped = copy_edited(source, tmp_path, replace("1.28204798376460E+04", "1.92204798376460E+04"))
    refused(bumped, 8, "resistance 19220.5 ohm at 4.60431 K breaks the trend of the table",
            "resistance falls with temperature; line 7")
    three = copy_edited(source, tmp_path, replace("1.28204798376460E+04", "1.28204798376460E+04  0.1"),
                        name="three.dat")
    refused(three, 8, "expected 2 numbers (temperature and resistance), got 3 fields")
    words = copy_edited(source, tmp_path, lambda l: l[:10] + ["end of run"] + l[10:], name="words.dat")
    refused(words, 11, "expected 2 numbers")
    twice = copy_edited(source, tmp_path, replace("4.60430756974449E+00", "4.21975966426137E+00"), name="twice.dat")
    refused(twice, 8, "temperature 4.21976 K appears twice (also line 7)")
    refused(copy_edited(source, tmp_path, lambda l: l[:6], name="short.dat"), 6,
            "a table needs at least 4 points, found 3")


def test_table_whose_spline_would_turn_back_is_refused(tmp_path):
    """Monotonic points, but a jump between them that no cubic can follow without overshooting."""
    uneven = tmp_path / "uneven.dat"
    uneven.write_text("Temperature Resistance\n" + "".join(f"{t} {r}\n" for t, r in
                                                          [(1, 1000), (2, 999), (3, 998), (4, 100), (5, 99), (6, 98)]))
    refused(uneven, 4, "the cubic spline through the table turns back near 480.252 ohm")


def test_unreadable_files_are_refused(tmp_path):
    refused(tmp_path / "absent.340", None, "file not found")
    binary = tmp_path / "image.dat"
    binary.write_bytes(b"\x89PNG\0\0")
    refused(binary, None, "not a text file")
    with pytest.raises(FileFormatError):               # one except clause for config and calibration files
        load_calibration(tmp_path / "absent.cof")
