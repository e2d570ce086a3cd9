"""The live web page: its HTTP interface, its limits, writes with the token, and a real headless browser.

The daemon runs with its loop held between two ticks (tests/gated_daemon.py), so what the page
shows can be compared with ``cryod ctl status`` of the same tick, and the test decides when the
values change. The browser is Debian's chromium driven through chromedriver by selenium; the
screenshot is kept as a test artifact: ``test-artifacts/web-page.png`` at the checkout's top (or in
the folder ``CRYOD_TEST_ARTIFACTS`` names), where CI and a reader find it after the run.
"""

import http.client
import json
import os
import re
import socket
import threading
import time
from pathlib import Path

import pytest

from cryod.config import WebConfig
from cryod.service.control_socket import send_command
from tests.gated_daemon import GatedDaemon
from tests.headless_browser import port_of, wait_until

#: Processes, real sockets or real time: the second step of the suite (pytest -m system).
pytestmark = pytest.mark.system

TOKEN = "f3a9c1d27b4e8a6f0c5d9e2b1a7f4c3d"


def web_daemon(tmp_path, writable=False):
    token_file = None
    if writable:
        token_file = tmp_path / "web.token"
        token_file.write_text(TOKEN + "\n")
        token_file.chmod(0o640)
    return GatedDaemon(tmp_path, sections={"web": WebConfig("127.0.0.1:0", writable, token_file)})


def request(daemon, method, path, body=None, headers=None, run_ticks=False):
    """(status code, decoded JSON or bytes) of one request; ticks run while it waits when asked."""
    result = {}

    def client():
        connection = http.client.HTTPConnection("127.0.0.1", port_of(daemon), timeout=20)
        connection.request(method, path, body=body, headers=headers or {})
        response = connection.getresponse()
        data = response.read()
        result["answer"] = (response.status, json.loads(data) if response.getheader("Content-Type", "").startswith(
            "application/json") else data, dict(response.getheaders()))
        connection.close()

    thread = threading.Thread(target=client)
    thread.start()
    while thread.is_alive():
        if run_ticks:
            daemon.gate.run_ticks(1)
        thread.join(0.005)
    return result["answer"]


def test_the_page_its_status_and_history_are_served_with_a_strict_policy(tmp_path):
    with web_daemon(tmp_path) as daemon:
        code, page, headers = request(daemon, "GET", "/")
        assert code == 200 and b'id="charts"' in page and b"http" not in page.replace(b"http-equiv", b"")
        assert "default-src 'none'" in headers["Content-Security-Policy"]
        for asset in ("/app.js", "/style.css", "/icon.svg", "/uPlot.iife.min.js", "/uPlot.min.css",
                      "/uPlot.LICENSE.txt"):                             # the charting library, served here
            assert request(daemon, "GET", asset)[0] == 200
        assert b"MIT" in request(daemon, "GET", "/uPlot.LICENSE.txt")[1]
        code, answer, _ = request(daemon, "GET", "/api/status")
        status = send_command(daemon.socket_path, "status")["status"]
        assert answer["writable"] is False and answer["page_commands"] == []
        assert answer["status"]["T2_K"] == status["T2_K"] and answer["status"]["time_s"] == status["time_s"]
        daemon.gate.run_ticks(40)                                    # more than a second of rows
        deadline = time.monotonic() + 10
        while not request(daemon, "GET", "/api/history")[1]["bins"]:
            assert time.monotonic() < deadline, "no history bin"
            time.sleep(0.05)
        bins = request(daemon, "GET", "/api/history")[1]["bins"]
        rows = [row for row in daemon.gate.rows if bins[0]["time_s"] <= row.time_s < bins[0]["time_s"] + 1.0]
        assert bins[0]["T2_min_K"] == min(row.T2_K for row in rows)
        assert bins[0]["T2_max_K"] == max(row.T2_K for row in rows)
        assert bins[0]["pi_W"] is not None and bins[0]["ff_min_W"] <= bins[0]["ff_max_W"]
        assert request(daemon, "GET", "/nothing")[0] == 404
        assert request(daemon, "DELETE", "/api/status")[0] == 405
        assert request(daemon, "GET", "/../etc/passwd")[0] == 404


def test_a_read_only_page_refuses_commands_and_says_so_in_the_journal(tmp_path):
    with web_daemon(tmp_path) as daemon:
        before = daemon.regulator_state()
        code, answer, _ = request(daemon, "POST", "/api/command", json.dumps({"command": "heater-off"}),
                                  {"X-Cryod-Token": TOKEN, "Content-Type": "application/json"})
        assert code == 403 and "read-only" in answer["message"]
        daemon.gate.run_ticks(2)
        assert daemon.regulator_state() == before
        journal = daemon.interfaces_journal()
    assert "web page: a command refused: web.writable is false (by web page, 127.0.0.1:" in journal
    assert f"uid {os.geteuid()} (" in journal.split("web.writable is false (by web page, ")[1].split("\n")[0]


def test_writes_need_the_token_go_through_the_limits_and_are_journaled_with_the_peer(tmp_path):
    with web_daemon(tmp_path, writable=True) as daemon:
        before = daemon.regulator_state()
        command = json.dumps({"command": "setpoint 5.2"})
        for headers in ({}, {"X-Cryod-Token": "wrong" * 8}, {"X-Cryod-Token": TOKEN, "Origin": "http://evil.test"}):
            code, answer, _ = request(daemon, "POST", "/api/command", command, headers)
            assert code == 403, answer
        assert request(daemon, "POST", "/api/command", json.dumps({"command": "reload"}),
                       {"X-Cryod-Token": TOKEN})[0] == 400                      # not taken from the page
        assert request(daemon, "POST", "/api/command", "x" * 5000, {"X-Cryod-Token": TOKEN})[0] == 413
        assert request(daemon, "POST", "/api/command", "{", {"X-Cryod-Token": TOKEN})[0] == 400
        daemon.gate.run_ticks(2)
        assert daemon.regulator_state() == before
        code, answer, _ = request(daemon, "POST", "/api/command", command, {"X-Cryod-Token": TOKEN}, run_ticks=True)
        assert code == 200 and answer["ok"] and answer["status"]["target_K"] == 5.2
        code, answer, _ = request(daemon, "POST", "/api/command", json.dumps({"command": "setpoint 50"}),
                                  {"X-Cryod-Token": TOKEN}, run_ticks=True)
        assert code == 409 and not answer["ok"] and "outside 3..20 K" in answer["message"]
        assert daemon.loop.regulator.ramp.target_K == 5.2
        messages = [event.message for _, event in daemon.gate.events if event.kind == "command"]
        accepted = next(message for message in messages if message.startswith("setpoint accepted: setpoint 5.2 K"))
        # the page's client (address and user) and the interfaces process that passed the command on
        assert "(by web page, 127.0.0.1:" in accepted and f", uid {os.geteuid()} (" in accepted
        assert "; via uid " in accepted
        journal = daemon.interfaces_journal()
    assert journal.count("wrong or missing token (by web page, 127.0.0.1:") == 2
    assert "another site's page refused" in journal


def test_slow_broken_foreign_and_excess_clients_are_refused_and_change_nothing(tmp_path):
    """The page's server as the daemon runs it (its limits in detail: tests/test_http_server.py): a head never
    finished is answered 408, a line too long 431, garbage 400, a foreign Host 421 (DNS rebinding), and 70
    connections that say nothing (more than the 64 places) keep no real client out."""
    with web_daemon(tmp_path) as daemon:
        port = port_of(daemon)
        with socket.create_connection(("127.0.0.1", port), timeout=10) as long_line:
            long_line.sendall(b"GET /" + b"a" * 20000 + b" HTTP/1.1\r\n\r\n")
            assert long_line.recv(100).startswith(b"HTTP/1.1 431")
        with socket.create_connection(("127.0.0.1", port), timeout=10) as garbage:
            garbage.sendall(bytes(range(256)) + b"\r\n\r\n")
            assert garbage.recv(100).startswith(b"HTTP/1.1 400")
        code, answer, _ = request(daemon, "GET", "/api/status", headers={"Host": f"rebound.example:{port}"})
        assert code == 421 and "does not answer for 'rebound.example" in answer["message"]
        idle = [socket.create_connection(("127.0.0.1", port), timeout=10) for _ in range(70)]
        try:
            time.sleep(0.2)
            for _ in range(5):
                assert request(daemon, "GET", "/api/status")[0] == 200
        finally:
            for connection in idle:
                connection.close()
        with socket.create_connection(("127.0.0.1", port), timeout=10) as slow:
            slow.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n")           # never finishes its head
            started = time.monotonic()
            assert slow.recv(100).startswith(b"HTTP/1.1 408")
            assert 4.0 < time.monotonic() - started < 8.0
        daemon.gate.run_ticks(3)
        assert daemon.loop.exit_code is None and request(daemon, "GET", "/api/status")[0] == 200
        assert "rebound.example" in daemon.interfaces_journal()


def test_open_pages_receive_the_status_at_each_new_tick(tmp_path):
    with web_daemon(tmp_path) as daemon:
        with socket.create_connection(("127.0.0.1", port_of(daemon)), timeout=20) as page:
            page.sendall(b"GET /api/events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            stream = page.makefile("rb")
            assert stream.readline().startswith(b"HTTP/1.1 200")
            frames = []
            while len(frames) < 3:
                line = stream.readline()
                if line.startswith(b"data: "):
                    frames.append(json.loads(line[6:]))
                    daemon.gate.run_ticks(1)
            times = [frame["status"]["time_s"] for frame in frames]
            assert times == sorted(times) and len(set(times)) == 3


def test_an_event_stream_starts_after_the_event_the_page_or_the_browser_names(tmp_path):
    """The page asks for the events after the last its history gave (``?after=``), a browser that reconnects
    for those after the last frame's id (``Last-Event-ID``): the events folded in between are in the first
    frame. Without either, the stream starts after the newest; a sequence number that is not one is refused."""
    def first_frame(daemon, head: bytes):
        with socket.create_connection(("127.0.0.1", port_of(daemon)), timeout=20) as page:
            page.sendall(b"GET /api/events" + head + b"\r\n\r\n")
            stream = page.makefile("rb")
            assert stream.readline().startswith(b"HTTP/1.1 200")
            identity = None
            while True:
                line = stream.readline()
                if line.startswith(b"id: "):
                    identity = int(line[4:])
                if line.startswith(b"data: "):
                    return identity, json.loads(line[6:])
                if not line.strip():
                    daemon.gate.run_ticks(1)

    def note(daemon, text):
        sent = threading.Thread(target=send_command, args=(daemon.socket_path, f"note {text}"))
        sent.start()
        while sent.is_alive():
            daemon.gate.run_ticks(1)
            sent.join(0.005)

    with web_daemon(tmp_path) as daemon:
        daemon.gate.run_ticks(20)
        for text in ("first", "second", "third"):
            note(daemon, text)
        deadline = time.monotonic() + 20.0            # the history is folded in the interfaces process
        while len(history := request(daemon, "GET", "/api/history", run_ticks=True)[1]["events"]) < 3:
            assert time.monotonic() < deadline, history
            daemon.gate.run_ticks(1)
        seqs = [event["seq"] for event in history]
        assert len(seqs) >= 2 and seqs == list(range(seqs[0], seqs[0] + len(seqs)))
        identity, frame = first_frame(daemon, f"?after={seqs[0]} HTTP/1.1\r\nHost: 127.0.0.1".encode())
        assert [event["seq"] for event in frame["events"]][:len(seqs) - 1] == seqs[1:]
        assert identity == frame["events"][-1]["seq"]
        identity, frame = first_frame(daemon, f" HTTP/1.1\r\nHost: 127.0.0.1\r\nLast-Event-ID: {seqs[-2]}".encode())
        assert [event["seq"] for event in frame["events"]][:1] == seqs[-1:]
        _, frame = first_frame(daemon, b" HTTP/1.1\r\nHost: 127.0.0.1")
        assert all(event["seq"] > seqs[-1] for event in frame["events"])
        _, frame = first_frame(daemon, b"?after=99999 HTTP/1.1\r\nHost: 127.0.0.1")      # a daemon restarted since
        assert all(event["seq"] > seqs[-1] for event in frame["events"])
        status, body, _ = request(daemon, "GET", "/api/events?after=-1")
        assert status == 400 and body["message"] == "after must be a whole number of events, got '-1'"


# -- a real browser ---------------------------------------------------------------------------------
def artifact_folder() -> Path:
    """The folder for files a reader looks at after the run: ``CRYOD_TEST_ARTIFACTS`` or test-artifacts/."""
    folder = Path(os.environ.get("CRYOD_TEST_ARTIFACTS") or Path(__file__).resolve().parents[1] / "test-artifacts")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def shown(browser, element_id) -> str:
    return browser.find_element("id", element_id).get_attribute("data-value")


def test_the_page_in_a_browser_shows_ctl_status_and_follows_the_loop(tmp_path, browser):
    """A real headless chromium on the page: its tiles show ctl status of the same tick (the heater's big number is
    its level over the last cooler cycles), its charts' time axis reads the lab's time of day (the daemon's clock
    plus its offset to the wall clock), a note sent with ``cryod ctl note`` reaches its list of events; the page is
    drawn at 1920x1080 and at a laptop's 1366x768 without a horizontal scroll bar, and both are kept as
    screenshots."""
    import datetime

    with web_daemon(tmp_path) as daemon:
        daemon.gate.run_ticks(300)                                      # 24 s: the averages have their windows
        browser.set_window_size(1920, 1080)
        browser.get(f"http://127.0.0.1:{port_of(daemon)}/")
        wait_until(lambda: browser.find_element("id", "connection").text == "live", "connect")
        for _ in range(3):
            status = send_command(daemon.socket_path, "status")["status"]
            wait_until(lambda: shown(browser, "time_s") == repr(status["time_s"]), "show this tick")
            assert shown(browser, "state") == status["state"]
            for key in ("T2_K", "T5_K", "setpoint_K", "heater_W", "heater_mean_W", "T2_average_K",
                        "line_amplitude_K", "ff_limit_K"):
                assert status[key] is not None, key
                assert float(shown(browser, key)) == pytest.approx(status[key], rel=1e-12, abs=1e-15), key
            assert browser.find_element("id", "T2_K").text == f"{status['T2_K']:.6f} K"
            assert browser.find_element("id", "heater_mean_W").text == f"{status['heater_mean_W'] * 1e3:.3f} mW"
            assert float(shown(browser, "error_K")) == pytest.approx(status["T2_K"] - status["setpoint_K"], abs=1e-12)
            assert float(shown(browser, "pi_W")) == pytest.approx(status["pi_proportional_W"] + status["pi_integral_W"])
            daemon.gate.run_ticks(15)                                   # the page follows the loop
        # the time of day: the tick's wall time as the record writes it, on the header and the charts' axis
        wall = daemon.daemon.clock_offset_s + status["time_s"]
        expected = datetime.datetime.fromtimestamp(wall).strftime("%H:%M")
        assert expected in browser.find_element("id", "wall_time").text
        axis = browser.find_element("id", "chart-T2").get_attribute("data-time-axis").split()
        assert axis and all(re.fullmatch(r"\d\d:\d\d(:\d\d)?", tick) for tick in axis), axis
        ticks = [datetime.datetime.strptime(tick, "%H:%M:%S" if tick.count(":") == 2 else "%H:%M") for tick in axis]
        last = datetime.datetime.strptime(datetime.datetime.fromtimestamp(wall).strftime("%H:%M:%S"), "%H:%M:%S")
        assert all(abs((tick - last).total_seconds()) < 700 for tick in ticks), (axis, last)   # the window's times
        legend = browser.execute_script('return [...document.querySelectorAll("#chart-heater .u-legend .u-label")]'
                                        '.map((label) => label.textContent);')
        assert {"heater, mean of the last 10 cooler cycles", "waveform range: lowest", "PI's part"} <= set(legend), legend
        sent = threading.Thread(target=send_command, args=(daemon.socket_path, "note cold plate swapped"))
        sent.start()
        while sent.is_alive():
            daemon.gate.run_ticks(1)
            sent.join(0.005)

        def listed():
            texts = browser.execute_script('return [...document.querySelectorAll("#events li")]'
                                           '.map((item) => item.textContent);')
            if any("note: cold plate swapped" in text for text in texts):
                return True
            daemon.gate.run_ticks(1)
            return False

        wait_until(listed, "list the note")
        assert browser.find_element("id", "control").get_attribute("hidden") is not None    # read-only page
        errors = [entry for entry in browser.get_log("browser") if entry["level"] == "SEVERE"]
        assert not errors, errors
        for name, size in (("web-page.png", (1920, 1080)), ("web-page-laptop.png", (1366, 768))):
            browser.set_window_size(*size)
            time.sleep(0.3)
            width = browser.execute_script("return [document.documentElement.scrollWidth, window.innerWidth];")
            assert width[0] <= width[1], (size, width)                  # nothing wider than the screen
            screenshot = artifact_folder() / name
            browser.save_screenshot(str(screenshot))
            print(f"screenshot of the page at {size[0]}x{size[1]}: {screenshot}")
            assert screenshot.stat().st_size > 10_000
