"""The interfaces' HTTP server keeps its door: heads in time, room made for real clients, streams that read.

The server runs in the test's process on an event loop of its own thread, with a route that answers
``/`` and streams ``/events``; the clients are real sockets and Python's http.client. The limits are
the module's, made small where the test would otherwise open hundreds of connections.
"""

import asyncio
import http.client
import socket
import threading
import time

import pytest

from cryod.interfaces import http_server
from cryod.interfaces.http_server import EventStream, HttpServer, Response, host_of

#: Processes, real sockets or real time: the second step of the suite (pytest -m system).
pytestmark = pytest.mark.system


class Served:
    """An HttpServer on 127.0.0.1 on an event loop of its own thread."""

    def __init__(self, **options):
        self.loop = asyncio.new_event_loop()
        self.frames_sent = 0

        async def route(request):
            if request.path == "/events":
                return EventStream(self._frames)
            if request.path == "/slow":
                await asyncio.sleep(2)
            return Response(200, b'{"ok": true}')

        self.server = HttpServer("test page", "127.0.0.1:0", route, allowed_hosts={"127.0.0.1", "localhost"},
                                 **options)
        ready = threading.Event()

        def run():
            asyncio.set_event_loop(self.loop)
            self.loop.run_until_complete(self.server.start())
            ready.set()
            self.loop.run_forever()

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()
        ready.wait(10)
        self.port = self.server.port

    async def _frames(self):
        while True:
            self.frames_sent += 1
            yield b"data: " + b"x" * 4000 + b"\n\n"
            await asyncio.sleep(0.01)

    def get(self, path="/", host="127.0.0.1"):
        connection = http.client.HTTPConnection("127.0.0.1", self.port, timeout=10)
        try:
            connection.request("GET", path, headers={"Host": host})
            response = connection.getresponse()
            return response.status, response.read()
        finally:
            connection.close()

    def close(self):
        asyncio.run_coroutine_threadsafe(self.server.stop(), self.loop).result(10)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)


@pytest.fixture
def served():
    servers = []

    def start(**options):
        options.setdefault("max_connections", 8)
        server = Served(**options)
        servers.append(server)
        return server

    yield start
    for server in servers:
        server.close()


def test_a_head_not_sent_in_time_is_answered_408_and_its_place_freed(served, monkeypatch):
    monkeypatch.setattr(http_server, "HEAD_TIMEOUT_S", 0.5)
    server = served()
    with socket.create_connection(("127.0.0.1", server.port), timeout=10) as slow:
        slow.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        started = time.monotonic()
        assert slow.recv(100).startswith(b"HTTP/1.1 408")
        assert 0.4 < time.monotonic() - started < 3.0
    deadline = time.monotonic() + 5                 # the place is given back once the answer is out
    while server.server.places:
        assert time.monotonic() < deadline, server.server.places
        time.sleep(0.01)
    assert server.server.counts["head_timeouts"] == 1


def test_connections_that_say_nothing_however_many_keep_no_real_client_out(served):
    """300 connections that never finish their head (slowloris) against 8 places: each real request in between
    is answered, by closing the one that has waited longest."""
    server = served()
    quiet = []
    answered = 0
    try:
        for index in range(300):
            connection = socket.create_connection(("127.0.0.1", server.port), timeout=10)
            connection.sendall(b"GET / HTTP/1.1\r\nX-Slow: ")
            quiet.append(connection)
            if index % 10 == 9:
                status, body = server.get()
                answered += status == 200
        assert answered == 30
        assert server.server.counts["closed_for_room"] >= 290 and len(server.server.places) <= 8
    finally:
        for connection in quiet:
            connection.close()


def test_when_every_place_is_being_answered_one_more_is_told_503(served):
    server = served(max_connections=2)
    results = []
    slow = [threading.Thread(target=lambda: results.append(server.get("/slow"))) for _ in range(2)]
    for thread in slow:
        thread.start()
    deadline = time.monotonic() + 5
    while sum(place.state == "being answered" for place in server.server.places.values()) < 2:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    status, body = server.get()
    assert status == 503 and b"busy" in body
    for thread in slow:
        thread.join(10)
    assert [status for status, _ in results] == [200, 200]


def test_an_event_stream_whose_client_reads_nothing_is_closed_within_seconds(served):
    server = served()
    with socket.create_connection(("127.0.0.1", server.port), timeout=10) as stream:
        stream.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        stream.sendall(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        started = time.monotonic()
        deadline = started + 20
        while server.server.counts["closed_not_reading"] == 0:
            assert time.monotonic() < deadline, "a stream nobody reads was not closed"
            time.sleep(0.05)
        assert time.monotonic() - started < http_server.STREAM_STALL_S + 5.0
    reader = socket.create_connection(("127.0.0.1", server.port), timeout=10)
    try:                                            # one that reads goes on
        reader.sendall(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        received = 0
        until = time.monotonic() + http_server.STREAM_STALL_S + 2.0
        while time.monotonic() < until:
            received += len(reader.recv(65536))
        assert received > 100_000 and server.server.counts["closed_not_reading"] == 1
    finally:
        reader.close()


def test_streams_beyond_their_share_give_way_and_plain_requests_keep_their_places(served):
    server = served(max_connections=8, max_streams=3)
    streams = [socket.create_connection(("127.0.0.1", server.port), timeout=10) for _ in range(5)]
    try:
        for connection in streams:
            connection.sendall(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            time.sleep(0.05)
        time.sleep(0.2)
        assert server.server.streams == 3 and server.server.counts["closed_for_room"] == 2
        assert server.get()[0] == 200
    finally:
        for connection in streams:
            connection.close()


def test_a_host_this_server_does_not_answer_for_is_refused(served):
    server = served()
    assert server.get(host=f"127.0.0.1:{server.port}")[0] == 200
    assert server.get(host=f"localhost:{server.port}")[0] == 200
    status, body = server.get(host="attacker.example")
    assert status == 421 and b"does not answer for 'attacker.example'" in body
    assert [host_of(header) for header in ("[::1]:8080", "LocalHost:80", "::1", "example")] == \
        ["::1", "localhost", "::1", "example"]
