"""Numbers in configuration and model files: plain decimal, or refused at their file, line and key.

YAML 1.1 (what PyYAML reads) takes ``010`` for octal 8, ``1_2`` for 12 and ``1:30`` for 90; YAML 1.2
and every person reading the file take them otherwise. A configuration that means the same to
both is one of plain decimal numbers; the other forms are refused with what each YAML would make
of them. File modes are octal by nature and keep their octal digits, quoted or not.
"""

import pytest

from cryod.config import load_config
from cryod.model import load_model
from cryod.yaml_source import FileFormatError
from tests.conftest import CONFIG
from tests.example_config import line_of, written


@pytest.mark.parametrize("written_as, reason", [
    ("010", "'010' has a leading zero: YAML 1.1 reads it as octal 8, YAML 1.2 as 10; write the number meant "
            "without the leading zero"),
    ("'010'", "'010' has a leading zero"),
    ("09", "'09' has a leading zero: YAML 1.2 reads it as 9, YAML 1.1 as text"),
    ("1_2", "'1_2' has an underscore: YAML 1.1 reads it as 12, YAML 1.2 as text; write 12"),
    ("1_2.5", "'1_2.5' has an underscore: YAML 1.1 reads it as 12.5"),
    ("1:30", "'1:30' is a base-60 number in YAML 1.1 (90) and text in YAML 1.2; write 90"),
    ("0xC", "'0xC' is hexadecimal: write it as plain decimal digits (12)"),
    ("0o14", "'0o14' is octal: write it as plain decimal digits (12)"),
    ("0b1100", "'0b1100' is binary: write it as plain decimal digits (12)"),
])
def test_numbers_yaml_versions_read_differently_are_refused_naming_the_key(tmp_path, written_as, reason):
    path, text = written(tmp_path, "  setpoint_K: 5.0", f"  setpoint_K: {written_as}")
    with pytest.raises(FileFormatError) as caught:
        load_config(path)
    error = caught.value
    assert (error.source, error.line, error.key) == (str(path), line_of(text, "setpoint_K:"), "control.setpoint_K")
    assert error.reason == f"must be a number: {reason}" or reason in error.reason, error.reason


@pytest.mark.parametrize("written_as, value", [("12", 12.0), ("12.0", 12.0), ("012.5", 12.5), (".5e1", 5.0),
                                              ("12e0", 12.0), ("+12", 12.0), ('"12"', 12.0)])
def test_plain_decimal_numbers_are_taken(tmp_path, written_as, value):
    path, _ = written(tmp_path, "  setpoint_K: 5.0", f"  setpoint_K: {written_as}")
    assert load_config(path).control.setpoint_K == value


def test_a_whole_number_with_a_leading_zero_is_refused_where_a_count_is_asked_for(tmp_path):
    path, text = written(tmp_path, "  seed: 0 ", "  seed: 010 ")
    with pytest.raises(FileFormatError, match="simulation.seed: must be a number: '010' has a leading zero"):
        load_config(path)


@pytest.mark.parametrize("written_as", ['"0660"', "0660", "660", '"0o660"', "0o660", '"660"'])
def test_a_socket_mode_keeps_its_octal_digits_however_it_is_written(tmp_path, written_as):
    path, _ = written(tmp_path, '  mode: "0660"', f"  mode: {written_as}")
    assert load_config(path).control_socket.mode == 0o660


@pytest.mark.parametrize("written_as", ["0680", "1_0", "0x1B0", "432"])
def test_a_socket_mode_that_is_not_octal_digits_is_refused(tmp_path, written_as):
    """``432`` is 0o660 as a decimal integer, and as octal digits 4, 3, 2 a mode that opens the socket to
    others (r---wx-w-): refused either way, never read as 0o660."""
    path, _ = written(tmp_path, '  mode: "0660"', f"  mode: {written_as}")
    with pytest.raises(FileFormatError) as caught:
        load_config(path)
    assert caught.value.key == "control_socket.mode"


def test_a_model_file_number_in_a_yaml_1_1_form_is_refused_naming_the_key(tmp_path):
    text = (CONFIG / "model.yaml").read_text()
    path = tmp_path / "model.yaml"
    path.write_text(text.replace("numerator: [2.77]", "numerator: [2_77]"))
    with pytest.raises(FileFormatError) as caught:
        load_model(path)
    error = caught.value
    assert error.line == line_of(text, "numerator: [2.77]")
    assert "heater_to_ptc_stage.numerator" in error.key and "'2_77' has an underscore" in error.reason
