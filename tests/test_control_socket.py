"""The control socket under load and hostile input, and ``cryod ctl`` at its edges.

Many clients at once, long, partial and undecodable lines, a full connection backlog, numbers
that Python's ``float`` takes and the lab does not, and a reader of ``cryod ctl``'s output that
goes away. The generated-input fuzz test is in test_control_socket_fuzz.py (slow suite).
"""

import argparse
import collections
import json
import os
import socket
import subprocess
import sys
import threading
import time

import pytest
from hypothesis import example, given, settings, strategies as st

from cryod.argument_types import number, plain_decimal
from cryod.cli import READER_GONE, main
from cryod.config import load_config
from cryod.records.columns import Row
from drivers.clock import VirtualClock
from cryod.service.commands import COMMANDS, Command, parse_command
from cryod.service.control_socket import MAX_LINE, ControlSocketServer, send_command
from cryod.service.loop import COMMANDS_PER_TICK, ControlLoop
from cryod.thermometry import load_calibration
from simulated_hw.cryostat import SimulatedCryostat
from tests.conftest import CONFIG, REPOSITORY
from tests.gated_daemon import GatedDaemon
from tests.loop_doubles import DirectInstruments

STATUS = {f"key_{index:02d}": float(index) for index in range(30)}     # 30 lines in `cryod ctl status`


class AnsweringLoop:
    """Stands in for the loop: answers each submitted command from a thread of its own, in order."""

    def __init__(self):
        self.seen = []
        self._queue = collections.deque()
        self._wake = threading.Event()
        self._thread = threading.Thread(target=self._answer, daemon=True)
        self._thread.start()

    def submit(self, command: Command) -> Command:
        self.seen.append((command.name, command.value))
        self._queue.append(command)
        self._wake.set()
        return command

    def _answer(self):
        while True:
            self._wake.wait()
            self._wake.clear()
            while self._queue:
                command = self._queue.popleft()
                command.answer(command.value is None or command.value < 10, f"{command.name} done")


@pytest.fixture
def served(tmp_path):
    """A control socket on a stand-in loop: ``served(**options) -> (path, loop, server)``."""
    servers = []

    def start(**options):
        loop = AnsweringLoop()
        server = ControlSocketServer(tmp_path / "control.sock", 0o660, None, None, loop.submit,
                                     lambda: dict(STATUS), **options)
        server.start()
        servers.append(server)
        return server.path, loop, server

    yield start
    for server in servers:
        server.stop()


def raw_exchange(path, data: bytes, half_close=False, timeout_s=10.0) -> dict:
    """What a client that is not ``cryod ctl`` gets: connect (with a timeout, as most clients do), send, read."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as client:
        client.settimeout(timeout_s)
        client.connect(str(path))
        client.sendall(data)
        if half_close:
            client.shutdown(socket.SHUT_WR)
        return json.loads(client.makefile("rb").readline())


def well_formed(reply) -> bool:
    return (isinstance(reply, dict) and isinstance(reply.get("ok"), bool) and isinstance(reply.get("message"), str)
            and (not reply["ok"] or isinstance(reply.get("status"), dict)))


# -- many clients -----------------------------------------------------------------------------------
def test_a_hundred_clients_at_once_on_the_running_daemon_all_get_their_reply(tmp_path):
    """A hundred connects at once overflow a small listen backlog (with 5, a quarter get a raw BlockingIOError);
    every client gets its reply, and no client costs the daemon a thread of its own."""
    lines = {"status": 25, "setpoint 5.5": 25, "ramp 1_5": 25, "manual 0.6": 25}
    with GatedDaemon(tmp_path) as daemon:
        before = set(threading.enumerate())
        replies, errors = collections.defaultdict(list), []
        barrier = threading.Barrier(sum(lines.values()))

        def client(line):
            barrier.wait()
            try:
                replies[line].append(raw_exchange(daemon.socket_path, line.encode() + b"\n"))
            except Exception as error:
                errors.append(f"{line}: {type(error).__name__}: {error}")

        clients = [threading.Thread(target=client, args=(line,)) for line, count in lines.items()
                   for _ in range(count)]
        for thread in clients:
            thread.start()
        rows_before = len(daemon.gate.rows)
        extra_threads = set()
        for _ in range(400):                # ticks, one at a time, while the clients wait for their answers
            extra_threads |= set(threading.enumerate()) - before - set(clients)
            if not any(thread.is_alive() for thread in clients):
                break
            daemon.gate.run_ticks(1)
            for thread in clients:
                thread.join(0.002)
        assert not any(thread.is_alive() for thread in clients)
        ticks = len(daemon.gate.rows) - rows_before
        commands = [row for row, event in daemon.gate.events if event.kind == "command" and row >= rows_before]
        overruns = daemon.loop.timing.overruns
    assert errors == []
    assert all(well_formed(reply) for answers in replies.values() for reply in answers)
    assert [reply["ok"] for reply in replies["status"]] == [True] * 25
    assert [reply["message"] for reply in replies["setpoint 5.5"]] == ["setpoint 5.5 K"] * 25
    assert all("'ramp' argument K_PER_MIN: '1_5' is not a number" in reply["message"] and not reply["ok"]
               for reply in replies["ramp 1_5"])
    assert all("manual 0.6 W refused" in reply["message"] or "0..0.5 W" in reply["message"]
               for reply in replies["manual 0.6"])
    # no thread per client: the socket's one thread served them all
    assert {thread.name for thread in extra_threads if not thread.name.startswith("cryod-")} == set()
    # the 50 commands that reached the loop were carried out at most COMMANDS_PER_TICK a tick
    per_tick = collections.Counter(commands)
    assert len(commands) == 50 and max(per_tick.values()) <= COMMANDS_PER_TICK and ticks >= 50 / COMMANDS_PER_TICK
    assert overruns == 0


def wait_for_connections(server, count, timeout_s=10.0):
    end = time.monotonic() + timeout_s
    while server.clients != count and time.monotonic() < end:
        time.sleep(0.005)
    assert server.clients == count


class SlowLoop(AnsweringLoop):
    """A loop that answers heater-off at once and every other command only when :meth:`release` is called."""

    def __init__(self):
        self.released = threading.Event()
        super().__init__()

    def submit(self, command):
        if command.name == "heater-off":
            self.seen.append((command.name, command.value))
            command.answer(True, "heater-off done")
            return command
        return super().submit(command)

    def _answer(self):
        self.released.wait()
        super()._answer()

    def release(self):
        self.released.set()
        self._wake.set()


def test_with_every_connection_waiting_for_the_loop_only_heater_off_is_taken_and_cryod_ctl_retries(tmp_path):
    loop = SlowLoop()
    server = ControlSocketServer(tmp_path / "control.sock", 0o660, None, None, loop.submit, lambda: dict(STATUS),
                                 reply_timeout_s=60.0, max_clients=3)
    server.start()
    path = server.path
    holders = [socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) for _ in range(3)]
    try:
        for holder in holders:
            holder.connect(str(path))
            holder.sendall(b"setpoint 6\n")            # each waits for the loop's answer: none is idle
        wait_for_connections(server, 3)
        end = time.monotonic() + 5.0
        while len(loop.seen) < 3 and time.monotonic() < end:
            time.sleep(0.005)
        busy = raw_exchange(path, b"setpoint 5\n")
        assert busy == {"ok": False, "message": "busy: 4 connections open at once (at most 3 for commands; beyond "
                                                "that only heater-off is taken); try again in a moment"}
        assert ("setpoint", 5.0) not in loop.seen      # the busy client's command never reached the loop
        assert raw_exchange(path, b"heater-off\n")["message"] == "heater-off done"
        assert ("heater-off", None) in loop.seen
        with pytest.raises(ConnectionError, match=r"stayed busy for 0.3 s \(\d+ attempts\); its last answer: busy:"):
            send_command(path, "setpoint 5", timeout_s=0.3)
        releaser = threading.Timer(0.3, loop.release)
        releaser.start()                               # cryod ctl asks again until there is room
        assert main(["ctl", "--socket", str(path), "setpoint", "5"]) == 0
        releaser.join()
    finally:
        loop.release()
        for holder in holders:
            holder.close()
        server.stop()


def test_idle_connections_however_many_cannot_keep_heater_off_out(served, capsys):
    """Idle connections must not hold every place (a heater-off answered "busy: 256 connections open" for as long
    as they stay): a connection beyond the limit closes the one that has waited longest without a line."""
    path, loop, server = served(max_clients=40)
    idle = []
    try:
        for _ in range(120):                           # three times the limit, none sending anything
            client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            client.connect(str(path))
            idle.append(client)
        end = time.monotonic() + 10.0
        while (server.connections.closed_for_room < 80 or server.clients > 40) and time.monotonic() < end:
            time.sleep(0.005)
        assert server.clients == 40                    # the limit: no more held open
        assert main(["ctl", "--socket", str(path), "heater-off"]) == 0
        assert loop.seen == [("heater-off", None)] and "heater-off done" in capsys.readouterr().out
        closed = json.loads(idle[0].makefile("rb").readline())       # the idlest, closed for room, were told
        assert closed["ok"] is False and closed["message"].startswith("closed: no command line yet when the 40 "
                                                                      "connections open at once were all taken")
    finally:
        for client in idle:
            client.close()


def test_cryod_ctl_waits_while_the_backlog_is_full(tmp_path):
    """A full backlog is a wait for the client, not a raw BlockingIOError at once from a connect with a timeout."""
    path = tmp_path / "full.sock"
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(str(path))
    listener.listen(0)                                 # room for one waiting connection, nobody accepts
    waiting = [socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)]
    waiting[0].connect(str(path))
    try:
        with pytest.raises(ConnectionError, match="stayed busy for 0.2 s"):
            send_command(path, "status", timeout_s=0.2)

        def serve_later():
            time.sleep(0.1)
            for _ in range(3):
                connection, _ = listener.accept()
                with connection:
                    line = connection.makefile("rb").readline()
                    if line:
                        connection.sendall(json.dumps({"ok": True, "message": f"served {line.strip().decode()}"})
                                           .encode() + b"\n")
                        return

        waiting[0].close()          # its connection stays queued, empty: served first, with nothing to answer
        server = threading.Thread(target=serve_later)
        server.start()
        assert send_command(path, "status", timeout_s=5.0) == {"ok": True, "message": "served status"}
        server.join(5.0)
    finally:
        listener.close()


def test_a_client_waiting_for_the_loop_is_told_when_the_daemon_stops(tmp_path, capfd):
    """The client is answered at once (not after its reply timeout), and the server prints no cancelled task's
    traceback."""
    with_the_loop = threading.Event()                  # a loop that never answers

    def submit(command):
        with_the_loop.set()
        return command

    server = ControlSocketServer(tmp_path / "control.sock", 0o660, None, None, submit, dict)
    server.start()
    result = {}
    client = threading.Thread(target=lambda: result.update(reply=send_command(server.path, "setpoint 5")))
    client.start()
    assert with_the_loop.wait(5.0)
    started = time.monotonic()
    server.stop()
    client.join(5.0)
    assert time.monotonic() - started < 1.0
    assert result["reply"] == {"ok": False, "message": "the daemon is stopping; nothing more is answered"}
    assert "Traceback" not in capfd.readouterr().err


# -- lines ------------------------------------------------------------------------------------------------
def test_a_one_megabyte_line_is_refused_and_cryod_ctl_shows_the_refusal(served, capsys):
    """The daemon refuses the line, and cryod ctl shows that refusal rather than dying with 'Broken pipe' (exit 3)."""
    path, loop, _ = served()
    assert send_command(path, "setpoint " + "1" * 1_000_000) == {
        "ok": False, "message": f"command longer than {MAX_LINE} bytes refused"}
    assert main(["ctl", "--socket", str(path), "setpoint", "1" * 1_000_000]) == 1
    captured = capsys.readouterr()
    assert captured.err.strip() == f"command longer than {MAX_LINE} bytes refused" and captured.out == ""
    assert main(["ctl", "--socket", str(path), "setpoint", "5\nsetpoint 50"]) == 2
    assert "one line" in capsys.readouterr().err
    assert loop.seen == []


def test_partial_undecodable_and_extra_lines_each_get_one_reply(served):
    path, loop, _ = served(line_timeout_s=0.1)
    # the last line of a client that ends without a newline is its command
    assert raw_exchange(path, b"setpoint 5.5", half_close=True)["message"] == "setpoint done"
    # a client that does not finish its line is answered after line_timeout_s and cut off
    assert raw_exchange(path, b"setp") == {
        "ok": False, "message": "no complete command line within 0.1 s; send one line ending in a newline"}
    assert raw_exchange(path, b"\xff\xfe status\n") == {"ok": False, "message": "command is not UTF-8 text"}
    assert raw_exchange(path, b"x" * (MAX_LINE + 1) + b"\n")["message"] == f"command longer than {MAX_LINE} bytes refused"
    assert raw_exchange(path, b"x" * MAX_LINE + b"\n")["message"].startswith("unknown command 'xxxx")
    # one command per connection: what follows the first line is not read
    assert raw_exchange(path, b"setpoint 6\nsetpoint 50\n")["message"] == "setpoint done"
    assert loop.seen == [("setpoint", 5.5), ("setpoint", 6.0)]


@pytest.mark.system
def test_cryod_ctl_ends_quietly_when_its_reader_goes_away(served):
    """``cryod ctl status | head -2``: no BrokenPipeError traceback."""
    path, _, _ = served()
    for extra in ([], ["--json"]):
        reader, writer = os.pipe()
        os.close(reader)                               # the reader has gone before the first line
        try:
            result = subprocess.run([sys.executable, "-m", "cryod.cli", "ctl", "--socket", str(path), *extra,
                                     "status"], stdout=writer, stderr=subprocess.PIPE, text=True, cwd=REPOSITORY,
                                    timeout=60)
        finally:
            os.close(writer)
        assert (result.returncode, result.stderr) == (READER_GONE, "")
    piped = subprocess.run(f"{sys.executable} -m cryod.cli ctl --socket {path} status | head -2", shell=True,
                           capture_output=True, text=True, cwd=REPOSITORY, timeout=60)
    assert piped.stdout == "key_00: 0\nkey_01: 1\n" and piped.stderr == ""      # values printed as readable()


# -- numbers ------------------------------------------------------------------------------------------------
REFUSED_NUMBERS = ["1_5", "nan", "inf", "-inf", "infinity", "\u0665", "\uff15", "1\u00a0", "\u00a05", "0x10",
                   "5,2", "1e999", "--5", "5e", ".", "+", "٣.٥", "5\u2003"]


@pytest.mark.parametrize("text", REFUSED_NUMBERS)
def test_the_socket_and_the_command_line_refuse_the_same_numbers(text):
    """Neither takes a number with a character that is not ASCII ('setpoint\\u00a05', '1\\u00a0'), and the
    message names the argument."""
    with pytest.raises(ValueError, match=r"^'setpoint' argument K: .* is not a (finite )?number") as refused:
        parse_command(f"setpoint {text}")
    assert repr(text) in str(refused.value)
    with pytest.raises(ValueError):
        parse_command(f"setpoint{text}")               # no space of another script between the words either
    with pytest.raises(argparse.ArgumentTypeError, match="expected a (finite )?number"):
        number(text)


@settings(max_examples=300, deadline=None)
@given(st.text(alphabet=st.sampled_from("0123456789+-.eE_ xn\u0665\uff15\u00a0\t"), max_size=12))
@example("1\u00a0")
def test_one_number_rule_for_the_socket_and_the_command_line(text):
    """Both take the same numbers, with the same value, and nothing that is not ASCII (not even '1\u00a0')."""
    assert COMMANDS["setpoint"].parse is plain_decimal
    try:
        expected = number(text)
    except argparse.ArgumentTypeError:
        expected = None
    try:
        value = parse_command(f"ramp {text}").value
    except ValueError:
        value = None
    if text.strip(" \t") == text:                      # the command line ignores ASCII space around a number
        assert value == expected
    if not text.isascii():
        assert value is None and expected is None


def test_cryod_simulate_refuses_setpoint_and_seed_that_float_and_int_take(tmp_path, capsys):
    """What float and int take is not a lab's number: --setpoint 1_5 is not 15 K, --seed \\u0663 is not seed 3."""
    for option, text in (("--setpoint", "1_5"), ("--seed", "\u0663"), ("--seed", "1_0")):
        with pytest.raises(SystemExit) as stopped:
            main(["--simulate", "--speed", "max", "--duration", "0.2", "--data-dir", str(tmp_path / "data"),
                  "--socket", str(tmp_path / "c.sock"), option, text])
        assert stopped.value.code == 2
        assert f"argument {option}" in capsys.readouterr().err


# -- the loop -----------------------------------------------------------------------------------------------
def direct_loop(reference_model):
    """(instruments, loop, what it emitted): the example configuration's loop on a simulated cryostat."""
    config = load_config(CONFIG / "cryod.yaml")
    curves = (load_calibration(CONFIG / "calibration" / "X186279.340"),
              load_calibration(CONFIG / "calibration" / "X207058.340"))
    clock = VirtualClock()
    instruments = DirectInstruments(SimulatedCryostat(reference_model, clock, seed=2), *curves, clock)
    items = []
    return instruments, ControlLoop(config, instruments, *curves, clock, emit=items.append), items


def test_the_loop_carries_out_at_most_a_few_commands_a_tick_in_order(reference_model):
    instruments, loop, items = direct_loop(reference_model)
    flood = [Command("ramp", 0.1 * (index % 10)) for index in range(20)]

    def measure():
        if instruments.measurements == 100:
            for command in flood:
                loop.submit(command)
        return DirectInstruments.measure(instruments)

    instruments.measure = measure
    assert loop.run(duration_s=10.0, manage_gc=False) == 0
    per_tick, rows = [], 0
    for item in items:
        if isinstance(item, Row):
            rows += 1
        elif item.kind == "command":
            per_tick.append(rows)
    assert collections.Counter(per_tick) == {101: 8, 102: 8, 103: 4}
    assert all(command.ok for command in flood) and loop.regulator.ramp.rate_K_per_min == pytest.approx(0.9)


def test_a_heater_off_never_waits_behind_a_flood_and_what_was_sent_before_it_is_superseded(reference_model):
    """A heater-off is applied at the next tick, not behind the queue (256 commands would hold it 32 ticks, 2.6 s);
    the setpoints sent before it are refused as superseded, what comes after it runs in order."""
    instruments, loop, items = direct_loop(reference_model)
    before = [Command("setpoint", 5.0 + 0.001 * index) for index in range(40)]
    off = Command("heater-off")
    after = [Command("ramp", 0.5), Command("ramp", 0.25)]

    def measure():
        if instruments.measurements == 100:
            for command in (*before, off, *after):
                loop.submit(command)
        return DirectInstruments.measure(instruments)

    instruments.measure = measure
    assert loop.run(duration_s=10.0, manage_gc=False) == 0
    rows, applied_at = 0, {}
    for item in items:
        if isinstance(item, Row):
            rows += 1
        elif item.kind == "command":
            applied_at.setdefault(item.message.split(" ")[0], rows)
    assert applied_at["heater-off"] == 101                             # at the first tick after it was sent
    assert all(not command.ok and "superseded by a heater-off" in command.message for command in before)
    assert off.ok and all(command.ok for command in after)             # what came after it, in order
    assert loop.regulator.ramp.rate_K_per_min == 0.25 and loop.heater_w == 0.0
    states = [item.state for item in items if isinstance(item, Row)]
    assert set(states[101:]) == {"off"}                               # and stayed off to the end


# -- a command is taken by the loop or withdrawn by its client, never both ----------------------------
def test_of_take_and_withdraw_only_the_first_succeeds_whatever_the_threads():
    """Two threads race for each of 2000 commands: exactly one of the loop's take and the client's withdraw wins."""
    outcomes = collections.Counter()
    for index in range(2000):
        command = Command("setpoint", 5.0)
        results = {}
        start = threading.Barrier(2)

        def race(name, claim):
            start.wait()
            results[name] = claim()

        threads = [threading.Thread(target=race, args=("take", command.take)),
                   threading.Thread(target=race, args=("withdraw", command.withdraw))]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        assert results["take"] != results["withdraw"]
        assert command.claim == ("taken" if results["take"] else "withdrawn")
        outcomes[command.claim] += 1
    assert sum(outcomes.values()) == 2000


def test_a_command_whose_client_stopped_waiting_is_never_carried_out(tmp_path):
    """The loop stands between two ticks; a setpoint sent through the socket with a 0.3 s reply timeout is
    answered as withdrawn, and when the loop goes on it is journaled as withdrawn and the setpoint stays."""
    with GatedDaemon(tmp_path) as daemon:
        target_before = daemon.loop.regulator.ramp.target_K
        server = ControlSocketServer(tmp_path / "short.sock", 0o600, None, None, daemon.daemon._submit,
                                     lambda: {}, reply_timeout_s=0.3)
        server.start()
        try:
            reply = send_command(server.path, "setpoint 6.5")
        finally:
            server.stop()
        assert reply["ok"] is False and "withdrawn" in reply["message"] and "not be carried out" in reply["message"]
        daemon.gate.run_ticks(3)
        assert daemon.loop.regulator.ramp.target_K == target_before != 6.5
        messages = [event.message for _, event in daemon.gate.events if event.kind == "command"]
        assert any(message.startswith("setpoint withdrawn") for message in messages)
        assert not any("setpoint accepted" in message for message in messages)
