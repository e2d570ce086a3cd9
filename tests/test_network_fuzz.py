"""Generated input against the web page and the Lake Shore 336 command set (slow suite: ``pytest -m slow``).

As tests/test_control_socket_fuzz.py does for the control socket: the daemon runs on the simulated
bench with its loop held between ticks, both interfaces on and writable. Each example is one
connection with random bytes, messages built from the 336's words and arguments of every kind,
overlong lines, HTTP requests with random methods, paths, headers and bodies, and connections
left unfinished. Whatever was sent:

* the 336 interface answers only in CR LF terminated ASCII lines, the web page only in HTTP;
* nothing the operator sets changes except through an accepted command within the limits;
* the interfaces and the loop go on (the next example connects; no fault, no stop).
"""

import socket
import threading

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from cryod.config import Lakeshore336Config, WebConfig
from tests.gated_daemon import GatedDaemon
from tests.fuzz_inputs import NUMBER_TEXTS, limits_kept

TOKEN = "0123456789abcdef0123456789abcdef"
WORDS = st.sampled_from(["*IDN?", "*OPC?", "*ESR?", "*CLS", "*RST", "KRDG?", "SRDG?", "RDGST?", "SETP", "SETP?",
                         "RAMP", "RAMP?", "RAMPST?", "HTR?", "HTRST?", "RANGE", "RANGE?", "OUTMODE?", "PID?",
                         "PID", "MOUT?", "INTYPE?", "CRVHDR?", "setp", "", "KRDG"])
ARGUMENT = st.one_of(NUMBER_TEXTS, st.sampled_from(["A", "B", "C", "D", "E", "0", "1", "2", "5", "a"]),
                     st.text(max_size=8))


@st.composite
def lakeshore_messages(draw) -> bytes:
    parts = []
    for _ in range(draw(st.integers(1, 4))):
        arguments = draw(st.lists(ARGUMENT, max_size=3))
        parts.append(draw(WORDS) + (" " + ",".join(arguments) if arguments else ""))
    return ";".join(parts).encode("utf-8", "replace")


LAKESHORE_SENT = st.one_of(lakeshore_messages(), lakeshore_messages(), st.binary(max_size=600),
                           st.integers(200, 20_000).map(lambda length: b"SETP 1," + b"1" * length))
HTTP_SENT = st.one_of(
    st.builds(lambda method, path, headers, body: (f"{method} {path} HTTP/1.1\r\n" + "".join(
        f"{name}: {value}\r\n" for name, value in headers) + "\r\n").encode("utf-8", "replace") + body,
              st.sampled_from(["GET", "POST", "PUT", "HEAD", "get", "POST\x00"]),
              st.one_of(st.sampled_from(["/", "/api/status", "/api/history", "/api/command", "/app.js", "/x"]),
                        st.text(max_size=30)),
              st.lists(st.tuples(st.sampled_from(["Host", "Content-Length", "X-Cryod-Token", "Origin", "A"]),
                                 st.one_of(st.sampled_from([TOKEN, "5", "20", "http://evil"]), st.text(max_size=20))),
                       max_size=5),
              st.one_of(st.just(b""), st.just(b'{"command": "setpoint 30"}'), st.just(b'{"command": "setpoint 5.1"}'),
                        st.binary(max_size=50))),
    st.binary(max_size=600))


def exchange(port: int, data: bytes, finish: bool, result: dict) -> None:
    with socket.create_connection(("127.0.0.1", port), timeout=20) as client:
        try:
            client.sendall(data + (b"\n" if finish else b""))
            client.shutdown(socket.SHUT_WR)
        except OSError:
            pass
        received = b""
        try:
            while chunk := client.recv(65536):
                received += chunk
        except OSError:
            pass
        result["received"] = received


@pytest.mark.slow
def test_fuzzed_connections_to_both_interfaces_change_nothing_they_may_not(tmp_path):
    token = tmp_path / "web.token"
    token.write_text(TOKEN)
    token.chmod(0o600)
    sections = {"web": WebConfig("127.0.0.1:0", True, token), "lakeshore336": Lakeshore336Config("127.0.0.1:0", True)}
    with GatedDaemon(tmp_path, sections=sections) as daemon:
        ports = {name: daemon.port(name) for name in ("web", "lakeshore336")}

        @settings(max_examples=600, deadline=None, database=None, suppress_health_check=list(HealthCheck))
        @given(which=st.sampled_from(["web", "lakeshore336"]), lakeshore=LAKESHORE_SENT, http=HTTP_SENT,
               finish=st.booleans())
        def one_connection(which, lakeshore, http, finish):
            result = {}
            client = threading.Thread(target=exchange, args=(ports[which], lakeshore if which == "lakeshore336"
                                                             else http, finish, result))
            client.start()
            for _ in range(100):
                client.join(0.002)
                if not client.is_alive():
                    break
                daemon.gate.run_ticks(1)
            client.join(20.0)
            assert not client.is_alive(), "the interface neither answered nor closed"
            received = result["received"]
            if which == "lakeshore336":
                assert received == b"" or received.endswith(b"\r\n"), received[:200]
                received.decode("ascii")
            else:
                assert received == b"" or received.startswith(b"HTTP/1.1 "), received[:200]
                assert b"HTTP/1.1 5" not in received[:12], received[:200]     # never the server's own failure
            assert limits_kept(daemon)
            assert daemon.loop.exit_code is None and not daemon.gate.rows[-1].state.startswith("fault")

        one_connection()
        assert daemon.loop.exit_code is None
    assert daemon.result.exit_code == 0
