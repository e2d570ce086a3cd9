"""Hostile and inconsistent configurations: a clear error naming file, line and key, never a traceback.

The cases: values Python cannot convert, keys that are lists, anchors that expand exponentially,
modes that open the heater to every user, values that must not pass silently, limits that
contradict each other or the sensors' calibration curves, and messages that must name the right
key.
"""

import time

import pytest

from cryod.config import MAX_RAMP_K_PER_MIN, load_config
from cryod.yaml_source import ALIAS_NODE_BUDGET, MAX_REASON_CHARS, FileFormatError
from tests.conftest import CALIBRATION_DATA, CONFIG
from tests.example_config import line_of, written

#: No error message quotes more than this of what the file holds (reason plus location).
MESSAGE_CHARS = MAX_REASON_CHARS + 500


def refused(path):
    with pytest.raises(FileFormatError) as caught:
        load_config(path)
    error = caught.value
    assert len(str(error)) < MESSAGE_CHARS, str(error)[:300]
    return error


def laughs(levels, name="lol"):
    """A billion-laughs mapping in flow style: ``levels`` anchors, each nine aliases of the one before."""
    items = [f"a0: &a0 [{', '.join([name] * 9)}]"]
    for level in range(1, levels):
        items.append(f"a{level}: &a{level} [{', '.join([f'*a{level - 1}'] * 9)}]")
    return "{" + ", ".join(items) + "}"


# ---------------------------------------------------------------------------
# values and keys Python cannot take as they are
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("old, new, key, reason", [
    ("  resistance_ohm: 50.0", "  resistance_ohm: " + "9" * 400, "heater.resistance_ohm",
     "an integer of 400 digits"),
    ("  resistance_ohm: 50.0", "  resistance_ohm: " + "9" * 5000, "heater.resistance_ohm",
     "an integer of 5000 digits is not a usable number"),
    ("  resistance_ohm: 50.0", "  resistance_ohm: 2024-13-45", "heater.resistance_ohm",
     "not a valid timestamp: month must be in 1..12"),
    ("  resistance_ohm: 50.0", "  resistance_ohm: !!float fifty", "heater.resistance_ohm",
     "'fifty' is not a valid float"),
])
def test_values_python_cannot_convert_are_named(tmp_path, old, new, key, reason):
    path, text = written(tmp_path, old, new)
    error = refused(path)
    assert error.key == key and reason in error.reason, str(error)
    assert error.line == line_of(text, "resistance_ohm:") and error.source == str(path)


@pytest.mark.parametrize("key_text, kind", [("[a, b]", "list"), ("{a: 1}", "mapping")])
def test_a_list_or_mapping_as_a_key_is_named(tmp_path, key_text, kind):
    path, text = written(tmp_path, "  resistance_ohm: 50.0", f"  resistance_ohm: 50.0\n  ? {key_text}\n  : 1")
    error = refused(path)
    assert error.key == "heater" and f"a key must be a name, not a {kind}" in error.reason
    assert error.line == line_of(text, f"? {key_text}")


def test_what_an_error_quotes_is_short(tmp_path):
    long_text = "gpib-" * 20000                                     # 100 kB in one value
    path, _ = written(tmp_path, "  trigger: gpib-group", f"  trigger: {long_text}")
    error = refused(path)
    assert error.key == "instruments.trigger" and "must be one of" in error.reason
    assert len(str(error)) < 400
    path, _ = written(tmp_path, "  resistance_ohm: 50.0", f"  resistance_ohm: {laughs(3)}")
    error = refused(path)                                           # 819 values shared by aliases: 729 shown
    assert error.key == "heater.resistance_ohm" and "must be a number, got mapping {'a0': [" in error.reason
    assert len(str(error)) < 400


def test_exponential_aliases_are_refused_before_anything_is_built(tmp_path):
    """Nine levels of nine aliases: 387 million values if built, 2.25 GB and 30 s to quote in a message
    before; refused while the file is read, at the alias that passes the budget."""
    path, text = written(tmp_path, "  resistance_ohm: 50.0", f"  resistance_ohm: {laughs(9)}")
    started = time.perf_counter()
    error = refused(path)
    assert time.perf_counter() - started < 2.0
    assert error.line == line_of(text, "resistance_ohm:")
    # the aliases of a1 add 9 x 10 values, those of a2 9 x 91: the first alias of a3 adds 820 more
    assert error.key == "heater.resistance_ohm.a3[0]"
    assert "the alias *a2" in error.reason and f"more than {ALIAS_NODE_BUDGET} values" in error.reason


@pytest.mark.parametrize("value, key, reason", [
    ("&loop [1, *loop]", "heater.resistance_ohm[1]", "the alias *loop is inside its own anchor &loop"),
    ("&loop {again: *loop}", "heater.resistance_ohm.again", "the alias *loop is inside its own anchor &loop"),
    ("[" * 1000 + "]" * 1000, "heater.resistance_ohm" + "[0]" * 30, "nested more than 32 levels deep"),
])
def test_recursive_aliases_and_deep_nesting_are_refused(tmp_path, value, key, reason):
    path, _ = written(tmp_path, "  resistance_ohm: 50.0", f"  resistance_ohm: {value}")
    error = refused(path)
    assert error.key == key and reason in error.reason, str(error)


def test_a_file_too_large_for_a_configuration_is_refused(tmp_path):
    path, _ = written(tmp_path, "format: cryod-config v1", "format: cryod-config v1\n" + "#" * 2_000_000)
    error = refused(path)
    assert error.line is None and "larger than 1000000 bytes" in error.reason


# ---------------------------------------------------------------------------
# merge keys are YAML, a key given twice is not
# ---------------------------------------------------------------------------
SHARED_ADAPTER = """  flange_dmm:                     # Keithley 2002 on the flange Cernox (T2)
    resource: GPIB0::16::INSTR
  ptc_stage_dmm:                  # Keithley 2002 on the PTC second-stage Cernox (T5)
    resource: GPIB0::17::INSTR"""


def test_a_merge_key_takes_the_mappings_own_keys_as_overrides(tmp_path):
    path, _ = written(tmp_path, SHARED_ADAPTER, """  flange_dmm:
    prologix: &adapter {port: /dev/ttyUSB0, address: 16}
  ptc_stage_dmm:
    prologix:
      <<: *adapter
      address: 17""")
    path.write_text(path.read_text().replace("trigger: gpib-group", "trigger: prologix"))   # both DMMs on the adapter
    config = load_config(path)
    assert config.instruments.flange_dmm.gpib_address == 16
    assert config.instruments.ptc_stage_dmm.gpib_address == 17
    assert config.instruments.ptc_stage_dmm.prologix_port == "/dev/ttyUSB0"


def test_a_key_given_twice_after_a_merge_is_still_refused_with_its_path(tmp_path):
    path, text = written(tmp_path, SHARED_ADAPTER, """  flange_dmm:
    prologix: &adapter {port: /dev/ttyUSB0, address: 16}
  ptc_stage_dmm:
    prologix:
      <<: *adapter
      address: 17
      address: 18""")
    error = refused(path)
    assert error.key == "instruments.ptc_stage_dmm.prologix.address" and error.reason == "key given twice"
    assert error.line == line_of(text, "address: 18")


# ---------------------------------------------------------------------------
# values that would otherwise pass silently and do harm later
# ---------------------------------------------------------------------------
def test_a_control_socket_mode_open_to_others_is_refused_and_owner_and_group_modes_are_not(tmp_path):
    for mode in ['"0777"', '"0666"', '"0664"', '"0662"', '"0661"', "0777", '"0o606"']:
        path, text = written(tmp_path, '  mode: "0660"', f"  mode: {mode}")
        error = refused(path)
        assert error.key == "control_socket.mode" and "every user of this computer" in error.reason, mode
        assert error.line == line_of(text, "  mode:")
    for mode, expected in [('"0660"', 0o660), ('"0600"', 0o600), ('"0640"', 0o640), ("0770", 0o770)]:
        path, _ = written(tmp_path, '  mode: "0660"', f"  mode: {mode}")
        assert load_config(path).control_socket.mode == expected


def test_a_ramp_limit_no_flange_can_follow_is_refused(tmp_path):
    for rate in ["1e300", "101", "6000"]:
        path, _ = written(tmp_path, "  max_ramp_K_per_min: 10.0", f"  max_ramp_K_per_min: {rate}")
        error = refused(path)
        assert error.key == "control.max_ramp_K_per_min", rate
        assert f"at most {MAX_RAMP_K_PER_MIN:g} K/min" in error.reason
    path, _ = written(tmp_path, "  max_ramp_K_per_min: 10.0", f"  max_ramp_K_per_min: {MAX_RAMP_K_PER_MIN}")
    assert load_config(path).control.max_ramp_K_per_min == MAX_RAMP_K_PER_MIN


@pytest.mark.parametrize("old, new, key", [
    ("  directory: /var/lib/cryod", '  directory: ""', "data.directory"),
    ("  directory: /var/lib/cryod", '  directory: "   "', "data.directory"),
    ("  path: /run/cryod/control.sock", '  path: ""', "control_socket.path"),
])
def test_an_empty_path_is_refused(tmp_path, old, new, key):
    path, _ = written(tmp_path, old, new)
    error = refused(path)
    assert error.key == key and "is empty" in error.reason


# ---------------------------------------------------------------------------
# limits against each other and the calibration curves
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("old, new, key, reason", [
    # T5 can never read below 1.2 K: every reading would be above the limit
    ("  ptc_stage_max_K: 15.0", "  ptc_stage_max_K: 0.5", "safety.ptc_stage_max_K",
     "at or below the lowest temperature the PTC-stage thermometer can read (1.2 K)"),
    ("  ptc_stage_max_K: 15.0", "  ptc_stage_max_K: 1.2", "safety.ptc_stage_max_K", "held off for good"),
    ("  ptc_stage_max_K: 15.0", "  ptc_stage_max_K: 350", "safety.ptc_stage_max_K",
     "outside the PTC-stage thermometer's calibration"),
    ("  setpoint_min_K: 3.0", "  setpoint_min_K: 0.5", "control.setpoint_min_K",
     "outside the flange thermometer's calibration"),
    ("  flange_max_K: 25.0", "  flange_max_K: 350.0", "safety.flange_max_K",
     "T2 could never be read at this limit"),
])
def test_limits_outside_the_calibration_curves_are_refused(tmp_path, old, new, key, reason):
    path, text = written(tmp_path, old, new)
    error = refused(path)
    assert error.key == key and reason in error.reason, str(error)
    assert error.line == line_of(text, new.strip().split(":")[0] + ":")
    assert "covers 1.2" in error.reason            # the curve's range, to act on


def test_a_gap_in_the_flange_calibration_inside_the_setpoint_range_is_refused(tmp_path):
    gapped = CALIBRATION_DATA / "X162690.cof"      # fit ranges 1.4..14.2 K and 80.1..325 K
    path, text = written(tmp_path, "    calibration: calibration/X186279.340", f"    calibration: {gapped}")
    path.write_text(text.replace("  flange_max_K: 25.0", "  flange_max_K: 90.0"))
    error = refused(path)
    assert error.key == "control.setpoint_max_K" and "has a gap" in error.reason
    assert "1.4..14.2 K and 80.1..325 K" in error.reason
    narrowed = text.replace("  setpoint_max_K: 20.0", "  setpoint_max_K: 12.0").replace(
        "  flange_max_K: 25.0", "  flange_max_K: 14.0")
    path.write_text(narrowed)
    assert load_config(path).safety.flange_max_K == 14.0


def test_the_limits_are_checked_on_reload_too(tmp_path):
    """A reload reads the file with the same checks: the PTC-stage limit of 0.5 K is refused."""
    path, text = written(tmp_path, "  ptc_stage_max_K: 15.0", "  ptc_stage_max_K: 15.0")
    running = load_config(path)
    path.write_text(text.replace("  ptc_stage_max_K: 15.0", "  ptc_stage_max_K: 0.5"))
    with pytest.raises(FileFormatError, match="safety.ptc_stage_max_K"):
        load_config(running.source)


# ---------------------------------------------------------------------------
# messages that name the right thing
# ---------------------------------------------------------------------------
def test_a_calibration_path_that_is_a_directory_says_so(tmp_path):
    path, text = written(tmp_path, "    calibration: calibration/X186279.340", f"    calibration: {tmp_path}")
    error = refused(path)
    assert error.key == "sensors.flange.calibration" and error.reason == f"is a directory, not a file: {tmp_path}"
    assert error.line == line_of(text, f"calibration: {tmp_path}")


def test_a_calibration_file_that_is_not_a_curve_is_named_with_its_key(tmp_path):
    path, _ = written(tmp_path, "    calibration: calibration/X207058.340", f"    calibration: {CONFIG / 'model.yaml'}")
    error = refused(path)
    assert error.key == "sensors.ptc_stage.calibration" and "calibration not usable" in error.reason


@pytest.mark.parametrize("inside", [False, True])
def test_a_data_directory_that_is_a_file_is_refused_at_load_naming_its_key(tmp_path, inside):
    occupied = tmp_path / "occupied"
    occupied.write_text("a file")
    directory = occupied / "data" if inside else occupied
    path, text = written(tmp_path, "  directory: /var/lib/cryod", f"  directory: {directory}")
    error = refused(path)
    assert error.key == "data.directory" and error.line == line_of(text, f"directory: {directory}")
    assert f"{occupied}, which is a file" in error.reason if inside else "is a file, not a directory" in error.reason


def test_a_sensor_without_its_calibration_is_refused(tmp_path):
    """``flange: {}`` is a sensor without its calibration, refused at load (not a TypeError when the daemon starts)."""
    path, text = written(tmp_path, "    calibration: calibration/X186279.340       # .340, .cof, or a raw R-T table",
                         "    {}")
    path.write_text(text.replace("  flange:\n    {}", "  flange: {}"))
    error = refused(path)
    assert error.key == "sensors.flange.calibration" and error.reason == "missing required key"
    assert error.line == line_of(text, "flange:")
