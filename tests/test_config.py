"""The daemon configuration: every error names file, line and key; nothing runs on a bad file."""

import dataclasses
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from cryod.config import load_config
from cryod.control.pi import PiGains
from cryod.yaml_source import FileFormatError
from tests.conftest import CONFIG, REPOSITORY
from tests.example_config import EXAMPLE, line_of, written


def test_example_config_is_valid_and_complete():
    config = load_config(CONFIG / "cryod.yaml")
    assert config.loop.period_s == 0.08 and config.heater.max_current_A == 0.1
    assert config.heater.max_power_w == pytest.approx(0.5)
    assert config.sensors.flange_calibration.name == "X186279.340"
    assert config.control_socket.mode == 0o660 and config.simulation.transport == "tcp"


@pytest.mark.parametrize("old, new, key, reason", [
    ("  period_s: 0.08", "  period_s: 0.08\n  perod_s: 0.08", "loop.perod_s", "unknown key"),
    ("  resistance_ohm: 50.0", "  resistance_ohm: fifty", "heater.resistance_ohm", "must be a number"),
    ("  max_current_A: 0.1", "  max_current_A: 0.2", "heater.max_current_A", "at most 0.105"),
    ("    calibration: calibration/X186279.340", "    calibration: calibration/missing.340",
     "sensors.flange.calibration", "file not found"),
    ("  setpoint_K: 5.0", "  setpoint_K: 30.0", "control.setpoint_K", "outside 3..20 K"),
    ("  setpoint_max_K: 20.0", "  setpoint_max_K: 26.0", "control.setpoint_max_K", "over-temperature limit"),
    ("  trigger: gpib-group", "  trigger: smoke-signal", "instruments.trigger", "must be one of"),
    ("    nplc: 1 ", "    nplc: 3 ", "instruments.dmm.nplc", "leaves no time"),
    ("  voltage_compliance_V: 10.0", "  voltage_compliance_V: 2.0", "heater.voltage_compliance_V",
     "cannot drive"),
    ('  mode: "0660"', '  mode: "rw-rw----"', "control_socket.mode", "octal"),
    ("  lock_memory: true", "  lock_memory: yes please", "loop.lock_memory", "true or false"),
    ("    proportional_W_per_K: 10.0", "    proportional_W_per_K: -1", "control.pi.proportional_W_per_K", "at least 0"),
    ("    integral_W_per_K_s: 0.2 ", "    integral_W_per_K_s: 0.2\n    derivative: 1 ", "control.pi.derivative",
     "unknown key"),
    ("  max_ramp_K_per_min: 10.0", "  max_ramp_K_per_min: 10.0\n  proportional_W_per_K: 10.0",
     "control.proportional_W_per_K", "give it as control.pi.proportional_W_per_K"),
])
def test_errors_name_file_line_and_key(tmp_path, old, new, key, reason):
    path, text = written(tmp_path, old, new)
    with pytest.raises(FileFormatError) as caught:
        load_config(path)
    error = caught.value
    assert error.source == str(path) and error.key == key, str(error)
    assert reason in error.reason
    assert error.line == line_of(text, key.split(".")[-1].split("[")[0] + ":"), str(error)


def test_missing_section_is_named(tmp_path):
    text = EXAMPLE.replace("calibration: calibration/", f"calibration: {CONFIG}/calibration/")
    start = text.index("heater:\n  resistance_ohm")
    end = text.index("control:\n")
    path = tmp_path / "cryod.yaml"
    path.write_text(text[:start] + text[end:])
    with pytest.raises(FileFormatError, match="heater: missing required key"):
        load_config(path)


def test_restart_needed_for_lists_sections_that_cannot_reload():
    config = load_config(CONFIG / "cryod.yaml")
    gains = dataclasses.replace(config, control=dataclasses.replace(config.control, terms=(("pi", PiGains(1.0, 0.2)),)))
    assert config.restart_needed_for(gains) == []
    moved = dataclasses.replace(config, heater=dataclasses.replace(config.heater, resistance_ohm=25.0))
    assert config.restart_needed_for(moved) == ["heater"]


def test_bad_config_stops_run_before_any_instrument(tmp_path):
    path, _ = written(tmp_path, "  resistance_ohm: 50.0", "  resistance_ohm: -5")
    result = subprocess.run([sys.executable, "-m", "cryod.cli", "run", "--config", str(path)],
                            capture_output=True, text=True, cwd=REPOSITORY, timeout=60)
    assert result.returncode == 2
    assert "nothing was started" in result.stderr and "heater.resistance_ohm" in result.stderr
    assert f"{path}:" in result.stderr


def test_a_control_term_section_that_is_required_is_named(tmp_path):
    start = EXAMPLE.index("  pi:")
    end = EXAMPLE.index("safety:")
    path = tmp_path / "cryod.yaml"
    path.write_text(EXAMPLE.replace("calibration: calibration/", f"calibration: {CONFIG}/calibration/")
                    .replace(EXAMPLE[start:end], "\n"))
    with pytest.raises(FileFormatError, match="control.pi: missing required key"):
        load_config(path)


# -- the web page and the Lake Shore 336 command set ---------------------------------------------
def _with(tmp_path, text: str) -> Path:
    source = (CONFIG / "cryod.yaml").read_text().replace("calibration: calibration/",
                                                          f"calibration: {CONFIG}/calibration/")
    source = re.sub(r"(?m)^(web|lakeshore336): null.*$", "", source)
    path = tmp_path / "cryod.yaml"
    path.write_text(source + "\n" + text)
    return path


def test_web_and_lakeshore336_are_off_in_the_example_and_read_when_given(tmp_path):
    example = load_config(CONFIG / "cryod.yaml")
    assert example.web is None and example.lakeshore336 is None
    text = (CONFIG / "cryod.yaml").read_text()
    for line in ('#   address: "127.0.0.1:8336"', '#   address: "127.0.0.1:7777"', "#   writable: false"):
        assert line in text                                     # the lines that turn them on
    token = tmp_path / "web.token"
    token.write_text("0123456789abcdef0123456789abcdef\n")
    token.chmod(0o640)
    config = load_config(_with(tmp_path, f'web: {{address: "0.0.0.0:8336", writable: true, token_file: {token}}}\n'
                                         'lakeshore336: {address: "127.0.0.1:7777"}\n'))
    assert (config.web.address, config.web.writable, config.web.token_file) == ("0.0.0.0:8336", True, token)
    assert (config.lakeshore336.address, config.lakeshore336.writable) == ("127.0.0.1:7777", False)


@pytest.mark.parametrize("text, message", [
    ('web: {address: ":8336"}', "web.address: ':8336' is not host:port"),
    ('web: {address: "labpc:8336"}', "the host must be an IP address"),
    ('lakeshore336: {address: "127.0.0.1:77777"}', "lakeshore336.address: '127.0.0.1:77777': the port"),
    ('lakeshore336: {address: "127.0.0.1:7777", writeable: true}', "lakeshore336.writeable"),
    ('web: {address: "127.0.0.1:8336", writable: true}', "web.writable: control from the page needs web.token_file"),
])
def test_web_and_lakeshore336_refusals_name_the_key(tmp_path, text, message):
    with pytest.raises(FileFormatError, match=re.escape(message)):
        load_config(_with(tmp_path, text + "\n"))


def test_a_token_file_others_may_read_or_without_a_token_is_refused(tmp_path):
    token = tmp_path / "web.token"
    token.write_text("0123456789abcdef0123456789abcdef\n")
    token.chmod(0o644)
    with pytest.raises(FileFormatError, match="mode 0644: every user of this computer could read the token"):
        load_config(_with(tmp_path, f'web: {{address: "127.0.0.1:8336", writable: true, token_file: {token}}}\n'))
    token.chmod(0o600)
    token.write_text("short\n")
    with pytest.raises(FileFormatError, match="holds no usable token"):
        load_config(_with(tmp_path, f'web: {{address: "127.0.0.1:8336", writable: true, token_file: {token}}}\n'))


def test_the_token_file_is_checked_at_every_read_and_nothing_but_a_bounded_regular_file_is_read(tmp_path):
    """What the web page reads at each write: a FIFO (which would hold the reader until a writer came), a device
    (/dev/zero never ends), a file of another user and a file grown beyond the bound are refused at once."""
    import time
    from cryod.web_token import MAX_TOKEN_FILE_BYTES, read_token

    token = tmp_path / "web.token"
    token.write_text("0123456789abcdef0123456789abcdef\n")
    token.chmod(0o640)
    assert read_token(token) == "0123456789abcdef0123456789abcdef"
    token.unlink()
    os.mkfifo(token, 0o640)
    started = time.monotonic()
    with pytest.raises(ValueError, match="is a FIFO .* regular file only"):
        read_token(token)
    assert time.monotonic() - started < 1.0
    token.unlink()
    token.symlink_to("/dev/zero")
    with pytest.raises(ValueError, match="is a character device"):
        read_token(token)
    token.unlink()
    token.write_text("0123456789abcdef0123456789abcdef\n" + "#" * MAX_TOKEN_FILE_BYTES)
    token.chmod(0o640)
    with pytest.raises(ValueError, match="bytes: a token file holds one line"):
        read_token(token)
    token.write_text("0123456789abcdef0123456789abcdef\n")
    if os.geteuid() == 0:                         # only root can give a file away
        os.chown(token, 65534, 65534)
        with pytest.raises(ValueError, match="belongs to uid 65534, not to this service's user"):
            read_token(token)
