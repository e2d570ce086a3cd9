"""``cryod simulate`` in a process of its own (with the lab's interfaces on), for tests with third-party clients.

The configuration is the example's with ``web`` and ``lakeshore336`` on free ports (port 0); the
ports are read from the journal lines the daemon writes at start. Its standard error goes to a
file (a pipe nobody reads would fill and block the daemon's logging).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

from tests.conftest import CONFIG, REPOSITORY

ADDRESS = re.compile(r"(Lake Shore 336 command set|web page) \((?:writable|read-only)\) on 127\.0\.0\.1:(\d+)")


def lab_config(folder: Path, writable: bool = True, token_file: Path | None = None, **replacements: str) -> Path:
    """The example configuration with both interfaces on (free ports), written into ``folder``."""
    text = (CONFIG / "cryod.yaml").read_text().replace("calibration: calibration/",
                                                        f"calibration: {CONFIG}/calibration/")
    web = f'web: {{address: "127.0.0.1:0", writable: {str(token_file is not None).lower()}' + \
        (f", token_file: {token_file}}}" if token_file else "}")
    text = re.sub(r"(?m)^web: null.*$", web, text)
    text = re.sub(r"(?m)^lakeshore336: null.*$",
                  f'lakeshore336: {{address: "127.0.0.1:0", writable: {str(writable).lower()}}}', text)
    for old, new in replacements.items():
        text = text.replace(old, new)
    path = folder / "cryod.yaml"
    path.write_text(text)
    return path


class DryRunProcess:
    """A running ``cryod simulate`` with its control socket, record folder and interfaces' ports."""

    def __init__(self, folder: Path, config: Path, *arguments: str, interfaces: bool = True):
        self.folder = folder
        self.socket = folder / "control.sock"
        self.data = folder / "data"
        self.stderr_path = folder / "stderr.txt"
        self._stderr = open(self.stderr_path, "w")
        env = dict(os.environ, PYTHONPATH=str(REPOSITORY))
        self.process = subprocess.Popen([sys.executable, "-m", "cryod.cli", "simulate", "--config", str(config),
                                         "--data-dir", str(self.data), "--socket", str(self.socket), *arguments],
                                        env=env, cwd=folder, stdout=subprocess.DEVNULL, stderr=self._stderr)
        self.ports = self._wait_for_ports() if interfaces else self._wait_for_socket()

    def _wait_for_socket(self, timeout_s: float = 60.0) -> dict[str, int]:
        """A dry run without the interfaces process: ready once its socket is there."""
        deadline = time.monotonic() + timeout_s
        while not self.socket.exists():
            if self.process.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"the dry run did not start: {self.journal()[-3000:]}")
            time.sleep(0.05)
        return {}

    def _wait_for_ports(self, timeout_s: float = 60.0) -> dict[str, int]:
        deadline = time.monotonic() + timeout_s
        while True:
            found = {name: int(port) for name, port in ADDRESS.findall(self.stderr_path.read_text())}
            if len(found) == 2 and self.socket.exists():
                return {"lakeshore336": found["Lake Shore 336 command set"], "web": found["web page"]}
            if self.process.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"the dry run did not start its interfaces: {self.journal()[-3000:]}")
            time.sleep(0.05)

    def journal(self) -> str:
        """What the daemon wrote to standard error so far."""
        return self.stderr_path.read_text()

    def stop(self) -> int:
        self.process.terminate()
        try:
            return self.process.wait(timeout=30)
        finally:
            self._stderr.close()
