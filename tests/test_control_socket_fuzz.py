"""Generated input against the running daemon's control socket (slow suite: ``pytest -m slow``).

The daemon runs on the simulated bench with its loop held between ticks (tests/gated_daemon.py).
Each example is one connection: random bytes, command lines built from the command words and
arguments of every kind (numbers Python's ``float`` takes and the lab does not, other scripts'
digits and spaces, text), lines longer than the limit, and lines left unfinished (with the
connection half-closed, or held open until the server gives up on it). Whatever was sent:

* exactly one well-formed JSON reply comes back;
* a refused command changes nothing the operator sets (loop state, mode, target, ramp, manual
  power, feedforward switch) and, outside closed loop, not the heater power either;
* an accepted one leaves every limit kept;
* the socket and the loop go on (the next example connects; no fault, no stop).
"""

import json
import socket
import threading

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from cryod.service import control_socket
from cryod.service.commands import COMMANDS
from cryod.service.control_socket import MAX_LINE
from tests.fuzz_inputs import NUMBER_TEXTS, limits_kept
from tests.gated_daemon import GatedDaemon

ARGUMENTS = st.one_of(NUMBER_TEXTS, st.text(max_size=20))
SEPARATORS = st.sampled_from([" ", "\t", "  ", " \t ", "\u00a0", "\u2003", ""])
COMMAND_WORDS = st.one_of(st.sampled_from(sorted(COMMANDS) + ["reload", "STATUS", "set", "heater_off", ""]),
                          st.text(max_size=12))


@st.composite
def command_lines(draw) -> bytes:
    words = [draw(COMMAND_WORDS), *draw(st.lists(ARGUMENTS, max_size=3))]
    text = words[0]
    for word in words[1:]:
        text += draw(SEPARATORS) + word
    return draw(st.sampled_from(["", " ", "\t"])).encode() + text.encode("utf-8") + \
        draw(st.sampled_from([b"", b"\r", b" "]))


#: Commands of the right shape, with values inside and outside the configured limits (the loop's checks).
WELL_SHAPED = st.one_of(
    st.builds(lambda name, value: f"{name} {value:.6g}".encode(), st.sampled_from(["setpoint", "ramp", "manual"]),
              st.floats(min_value=-1.0, max_value=30.0)),
    st.sampled_from([b"status", b"heater-off", b"feedforward on", b"feedforward off", b"feedforward status"]))

SENT = st.one_of(                                           # the first two twice as often as the others
    WELL_SHAPED,
    WELL_SHAPED,
    command_lines(),
    command_lines(),
    st.binary(max_size=600),
    st.integers(min_value=MAX_LINE - 10, max_value=200_000).map(lambda length: b"setpoint " + b"1" * length),
    st.tuples(command_lines(), command_lines()).map(lambda pair: pair[0] + b"\n" + pair[1]),
)
ENDINGS = st.sampled_from(["newline", "newline", "half-close", "hold"])


def exchange(path, data: bytes, ending: str, result: dict) -> None:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as client:
        client.settimeout(20.0)
        client.connect(str(path))
        try:
            client.sendall(data + (b"\n" if ending == "newline" else b""))
            if ending == "half-close":
                client.shutdown(socket.SHUT_WR)
        except (BrokenPipeError, ConnectionResetError):
            pass                                            # refused before all of it was read
        received = b""
        try:
            while chunk := client.recv(65536):
                received += chunk
        except ConnectionResetError:                        # closed with our bytes unread: the reply came first
            pass
        result["received"] = received


@pytest.mark.slow
def test_fuzzed_connections_get_one_well_formed_reply_and_refusals_change_nothing(tmp_path, monkeypatch):
    monkeypatch.setattr(control_socket, "LINE_TIMEOUT_S", 0.05)     # unfinished lines are given up quickly
    with GatedDaemon(tmp_path) as daemon:
        seen = {"accepted": 0, "refused": 0, "messages": set()}

        @settings(max_examples=1000, deadline=None, database=None, suppress_health_check=list(HealthCheck))
        @given(data=SENT, ending=ENDINGS)
        def one_connection(data, ending):
            before = daemon.regulator_state()
            heater_before = daemon.gate.rows[-1].heater_W
            result = {}
            client = threading.Thread(target=exchange, args=(daemon.socket_path, data, ending, result))
            client.start()
            for _ in range(50):                              # ticks while the client waits for its answer
                client.join(0.002)
                if not client.is_alive():
                    break
                daemon.gate.run_ticks(1)
            client.join(20.0)
            assert not client.is_alive(), "no reply"
            lines = result["received"].split(b"\n")
            assert len(lines) == 2 and lines[1] == b"", f"not one reply line: {result['received'][:200]!r}"
            reply = json.loads(lines[0])
            assert isinstance(reply["ok"], bool) and isinstance(reply["message"], str) and reply["message"]
            assert daemon.loop.exit_code is None and not daemon.gate.rows[-1].state.startswith("fault")
            if reply["ok"]:
                assert isinstance(reply["status"], dict)
                assert limits_kept(daemon)
                seen["accepted"] += 1
            else:
                assert daemon.regulator_state() == before, reply["message"]
                if before[1] != "closed":
                    assert daemon.gate.rows[-1].heater_W == heater_before
                seen["refused"] += 1
            seen["messages"].add(reply["message"].split(":")[0][:30])

        one_connection()
        assert daemon.loop.exit_code is None
        assert str(daemon.loop.state) in ("closed", "manual", "off")
    # the inputs reached the loop and its checks, not only the parser
    print(f"fuzz: {seen['accepted']} accepted, {seen['refused']} refused, {len(seen['messages'])} kinds of message")
    assert seen["accepted"] >= 20 and seen["refused"] >= 500, seen
    assert daemon.result.exit_code == 0
