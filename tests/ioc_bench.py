"""``cryod ioc`` beside a dry run, on loopback and on free ports, for the EPICS tests and the benchmark.

Channel Access and pvAccess find servers by UDP broadcast and talk over TCP, on ports every IOC on
the network shares by default; the tests give both to 127.0.0.1 only (``EPICS_CA_ADDR_LIST``,
``EPICS_CA_AUTO_ADDR_LIST=NO``, ``EPICS_CAS_INTF_ADDR_LIST`` and their pvAccess twins) on ports
free when this module is imported, so that test runs side by side do not find each other's IOCs.
The same variables go into this process's environment (pyepics and p4p read them when their first
context is made) and into the IOC's.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from tests.conftest import CONFIG, REPOSITORY


def _free_port() -> int:
    """A port free for both TCP and UDP on 127.0.0.1 now."""
    while True:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as tcp:
            tcp.bind(("127.0.0.1", 0))
            port = tcp.getsockname()[1]
            try:
                with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
                    udp.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port


def _environment() -> dict[str, str]:
    ca, repeater, pva, broadcast = (_free_port() for _ in range(4))
    return {"EPICS_CA_ADDR_LIST": "127.0.0.1", "EPICS_CA_AUTO_ADDR_LIST": "NO",
            "EPICS_CAS_INTF_ADDR_LIST": "127.0.0.1", "EPICS_CA_SERVER_PORT": str(ca),
            "EPICS_CA_REPEATER_PORT": str(repeater),
            "EPICS_PVA_ADDR_LIST": "127.0.0.1", "EPICS_PVA_AUTO_ADDR_LIST": "NO",
            "EPICS_PVAS_INTF_ADDR_LIST": "127.0.0.1", "EPICS_PVA_SERVER_PORT": str(pva),
            "EPICS_PVAS_SERVER_PORT": str(pva), "EPICS_PVA_BROADCAST_PORT": str(broadcast),
            "EPICS_PVAS_BROADCAST_PORT": str(broadcast)}


#: This test process's EPICS environment (one set of ports for all its IOCs: pyepics keeps its first context).
EPICS_ENVIRONMENT = _environment()
os.environ.update(EPICS_ENVIRONMENT)

#: The IOC's settings in the tests: a STABLE that a dry run at --speed 10 reaches in seconds.
IOC_SECTION = 'ioc: {{prefix: "{prefix}", writable: {writable}, stable_tolerance_K: 5.0e-4, stable_hold_s: 5}}'


def ioc_lab_config(folder: Path, prefix: str = "CRYOTEST:", writable: bool = True, alarms: str = "",
                   **replacements: str) -> Path:
    """The example configuration with the ``ioc`` section on (and ``alarms`` as given), written into ``folder``."""
    text = (CONFIG / "cryod.yaml").read_text().replace("calibration: calibration/", f"calibration: {CONFIG}/calibration/")
    text = re.sub(r"(?m)^ioc: null.*$", IOC_SECTION.format(prefix=prefix, writable=str(writable).lower()), text)
    if alarms:
        text = re.sub(r"(?m)^alarms: null.*$", alarms, text)
    for old, new in replacements.items():
        assert old in text, old
        text = text.replace(old, new)
    path = folder / "cryod.yaml"
    path.write_text(text)
    return path


class IocProcess:
    """``cryod ioc --socket SOCKET`` in a process of its own, ready once its PVs answer on Channel Access."""

    def __init__(self, folder: Path, socket_path: Path, prefix: str = "CRYOTEST:", *arguments: str):
        self.folder, self.socket_path, self.prefix, self.arguments = folder, socket_path, prefix, arguments
        self.stderr_path = folder / "ioc-stderr.txt"
        self.process: subprocess.Popen | None = None
        self.start()

    def start(self, timeout_s: float = 60.0) -> None:
        env = dict(os.environ, PYTHONPATH=str(REPOSITORY), **EPICS_ENVIRONMENT)
        with open(self.stderr_path, "a") as stderr:
            self.process = subprocess.Popen([sys.executable, "-m", "cryod.cli", "ioc", "--socket",
                                             str(self.socket_path), *self.arguments], env=env, cwd=self.folder,
                                            stdout=stderr, stderr=stderr, stdin=subprocess.DEVNULL)
        deadline = time.monotonic() + timeout_s
        while "EPICS IOC of the daemon" not in self.journal():
            if self.process.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"cryod ioc did not start: {self.journal()[-3000:]}")
            time.sleep(0.05)

    def journal(self) -> str:
        return self.stderr_path.read_text() if self.stderr_path.exists() else ""

    def kill(self) -> None:
        """SIGKILL: the IOC ends without a word, as a crash would."""
        self.process.kill()
        self.process.wait(timeout=30)

    def stop(self) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                return self.process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.process.kill()
        return self.process.wait(timeout=30)


def wait_until(condition, timeout_s: float = 60.0, what: str = "the condition") -> None:
    """Poll ``condition`` every 50 ms until it holds; an assertion naming ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"{what} did not come within {timeout_s} s"
        time.sleep(0.05)


def daemon_status(socket_path) -> dict:
    """The daemon's status at ``socket_path``, as ``cryod ctl status --json`` gives it."""
    from cryod.service.control_socket import send_command

    return send_command(socket_path, "status")["status"]
