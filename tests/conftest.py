"""Shared fixtures: the shipped and printed models, a private runtime folder, a dry run to talk to, a headless browser."""

import os
import signal
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path

import pytest

from cryod.cli import use_one_blas_thread
from cryod.model import load_model
from drivers.clock import VirtualClock
from tests.headless_browser import headless_chromium

use_one_blas_thread()          # as the command line does for the daemon and the model tools

REPOSITORY = Path(__file__).resolve().parent.parent
CONFIG = REPOSITORY / "config"
DATA = Path(__file__).resolve().parent / "data"
CALIBRATION_DATA = DATA / "calibration"


#: How long before UTC midnight a test's daemon stops dating its record from now (s): longer than any
#: test's simulated run, so that none crosses midnight, where the daemon splits its record in two days' files.
MIDNIGHT_MARGIN_S = 4 * 3600.0


@pytest.fixture(autouse=True)
def records_dated_away_from_midnight(monkeypatch):
    """A daemon on a virtual clock dates its record from now, or, in the last four hours of a UTC day, from
    four hours before its end: a test that reads its daemon's record whole reads one file at any hour."""
    now = time.time()
    day_end = now - now % 86400.0 + 86400.0
    monkeypatch.setattr(VirtualClock, "wall_start_s", min(now, day_end - MIDNIGHT_MARGIN_S))


@pytest.fixture
def terminal_signals():
    """SIGINT and SIGQUIT as a shell at a terminal leaves them to a command, for the test's process: a shell
    that starts the tests as a background job ignores both, and the daemon leaves a signal it inherited
    ignored alone (it would not end the process)."""
    before = {number: signal.getsignal(number) for number in (signal.SIGINT, signal.SIGQUIT)}
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGQUIT, signal.SIG_DFL)
    yield
    for number, handler in before.items():
        signal.signal(number, handler)


@pytest.fixture(scope="session")
def reference_model():
    """config/model.yaml, the shipped model."""
    return load_model(CONFIG / "model.yaml")


@pytest.fixture(scope="session")
def printed_model():
    """The paper's equations exactly as printed."""
    return load_model(CONFIG / "model-paper-printed.yaml")


@pytest.fixture
def runtime_dir():
    """A private per-user runtime folder (for ``XDG_RUNTIME_DIR``) on a short path: a dry run's control
    socket goes in it, and a Unix socket's path holds at most 107 bytes however deep pytest's folders are."""
    with tempfile.TemporaryDirectory(prefix="cryod-run-") as folder:        # mode 0700
        yield Path(folder)


@pytest.fixture
def dry_run_speed():
    """The ``--speed`` of ``running_dry_run``: ``max`` for tests that wait on the daemon's clock; a module whose tests
    only need the loop regulating into a record overrides it with a paced speed, which leaves the CPU to the test."""
    return "max"


@pytest.fixture
def running_dry_run(tmp_path, monkeypatch, runtime_dir, dry_run_speed):
    """``cryod simulate --speed max`` (``dry_run_speed``) in its own process, found by the client without a path."""
    runtime = runtime_dir
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(runtime))
    monkeypatch.setattr("cryod.service.discovery.SERVICE_CONFIG", tmp_path / "no-service.yaml")
    env = dict(os.environ, PYTHONPATH=str(REPOSITORY), XDG_RUNTIME_DIR=str(runtime))
    # virtual time, as fast as the CPU allows (several hundred times real time): deterministic regulation on a
    # loaded test machine; the client measures the hold on the daemon's clock, as it should
    config = tmp_path / "cryod.yaml"
    config.write_text((CONFIG / "cryod.yaml").read_text()
                      # the gains `cryod tune --setpoint 5` suggests for this heater (docs/explanation/control.md)
                      .replace("proportional_W_per_K: 10.0", "proportional_W_per_K: 12.6")
                      .replace("integral_W_per_K_s: 0.2 ", "integral_W_per_K_s: 4.13 ")
                      .replace("calibration: calibration/", f"calibration: {CONFIG}/calibration/"))
    process = subprocess.Popen([sys.executable, "-m", "cryod.cli", "simulate", "--config", str(config), "--speed",
                                dry_run_speed, "--duration", "40000", "--data-dir", str(tmp_path / "data")],
                               env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    socket_path = runtime / "cryod" / "simulate.sock"
    deadline = time.monotonic() + 60
    while not socket_path.exists():
        assert process.poll() is None and time.monotonic() < deadline, process.communicate()[1][-2000:]
        time.sleep(0.05)
    yield types.SimpleNamespace(socket=socket_path, process=process)
    process.terminate()
    process.wait(timeout=30)


@pytest.fixture(scope="session")
def quiet_reference_model(reference_model):
    """Shipped model without the PTC oscillation (for step responses)."""
    return reference_model.with_ptc(ptc_stage_amplitude_K=0.0)


@pytest.fixture
def browser(tmp_path):
    """A headless chromium driven by selenium (tests/headless_browser.py); the test is skipped without one."""
    with headless_chromium(tmp_path) as session:
        yield session
