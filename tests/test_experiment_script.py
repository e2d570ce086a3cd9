"""The README's live dry run and docs/how-to/scripts.md's experiment script, as written there, against a real
``cryod simulate --speed 20`` in a process of its own (slow: about five minutes of wall time)."""

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import REPOSITORY

pytestmark = [pytest.mark.system, pytest.mark.slow]


def fenced_block(path: Path, after: str, language: str) -> str:
    """The first ```language block after the line ``after`` in ``path``."""
    text = path.read_text()
    text = text[text.index(after):]
    start = text.index(f"```{language}\n") + len(language) + 4
    return text[start:text.index("```", start)]


def test_the_readme_commands_and_the_experiment_script_against_a_paced_dry_run(tmp_path):
    runtime = tmp_path / "runtime"
    runtime.mkdir(mode=0o700)
    bin_folder = str(Path(sys.executable).parent)       # the environment's commands, run from tmp_path, not the
    env = dict(os.environ, XDG_RUNTIME_DIR=str(runtime))  # checkout: `.venv/bin/` is the environment's full path there
    readme = REPOSITORY / "README.md"
    live = re.search(r"started as `\.venv/bin/(cryod simulate --speed \d+)`", readme.read_text()).group(1)
    live = f"{bin_folder}/{live}"
    stderr = open(tmp_path / "daemon.txt", "w")
    daemon = subprocess.Popen(live.split(), cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=stderr, text=True)
    try:
        socket = runtime / "cryod" / "simulate.sock"
        deadline = time.monotonic() + 120
        while not socket.exists():
            assert daemon.poll() is None and time.monotonic() < deadline, (tmp_path / "daemon.txt").read_text()
            time.sleep(0.1)
        commands = [line.split("  #")[0].strip() for line in
                    fenced_block(readme, "Beside a running dry run", "sh").splitlines() if line.strip()]
        outputs = []
        for command in commands:
            assert command.startswith(".venv/bin/"), command      # the environment's commands, from the checkout
            command = command.replace(".venv/bin/", f"{bin_folder}/", 1)   # from any folder: its full path
            done = subprocess.run(command, shell=True, cwd=tmp_path, env=env, capture_output=True, text=True,
                                  timeout=900)
            assert done.returncode == 0, (command, done.stderr)
            outputs.append(done.stdout)
        status, setpoint, note, plot, settled = outputs
        record = re.search(r"^record_path: (.+\.csv)$", status, re.M).group(1)
        assert Path(record).is_absolute() and Path(record).exists()
        assert "setpoint 5.2 K" in setpoint and note.startswith("note written: cold plate swapped")
        assert Path(plot.strip()).exists()
        assert abs(float(settled) - 5.2) <= 1e-4                       # the one-liner returned, stable
        script = fenced_block(REPOSITORY / "docs" / "how-to" / "scripts.md", "## An experiment script", "python")
        started = time.monotonic()
        run = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True,
                             timeout=1800)
        print(f"the experiment script took {time.monotonic() - started:.0f} s of wall time")
        assert run.returncode == 0, run.stderr
        lines = run.stdout.splitlines()
        assert len(lines) == 3, run.stdout
        for kelvin, line in zip((5.0, 5.5, 6.0), lines):
            found = re.fullmatch(rf"{kelvin} K: T2 ([\d.]+) K, (\d+) µK rms over (\d+) s", line)
            assert found, line
            assert abs(float(found.group(1)) - kelvin) < 1e-4
            # the wait polls every 0.5 s of wall time, 10 s of the daemon's clock at speed 20
            assert int(found.group(2)) < 2000 and 600 <= int(found.group(3)) <= 615
        events = [text for _, text in __import__("cryod").read_record(record).events]
        assert any("note: cold plate swapped (by uid" in text for text in events)
    finally:
        daemon.send_signal(signal.SIGTERM)
        summary = daemon.communicate(timeout=60)[0]
        stderr.close()
    assert daemon.returncode == 0
    assert re.search(r"^overruns: 0$", summary, re.M), summary
    speed = float(re.search(r"^achieved_speed: ([\d.]+)", summary, re.M).group(1))
    assert 0.0 < speed <= 20.5
