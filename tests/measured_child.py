"""A cryod command line in a child process, with its own peak memory, its CPU and wall time.

The peak is the child's VmHWM after ``exec`` and the CPU time its own ``os.times()``, both written by the
child as it exits (also after a traceback): ``wait4``'s ``ru_maxrss`` would start from the parent's resident
size at the fork, which in a test process that has run the slow tests is gigabytes. A child killed at its
time limit has neither.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

_WRAPPER = ("import atexit, os, runpy, sys\n"
            "figures_file = sys.argv[1]\n"
            "def figures():\n"
            "    with open('/proc/self/status') as status:\n"
            "        kB = next(line.split()[1] for line in status if line.startswith('VmHWM'))\n"
            "    times = os.times()\n"
            "    open(figures_file, 'w').write(f'{kB} {times.user + times.system}')\n"
            "atexit.register(figures)\n"
            "sys.argv = ['cryod', *sys.argv[2:]]\n"
            "runpy.run_module('cryod.cli', run_name='__main__')\n")


@dataclass
class Measured:
    """What a child did: exit status (None: killed at its time limit), output, CPU and wall time (s), peak (MB)."""

    status: int | None
    stdout: str
    stderr: str
    cpu_s: float | None
    wall_s: float
    peak_MB: float | None

    @property
    def outcome(self) -> str:
        """The exit status and the first line of the message, or how it ended."""
        if self.status is None:
            return f"still running after {self.wall_s:.0f} s: killed"
        lines = [line for line in self.stderr.splitlines() if line.strip()]
        if "Traceback" in self.stderr:
            return f"exit {self.status}: traceback, {lines[-1][:120] if lines else ''}"
        return f"exit {self.status}" + (f": {lines[0][:160]}" if lines else "")


def run_cryod(arguments: list[str], cwd: Path, *, tree: Path | None = None, timeout_s: float | None = None,
              address_space_bytes: int | None = None) -> Measured:
    """Run ``cryod ARGUMENTS`` in a child process and measure it.

    Parameters
    ----------
    arguments : list of str
        After ``cryod``.
    cwd : pathlib.Path
    tree : pathlib.Path, optional
        A checkout put first on ``PYTHONPATH`` (another version to compare with).
    timeout_s : float, optional
        The child is killed after this long.
    address_space_bytes : int, optional
        The child's RLIMIT_AS: a child that would take all the memory gets MemoryError instead.
    """
    environment = dict(os.environ, MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1")
    if tree is not None:
        environment["PYTHONPATH"] = str(tree)

    def limit():
        if address_space_bytes is not None:
            resource.setrlimit(resource.RLIMIT_AS, (address_space_bytes, address_space_bytes))

    with tempfile.TemporaryDirectory() as folder:
        figures_file = Path(folder) / "figures"
        started = time.perf_counter()
        child = subprocess.Popen([sys.executable, "-c", _WRAPPER, str(figures_file), *arguments], cwd=cwd,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=environment,
                                 preexec_fn=limit if address_space_bytes is not None else None)
        try:
            stdout, stderr = child.communicate(timeout=timeout_s)
            killed = False
        except subprocess.TimeoutExpired:
            child.kill()
            stdout, stderr = child.communicate()
            killed = True
        wall = time.perf_counter() - started
        written = figures_file.read_text().split() if figures_file.exists() else []
    peak_MB, cpu_s = (int(written[0]) / 1024.0, float(written[1])) if len(written) == 2 else (None, None)
    return Measured(None if killed else child.returncode, stdout.decode(errors="replace"),
                    stderr.decode(errors="replace"), cpu_s, wall, peak_MB)
