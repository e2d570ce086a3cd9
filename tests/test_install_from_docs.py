"""docs/how-to/install.md's install steps, run as written in a scratch root (slow: a fresh venv and pip).

Each command of the first code block runs with /opt, /etc and /usr/local moved under a temporary
directory; the steps that change the host's users or services (useradd, usermod) are left out, and
the sensors' calibration files are the shipped ones. Then the installed ``cryod`` is used the way
the page goes on: ``--check`` on the installed configuration, ``--help`` from the PATH link, and
the unit file verified with systemd-analyze where it is installed.
"""

import os
import re
import shutil
import subprocess

import pytest

from tests.conftest import CONFIG, REPOSITORY

pytestmark = pytest.mark.slow


def install_commands() -> list[str]:
    text = (REPOSITORY / "docs" / "how-to" / "install.md").read_text()
    block = re.search(r"# Install the service.*?```sh\n(.*?)```", text, re.S).group(1)
    return [line.split("  #")[0].strip() for line in block.splitlines() if line.strip()]


def test_the_install_steps_work_as_written(tmp_path):
    root = tmp_path / "root"
    for folder in ("opt", "etc/systemd/system", "usr/local/bin"):
        (root / folder).mkdir(parents=True)
    ran = []
    for command in install_commands():
        if command.startswith(("sudo useradd", "sudo usermod")):
            continue                                          # the host's users: not in a test
        command = command.removeprefix("sudo ")
        for prefix in ("/opt/", "/etc/", "/usr/local/"):
            command = command.replace(prefix, f"{root}{prefix}")
        command = command.replace("/path/to/your/sensors/*.340", str(CONFIG / "calibration" / "*.340"))
        result = subprocess.run(command, shell=True, cwd=REPOSITORY, capture_output=True, text=True, timeout=600)
        assert result.returncode == 0, f"{command}\n{result.stderr[-3000:]}"
        ran.append(command)
    assert len(ran) >= 7
    cryod = root / "usr/local/bin/cryod"
    assert subprocess.run([cryod, "--help"], capture_output=True, text=True).returncode == 0
    config = root / "etc/cryod/cryod.yaml"
    # what the operator edits next (docs: "Edit /etc/cryod/cryod.yaml"): here, instruments behind a LAN gateway
    config.write_text(config.read_text().replace("GPIB0::16::INSTR", "TCPIP0::10.0.0.2::1234::SOCKET")
                      .replace("GPIB0::17::INSTR", "TCPIP0::10.0.0.3::1234::SOCKET")
                      .replace("GPIB0::12::INSTR", "TCPIP0::10.0.0.4::1234::SOCKET")
                      .replace("trigger: gpib-group", "trigger: sequential"))
    check = subprocess.run([cryod, "run", "--config", config, "--check"], capture_output=True, text=True,
                           env=dict(os.environ, PYTHONPATH=""))
    assert check.returncode == 0 and "valid" in check.stdout, check.stderr
    assert (root / "opt/cryod/docs/index.md").exists()                  # where Documentation= points
    unit = root / "etc/systemd/system/cryod.service"
    analyze = shutil.which("systemd-analyze")
    if analyze:
        unit.write_text(unit.read_text().replace("/opt/cryod/venv/bin/cryod", str(cryod)))
        verified = subprocess.run([analyze, "verify", unit], capture_output=True, text=True)
        assert verified.returncode == 0 and "cryod" not in verified.stderr, verified.stderr
