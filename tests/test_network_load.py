"""A real-time dry run keeps its 80 ms with 5 open web pages and 5 Lake Shore 336 clients flooding it.

``cryod simulate`` runs at real speed in its own process with both interfaces on. Its overruns are
counted over a stretch without clients and over an equal stretch with the load of
``benchmarks/network_load.py`` (5 pages reading the event stream; two clients polling as fast as
they are answered, one sending random bytes, one overlong lines, one half commands that it
abandons). The machine running the tests is shared, so the loaded stretch is compared with the
quiet one just before it rather than with zero; the numbers are printed. The default run compares two
3 s stretches (about 40 ticks each, a few hundred requests of each kind); the slow run, two of 8 s.
"""

import time

import pytest

from benchmarks.network_load import ClientLoad
from cryod.service.control_socket import send_command
from tests.dry_run_process import DryRunProcess, lab_config

#: Processes, real sockets or real time: the second step of the suite (pytest -m system).
pytestmark = pytest.mark.system


def overruns(process) -> int:
    return send_command(process.socket, "status")["status"]["overruns"]


@pytest.mark.parametrize("stretch_s", [3.0, pytest.param(8.0, marks=pytest.mark.slow)])
def test_pages_and_tcp_clients_do_not_slow_the_loop(tmp_path, stretch_s):
    process = DryRunProcess(tmp_path, lab_config(tmp_path, writable=False), "--speed", "1", "--duration", "600")
    try:
        deadline = time.monotonic() + 60
        while send_command(process.socket, "status")["status"].get("state") != "closed":
            assert time.monotonic() < deadline, process.journal()[-2000:]
            time.sleep(0.1)
        before = send_command(process.socket, "status")["status"]
        time.sleep(stretch_s)
        quiet = overruns(process) - before["overruns"]
        start = overruns(process)
        with ClientLoad(process.ports["web"], process.ports["lakeshore336"]) as load:
            time.sleep(stretch_s)
            loaded = overruns(process) - start
        status = send_command(process.socket, "status")["status"]
        print(f"overruns: {quiet} in {stretch_s:g} s without clients, {loaded} in {stretch_s:g} s with 5 pages and "
              f"5 TCP clients ({load.counts}); lateness p99 {status['lateness_ms_p99']} ms")
        assert load.counts["frames"] >= 5 * stretch_s and load.counts["replies"] >= 10 * stretch_s    # really served
        assert load.counts["half"] >= 10 and load.counts["garbage"] >= 10 and load.counts["long"] >= 10
        assert loaded <= quiet + 2
        assert status["state"].startswith("closed") and status["target_K"] == 5.0     # nothing changed
        assert "Traceback" not in process.journal()
    finally:
        process.stop()
