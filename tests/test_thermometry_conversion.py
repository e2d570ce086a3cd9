"""Conversions: round trips, agreement with the calibration data, ranges refused, scalar and array calls."""

import importlib.util
import time

import numpy as np
import pytest

from cryod.thermometry import OutOfCalibrationRange, load_calibration
from cryod.thermometry.spline_table import SplineTableCurve
from tests.conftest import CALIBRATION_DATA, REPOSITORY

CURVE_FILES = ["X186279.340", "X207058.340", "X162690.cof", "X162690.dat", "X100332.dat", "X98650.txt"]


@pytest.fixture(scope="module")
def curves():
    return {name: load_calibration(CALIBRATION_DATA / name) for name in CURVE_FILES}


def x162690_table():
    data = np.loadtxt(CALIBRATION_DATA / "X162690.dat", skiprows=3)
    return data[:, 0], data[:, 1]


# ---------------------------------------------------------------------------
# round trips and agreement with the files
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("name", CURVE_FILES)
def test_round_trips_resistance_temperature_resistance(curves, name):
    curve = curves[name]
    for low, high in curve.calibrated_sensor_unit_ranges:
        resistances = np.geomspace(low, high, 400)
        np.testing.assert_allclose(curve.resistance_ohm(curve.temperature_K(resistances)), resistances, rtol=1e-10)
    for low, high in curve.calibrated_temperature_ranges_K:
        temperatures = np.geomspace(low, high, 400)
        np.testing.assert_allclose(curve.temperature_K(curve.resistance_ohm(temperatures)), temperatures, rtol=1e-10)


@pytest.mark.parametrize("name", ["X186279.340", "X207058.340"])
def test_340_curve_passes_through_every_breakpoint(curves, name):
    curve = curves[name]
    resistances = 10.0 ** curve.breakpoint_sensor_units
    np.testing.assert_allclose(curve.temperature_K(resistances), curve.breakpoint_temperatures_K, rtol=1e-14)
    np.testing.assert_allclose(curve.resistance_ohm(curve.breakpoint_temperatures_K), resistances, rtol=1e-14)


@pytest.mark.parametrize("name", ["X186279.340", "X207058.340"])
def test_340_between_breakpoints_is_the_straight_line_in_log_ohm(curves, name):
    """Lake Shore's method for data format 4, computed by hand: half way in log10(R) is half way in T."""
    curve = curves[name]
    log_ohm, kelvin = curve.breakpoint_sensor_units, curve.breakpoint_temperatures_K
    for fraction in (0.25, 0.5, 0.9):
        between = log_ohm[:-1] + fraction * (log_ohm[1:] - log_ohm[:-1])
        expected = kelvin[:-1] + fraction * (kelvin[1:] - kelvin[:-1])
        np.testing.assert_allclose(curve.temperature_K(10.0 ** between), expected, rtol=1e-12)


def test_chebyshev_fit_agrees_with_its_table_within_1p2_mK(curves):
    """X162690's Lake Shore fit against the measured points it was fitted to, 1.4 to 14.2 K."""
    temperatures, resistances = x162690_table()
    in_range = (temperatures >= 1.4) & (temperatures <= 14.2)
    differences = curves["X162690.cof"].temperature_K(resistances[in_range]) - temperatures[in_range]
    worst = np.abs(differences).max()
    assert in_range.sum() == 26
    assert worst < 1.2e-3
    assert worst == pytest.approx(1.147e-3, abs=1e-6)           # at the 1.403 K point; docs/explanation/thermometry.md
    assert np.sqrt(np.mean(differences ** 2)) == pytest.approx(0.56e-3, abs=0.01e-3)


def test_chebyshev_upper_range_agrees_with_its_table(curves):
    temperatures, resistances = x162690_table()
    curve = curves["X162690.cof"]
    low, high = curve.fit_ranges[1].lower_limit, curve.fit_ranges[1].upper_limit
    covered = (resistances >= low) & (resistances <= high)
    worst = np.abs(curve.temperature_K(resistances[covered]) - temperatures[covered]).max()
    assert covered.sum() == 27                                   # 85 to 320 K
    assert worst == pytest.approx(11.4e-3, abs=0.1e-3)           # at 220 K; docs/explanation/thermometry.md


def test_spline_through_the_table_agrees_with_the_chebyshev_fit_between_points(curves):
    """Two independent routes from X162690's data (Lake Shore's fit, our spline), 1.4 to 14.2 K."""
    low, high = curves["X162690.cof"].fit_ranges[0].lower_limit, curves["X162690.cof"].fit_ranges[0].upper_limit
    resistances = np.geomspace(low, high, 2000)
    difference = curves["X162690.dat"].temperature_K(resistances) - curves["X162690.cof"].temperature_K(resistances)
    assert np.abs(difference).max() < 1.2e-3


@pytest.mark.parametrize("name, median_limit, worst_limit", [
    ("X162690.dat", 4e-5, 4e-4), ("X100332.dat", 4e-5, 3e-4), ("X98650.txt", 6e-5, 1.4e-3),
])
def test_spline_predicts_left_out_points(curves, name, median_limit, worst_limit):
    """Leave one measured point out, interpolate it from the others: relative error in T."""
    curve = curves[name]
    temperatures, resistances = curve.temperatures_K, curve.resistances_ohm
    errors_relative = []
    for left_out in range(2, temperatures.size - 2):
        keep = np.arange(temperatures.size) != left_out
        partial = SplineTableCurve(temperatures[keep], resistances[keep], source=name)
        predicted = partial.temperature_K(resistances[left_out])
        errors_relative.append(abs(predicted - temperatures[left_out]) / temperatures[left_out])
    assert np.median(errors_relative) < median_limit
    assert max(errors_relative) < worst_limit


# ---------------------------------------------------------------------------
# sensitivity
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("name", CURVE_FILES)
def test_sensitivity_is_the_slope_of_resistance(curves, name):
    curve = curves[name]
    for low, high in curve.calibrated_temperature_ranges_K:
        for temperature in np.geomspace(low * 1.01, high * 0.99, 7):
            step = temperature * 1e-6
            slope = (curve.resistance_ohm(temperature + step) - curve.resistance_ohm(temperature - step)) / (2 * step)
            assert curve.sensitivity_ohm_per_K(temperature) == pytest.approx(slope, rel=1e-4)
            assert curve.sensitivity_ohm_per_K(temperature) < 0.0          # Cernox: negative coefficient


# ---------------------------------------------------------------------------
# out of range: refused, never extrapolated
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("name", CURVE_FILES)
def test_values_outside_the_calibration_are_refused(curves, name):
    curve = curves[name]
    (r_low, r_high), (t_low, t_high) = curve.resistance_range_ohm, curve.temperature_range_K
    assert isinstance(curve.temperature_K(r_low), float) and isinstance(curve.resistance_ohm(t_high), float)
    # rounding at the edge (10 ** log10(R) is not always R) is absorbed, not refused
    assert curve.temperature_K(r_high * (1 + 1e-13)) == curve.temperature_K(r_high)
    assert curve.resistance_ohm([t_low * (1 - 1e-13)]).tolist() == [curve.resistance_ohm(t_low)]
    for resistance in (r_low * (1 - 1e-9), r_high * (1 + 1e-9), float("nan"), -1.0):
        with pytest.raises(OutOfCalibrationRange) as caught:
            curve.temperature_K(resistance)
        assert caught.value.quantity == "resistance" and caught.value.unit == "ohm"
        assert str(caught.value).endswith(f"ohm of {curve.source}")
    for temperature in (t_low * (1 - 1e-9), t_high * (1 + 1e-9), 0.0):
        with pytest.raises(OutOfCalibrationRange, match=f"temperature .* K is outside the calibrated range"):
            curve.resistance_ohm(temperature)
        with pytest.raises(OutOfCalibrationRange):
            curve.sensitivity_ohm_per_K(temperature)


def test_array_with_values_out_of_range_names_the_first_and_counts_them(curves):
    curve = curves["X186279.340"]
    with pytest.raises(OutOfCalibrationRange) as caught:
        curve.temperature_K([1000.0, 30.0, 2000.0, 1e6])
    error = caught.value
    assert (error.value, error.count, error.calibrated_ranges) == (30.0, 2, [curve.resistance_range_ohm])
    assert "resistance 30 ohm is outside the calibrated range 67.0548 to 22373.3 ohm" in str(error)
    assert "(2 values out of range)" in str(error) and isinstance(error, ValueError)


def test_gap_between_fit_ranges_is_out_of_calibration(curves):
    curve = curves["X162690.cof"]
    assert curve.calibrated_temperature_ranges_K[0][1] == pytest.approx(14.2, abs=1e-5)
    assert curve.calibrated_temperature_ranges_K[1][0] == pytest.approx(80.1, abs=1e-3)
    with pytest.raises(OutOfCalibrationRange, match="calibrated ranges 1.4 to 14.2 and 80.1002 to 325 K") as caught:
        curve.resistance_ohm(40.0)
    assert len(caught.value.calibrated_ranges) == 2
    with pytest.raises(OutOfCalibrationRange, match="ranges 63.9896 to 231.849 and 899.154 to 21279.5 ohm"):
        curve.temperature_K(500.0)
    assert curve.temperature_K([100.0, 1000.0]).tolist() == [curve.temperature_K(100.0), curve.temperature_K(1000.0)]


# ---------------------------------------------------------------------------
# scalars and arrays
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["X186279.340", "X162690.cof", "X162690.dat"])
def test_scalar_in_float_out_array_in_array_out(curves, name):
    curve = curves[name]
    temperature = curve.temperature_K(np.float64(2000.0))
    assert type(temperature) is float and type(curve.temperature_K(2000)) is float
    assert type(curve.resistance_ohm(4)) is float and type(curve.sensitivity_ohm_per_K(4.2)) is float
    grid = np.array([[2000.0, 1500.0], [1200.0, 2000.0]])
    temperatures = curve.temperature_K(grid)
    assert isinstance(temperatures, np.ndarray) and temperatures.shape == (2, 2)
    assert temperatures[0, 0] == temperatures[1, 1] == temperature
    assert curve.resistance_ohm([4.2]).shape == (1,) and curve.sensitivity_ohm_per_K([4.2, 5.0]).shape == (2,)


def test_repr_says_what_the_curve_is(curves):
    text = repr(curves["X186279.340"])
    assert text.startswith("<BreakpointCurve X186279 (CX-1050-SD-HT-1.4L), 1.201 to 330.01 K, from ")
    assert "linear between breakpoints in (log10 ohm, T)" in text


def test_scalar_calls_are_fast_enough_for_every_reading():
    """The benchmark's own measurement (its numbers are in docs/explanation/thermometry.md), in this thread's CPU time: a
    busy machine delays the calls, it does not make them cost more."""
    specification = importlib.util.spec_from_file_location("thermometry_speed",
                                                           REPOSITORY / "benchmarks" / "thermometry_speed.py")
    benchmark = importlib.util.module_from_spec(specification)
    specification.loader.exec_module(benchmark)
    for name in ("X186279.340", "X162690.cof", "X162690.dat"):
        times_us = benchmark.scalar_call_times_us(load_calibration(CALIBRATION_DATA / name), calls=300, repeats=5,
                                                     timer=time.thread_time)
        assert max(times_us.values()) < 50.0, (name, times_us)


# ---------------------------------------------------------------------------
# one reading at a time: the breakpoint table, numpy's arithmetic to the last bit
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["X186279.340", "X207058.340"])
def test_one_reading_converts_as_numpy_interp_does_to_the_last_bit(curves, name):
    """The loop converts one float a tick through the breakpoint table; the value is exactly the one
    :func:`numpy.interp` gives (the array call), and a simulated DMM's temperature back to a resistance
    exactly what numpy gave for one numpy scalar."""
    curve = curves[name]
    random = np.random.default_rng(7)
    low, high = curve.resistance_range_ohm
    resistances = np.exp(random.uniform(np.log(low), np.log(high), 20000))
    resistances[:len(curve.breakpoint_sensor_units)] = 10.0 ** curve.breakpoint_sensor_units   # on breakpoints
    one_at_a_time = np.array([curve.temperature_K(float(r)) for r in resistances])
    assert np.array_equal(one_at_a_time, curve.temperature_K(resistances))
    temperatures = random.uniform(*curve.temperature_range_K, 20000)
    x = np.interp(np.asarray(temperatures), curve._y_increasing, curve._x_by_y)
    numpy_scalars = [float(10.0 ** np.float64(value)) for value in x]
    assert [curve.resistance_ohm(float(t)) for t in temperatures] == numpy_scalars
    assert [curve.resistance_ohm(np.float64(t)) for t in temperatures[:100]] == numpy_scalars[:100]


@pytest.mark.parametrize("name", ["X186279.340", "X207058.340"])
def test_one_reading_is_refused_or_taken_at_the_edges_as_an_array_is(curves, name):
    curve = curves[name]
    low, high = curve.resistance_range_ohm
    for value in (low, high, low * (1 - 1e-13), high * (1 + 1e-13)):
        assert curve.temperature_K(float(value)) == curve.temperature_K(np.array([value]))[0]
    for value in (low * (1 - 1e-11), high * (1 + 1e-11), float("nan"), float("inf"), 0.0, -1.0):
        with pytest.raises(OutOfCalibrationRange):
            curve.temperature_K(float(value))
    low_K, high_K = curve.temperature_range_K
    for value in (low_K * (1 - 1e-11), high_K * (1 + 1e-11), float("nan")):
        with pytest.raises(OutOfCalibrationRange):
            curve.resistance_ohm(float(value))
