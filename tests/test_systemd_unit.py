"""The unit file: systemd-analyze verify passes, and it asks for what the daemon relies on."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.systemd_units import IOC_UNIT, TEMPLATE, UNIT, unit_sections


@pytest.mark.parametrize("unit, directory", [(UNIT, "cryod"), (TEMPLATE, "cryod/%i")])
def test_unit_settings_the_daemon_relies_on(unit, directory):
    service = unit_sections(unit)["Service"]
    assert service["Type"] == "notify"
    assert "cryod run --config /etc/cryod/" + ("%i" if unit == TEMPLATE else "cryod") + ".yaml" in service["ExecStart"]
    assert service["ExecReload"] == "/bin/kill -HUP $MAINPID"
    # after any end (SIGKILL, a crash) the supply is switched off by a process of its own
    assert service["ExecStopPost"] == service["ExecStart"].replace("/opt/", "-/opt/", 1) + " --supply-off"
    assert int(service["WatchdogSec"]) >= 5
    assert service["Restart"] == "on-failure" and service["RestartPreventExitStatus"].split() == ["2", "7"]
    assert service["RuntimeDirectory"] == directory and service["StateDirectory"] == directory
    documentation = unit_sections(unit)["Unit"]["Documentation"]
    assert documentation == "file:/opt/cryod/docs/index.md"      # where docs/how-to/install.md copies the docs
    assert service["DevicePolicy"] == "closed" and "dialout" in service["SupplementaryGroups"]
    assert service["NoNewPrivileges"] == "yes" and service["ProtectSystem"] == "strict"
    # the instrument locks' directory, shared by every unit, made before the start and writable in the sandbox
    assert service["ExecStartPre"].startswith("+/usr/bin/install -d -o cryod -g cryod")
    assert service["ExecStartPre"].endswith(" /run/lock/cryod") and service["ReadWritePaths"] == "/run/lock/cryod"


@pytest.mark.system
@pytest.mark.parametrize("unit, name", [(UNIT, "cryod.service"), (TEMPLATE, "cryod@k2-flange.service")])
def test_systemd_analyze_verify_passes(tmp_path, unit, name):
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        if os.environ.get("CRYOD_REQUIRE_SYSTEMD_ANALYZE"):
            pytest.fail("systemd-analyze is not installed (CI installs it)")
        pytest.skip("systemd-analyze not installed")
    # verify checks that ExecStart exists: point it at this environment's cryod
    executable = Path(sys.executable).parent / "cryod"
    if not executable.exists():
        executable = Path(shutil.which("true"))
    if unit == TEMPLATE:          # verify takes an instance of a template beside the template file
        (tmp_path / TEMPLATE.name).write_text(TEMPLATE.read_text().replace("/opt/cryod/venv/bin/cryod",
                                                                           str(executable)))
    else:
        (tmp_path / name).write_text(UNIT.read_text().replace("/opt/cryod/venv/bin/cryod", str(executable)))
    result = subprocess.run([analyze, "verify", str(tmp_path / name)], capture_output=True, text=True, timeout=60,
                            cwd=tmp_path)
    assert result.returncode == 0, result.stderr + result.stdout
    assert "cryod" not in result.stderr, result.stderr


def test_the_ioc_unit_starts_after_the_daemon_and_again_after_a_failure():
    unit = unit_sections(IOC_UNIT)
    assert "cryod.service" in unit["Unit"]["After"].split()
    service = unit["Service"]
    assert service["ExecStart"] == "/opt/cryod/venv/bin/cryod ioc --config /etc/cryod/cryod.yaml"
    assert service["Restart"] == "on-failure" and service["RestartPreventExitStatus"].split() == ["2"]
    assert service["User"] == "cryod"          # the daemon's user: the only one whose relays it takes
    assert service["NoNewPrivileges"] == "yes" and service["ProtectSystem"] == "strict"


def test_systemd_analyze_verify_passes_for_the_ioc_unit(tmp_path):
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        if os.environ.get("CRYOD_REQUIRE_SYSTEMD_ANALYZE"):
            pytest.fail("systemd-analyze is not installed (CI installs it)")
        pytest.skip("systemd-analyze not installed")
    executable = Path(sys.executable).parent / "cryod"
    (tmp_path / IOC_UNIT.name).write_text(IOC_UNIT.read_text().replace("/opt/cryod/venv/bin/cryod", str(executable)))
    result = subprocess.run([analyze, "verify", str(tmp_path / IOC_UNIT.name)], capture_output=True, text=True,
                            timeout=60, cwd=tmp_path)
    assert result.returncode == 0, result.stderr + result.stdout
    assert "cryod" not in result.stderr, result.stderr
