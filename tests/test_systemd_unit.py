"""The unit file: systemd-analyze verify passes, and it asks for what the daemon relies on."""

import configparser
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPOSITORY

UNIT = REPOSITORY / "systemd" / "cryod.service"


def unit_sections() -> configparser.ConfigParser:
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str
    parser.read_string(UNIT.read_text())
    return parser


def test_unit_settings_the_daemon_relies_on():
    service = unit_sections()["Service"]
    assert service["Type"] == "notify"
    assert "cryod run --config" in service["ExecStart"]
    assert service["ExecReload"] == "/bin/kill -HUP $MAINPID"
    assert int(service["WatchdogSec"]) >= 5
    assert service["Restart"] == "on-failure" and service["RestartPreventExitStatus"].split() == ["2", "7"]
    assert service["RuntimeDirectory"] == "cryod" and service["StateDirectory"] == "cryod"
    assert service["DevicePolicy"] == "closed" and "dialout" in service["SupplementaryGroups"]
    assert service["NoNewPrivileges"] == "yes" and service["ProtectSystem"] == "strict"


def test_systemd_analyze_verify_passes(tmp_path):
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        if os.environ.get("CRYOD_REQUIRE_SYSTEMD_ANALYZE"):
            pytest.fail("systemd-analyze is not installed (CI installs it)")
        pytest.skip("systemd-analyze not installed")
    # verify checks that ExecStart exists: point it at this environment's cryod
    executable = Path(sys.executable).parent / "cryod"
    if not executable.exists():
        executable = Path(shutil.which("true"))
    unit = tmp_path / "cryod.service"
    unit.write_text(UNIT.read_text().replace("/opt/cryod/venv/bin/cryod", str(executable)))
    result = subprocess.run([analyze, "verify", str(unit)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr + result.stdout
    assert "cryod.service" not in result.stderr, result.stderr
