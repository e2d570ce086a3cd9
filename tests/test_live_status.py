"""What the operator and the lab's monitoring see while the daemon runs.

The status line is checked on a real pseudo-terminal (and its absence in a pipe)
with the real ``cryod --simulate`` process; the Prometheus endpoint is scraped by
a real HTTP client during a daemon run on virtual time and parsed with
prometheus_client's own text parser.
"""

import dataclasses
import fcntl
import math
import os
import pty
import select
import socket
import struct
import subprocess
import sys
import termios
import time
import urllib.error
import urllib.request

import pytest
from prometheus_client.parser import text_string_to_metric_families

from cryod.config import MetricsConfig
from cryod.records.columns import Event, Row
from cryod.service.live_view import LiveView
from cryod.interfaces.metrics import MetricsEndpoint, metrics_address
from tests.event_loop_thread import EventLoopThread
from cryod.service.status_line import format_status
from tests.example_config import simulated_config
from tests.fault_drills import FaultDrill


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def scrape(port: int) -> dict:
    """{(name, labels as a sorted tuple): value} of one scrape, parsed by prometheus_client."""
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as reply:
        assert reply.status == 200
        text = reply.read().decode()
    return {(sample.name, tuple(sorted(sample.labels.items()))): sample.value
            for family in text_string_to_metric_families(text) for sample in family.samples}


def test_the_line_amplitude_is_the_feedforwards_estimate_or_a_fit_of_recent_T2():
    view = LiveView(period_s=0.08, line_rad_s=10.83)
    assert math.isnan(view.snapshot()["line_amplitude_K"]) and view.snapshot()["state"] == "starting"
    for tick in range(300):
        t = 0.08 * tick
        view(Row(time_s=t, lateness_ms=0.0, state="closed", T2_K=5.0 + 8e-4 * math.cos(10.83 * t + 0.3),
                 T5_K=3.4, heater_W=0.1, setpoint_K=5.0, T2_sample_s=t))
    assert view.snapshot()["line_amplitude_K"] == pytest.approx(8e-4, rel=1e-3)
    view(Row(time_s=24.0, lateness_ms=0.0, state="closed", T2_K=5.0, T5_K=3.4, heater_W=0.1, setpoint_K=5.0,
             control={"ff_line_K": 2.5e-4, "ff_scale": 1.0}))
    assert view.snapshot()["line_amplitude_K"] == 2.5e-4
    view(Event("fault", "instrument_timeout: flange DMM did not answer"))
    view(Event("fault", "instrument_timeout: again"))
    assert view.snapshot()["faults"] == {"instrument_timeout": 2}


def test_status_text_has_units_and_sensible_precision():
    text = format_status({"state": "closed", "T2_K": 5.00000049, "error_K": 4.9e-7, "T5_K": 3.7,
                          "heater_W": 0.5000000000000001, "line_amplitude_K": 1.75e-3, "faults": {},
                          "lateness_ms": 0.04})
    assert text == "closed | T2 5.000000 K (+0.5 µK) | T5 3.7000 K | heater 500.0 mW | line 1.750 mK | lateness 0.0 ms"
    assert "heater UNKNOWN" in format_status({"state": "fault:connection_lost", "heater_W": math.nan,
                                              "faults": {"connection_lost": 1}, "last_fault": "x"})


def private_runtime(runtime_dir) -> dict:
    """An environment whose per-user runtime directory is the test's own (its dry run's socket goes there)."""
    return dict(os.environ, XDG_RUNTIME_DIR=str(runtime_dir))


def run_in_pseudo_terminal(argv, cwd, runtime_dir, columns=0) -> tuple[int, str]:
    """Run a command with stdout and stderr on a new pseudo-terminal; its exit code and all it drew."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, columns, 0, 0))
    process = subprocess.Popen(argv, stdin=slave, stdout=slave, stderr=slave, cwd=cwd, close_fds=True,
                               env=private_runtime(runtime_dir))
    os.close(slave)
    drawn = b""
    while True:
        ready, _, _ = select.select([master], [], [], 0.5)
        if ready:
            try:
                chunk = os.read(master, 65536)
            except OSError:          # the child closed the terminal
                break
            if not chunk:
                break
            drawn += chunk
        elif process.poll() is not None:
            break
    os.close(master)
    return process.wait(timeout=60), drawn.decode(errors="replace")


SIMULATE = [sys.executable, "-m", "cryod.cli", "--simulate", "--duration", "300", "--speed", "max"]


@pytest.mark.system
def test_a_terminal_gets_a_live_status_line_with_progress_and_a_pipe_gets_none(tmp_path, runtime_dir):
    code, drawn = run_in_pseudo_terminal(SIMULATE, tmp_path, runtime_dir)          # a pseudo-terminal that says 0 columns
    assert code == 0
    redraws = [part for part in drawn.split("\r") if "/300 s, left" in part and part.startswith("closed")]
    assert len(redraws) >= 2, drawn[-2000:]
    last = redraws[-1]
    assert "T2 5.00" in last and " K (" in last and ("µK)" in last or "mK)" in last)
    assert "heater " in last and " mW" in last and "line " in last
    assert "cryod.datalog: data log: writing" in drawn                 # the log still shows, above the line
    assert "duration_s: 300.0" in drawn                               # and the summary after it

    piped = subprocess.run(SIMULATE[:-4] + ["--duration", "300", "--speed", "max"], cwd=tmp_path,    # a second of
                           capture_output=True, text=True, timeout=120, env=private_runtime(runtime_dir))  # redraws, or more
    assert piped.returncode == 0
    assert "\r" not in piped.stderr and "left" not in piped.stderr


@pytest.mark.system
def test_the_metrics_endpoint_serves_live_state_and_faults_to_a_real_client(tmp_path):
    port = free_port()
    config = simulated_config(tmp_path)
    config = dataclasses.replace(config, metrics=MetricsConfig(address=f"127.0.0.1:{port}", cryostat="K2 flange"))
    scrapes = {}
    def when_served(name, row_index):
        """Scrape once the interfaces process has the row the loop stands at (its stream brings it within a
        tenth of a second; the loop waits here meanwhile)."""
        def action(bench):
            deadline = time.monotonic() + 20.0
            while True:
                try:
                    values = scrape(port)
                except OSError:
                    values = {}
                if values.get(("cryod_flange_temperature_kelvin", ())) == drill.rows[row_index].T2_K:
                    scrapes[name] = values
                    return
                assert time.monotonic() < deadline, f"the metrics did not show row {row_index}"
                time.sleep(0.02)
        return action

    actions = {
        1000: when_served("regulating", 1000),
        1200: lambda bench: bench.flange_dmm.inject_no_reply(True),
        1202: lambda bench: bench.flange_dmm.inject_no_reply(False),
        1205: when_served("after the fault", 1205),
    }
    drill = FaultDrill(tmp_path, actions, config=config)
    assert drill.run(150.0).exit_code == 0
    regulating, after = scrapes["regulating"], scrapes["after the fault"]
    row = drill.rows[1000]
    assert regulating[("cryod_flange_temperature_kelvin", ())] == pytest.approx(row.T2_K, abs=1e-9)
    assert regulating[("cryod_heater_power_watts", ())] == pytest.approx(row.heater_W, abs=1e-12)
    assert regulating[("cryod_setpoint_kelvin", ())] == 5.0
    assert 1e-5 < regulating[("cryod_ptc_line_amplitude_kelvin", ())] < 3e-3
    assert regulating[("cryod_state", (("state", "closed"),))] == 1.0
    assert regulating[("cryod_state", (("state", "fault"),))] == 0.0
    assert regulating[("cryod_info", (("cryostat", "K2 flange"), ("version", __import__("cryod").__version__)))] == 1
    assert regulating[("cryod_loop_ticks_total", ())] == pytest.approx(1001, abs=1)
    assert regulating[("cryod_faults_total", (("cause", "instrument_timeout"),))] == 0
    assert after[("cryod_faults_total", (("cause", "instrument_timeout"),))] >= 1
    assert after[("cryod_heater_power_watts", ())] == 0.0
    assert after[("cryod_state", (("state", "closed"),))] == 0.0
    with pytest.raises(OSError):                                        # stopped with the daemon
        scrape(port)


def test_a_bad_metrics_address_in_the_config_names_the_key(tmp_path):
    from cryod.config import load_config
    from cryod.yaml_source import FileFormatError
    from tests.conftest import CONFIG

    text = (CONFIG / "cryod.yaml").read_text().replace('address: null', 'address: "localhost"') \
        .replace("calibration: calibration/", f"calibration: {CONFIG}/calibration/")
    path = tmp_path / "cryod.yaml"
    path.write_text(text)
    with pytest.raises(FileFormatError, match="metrics.address.*host:port"):
        load_config(path)
    assert load_config(CONFIG / "cryod.yaml").metrics == MetricsConfig(address=None, cryostat="")


def test_metrics_addresses_are_checked_and_a_busy_port_is_named():
    assert metrics_address("[::1]:9477") == ("::1", 9477)
    for bad in ("9477", "localhost:http", "127.0.0.1:70000", ":9477"):
        with pytest.raises(ValueError):
            metrics_address(bad)
    with EventLoopThread() as loop:
        first = MetricsEndpoint(LiveView(0.08, 10.83), "127.0.0.1:0")
        loop.run(first.start())
        try:
            second = MetricsEndpoint(LiveView(0.08, 10.83), f"127.0.0.1:{first.port}")
            with pytest.raises(OSError, match=f"metrics.address 127.0.0.1:{first.port}"):
                loop.run(second.start())
        finally:
            loop.run(first.stop())


@pytest.mark.system
def test_hundreds_of_idle_connections_to_the_metrics_cost_no_thread_each_and_a_scrape_still_answers():
    """prometheus_client's own server takes a thread per connection (800 idle ones: 808 threads); the endpoint
    takes none, and a scrape is still answered: the connection that has waited longest for its request gives way."""
    import threading

    with EventLoopThread() as loop:
        before = threading.active_count()
        endpoint = MetricsEndpoint(LiveView(0.08, 10.83), "127.0.0.1:0", max_connections=32)
        loop.run(endpoint.start())
        idle = []
        try:
            for _ in range(300):
                idle.append(socket.create_connection(("127.0.0.1", endpoint.port)))
                idle[-1].sendall(b"GET /metr")                   # a request begun, never finished
            assert scrape(endpoint.port)[("cryod_loop_ticks_total", ())] == 0.0
            assert threading.active_count() == before            # no thread for any client
            counts = endpoint.server.counts
            end = time.monotonic() + 10.0
            while (counts["closed_for_room"] < 268 or len(endpoint.server.places) > 32) and time.monotonic() < end:
                time.sleep(0.01)
            assert counts["closed_for_room"] >= 268 and len(endpoint.server.places) <= 32
            with urllib.request.urlopen(f"http://127.0.0.1:{endpoint.port}/nothing", timeout=5) as reply:
                raise AssertionError(f"a path that is not the metrics answered {reply.status}")
        except urllib.error.HTTPError as error:
            assert error.code == 404
        finally:
            for connection in idle:
                connection.close()
            loop.run(endpoint.stop())
