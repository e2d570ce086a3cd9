"""The daemon's live state as Prometheus metrics, for labs that watch many cryostats.

Off unless the configuration gives ``metrics.address`` (``host:port``). The
endpoint serves every client from one thread with an asyncio event loop (not a
thread per connection, as prometheus_client's own server does: 800 idle
connections would be 800 threads competing with the loop); each scrape reads a
:class:`~cryod.service.live_view.LiveView` snapshot, so the loop does no work for
it, and prometheus_client encodes it. One request per connection: a client has
:data:`REQUEST_TIMEOUT_S` to send it, and beyond :data:`MAX_CONNECTIONS` open at
once the one that has waited longest without sending it is closed to make room
(:class:`cryod.service.async_clients.ConnectionBook`). Metric names follow Prometheus' conventions (base units,
``_total`` for counters)::

    cryod_flange_temperature_kelvin        T2
    cryod_ptc_stage_temperature_kelvin     T5
    cryod_setpoint_kelvin                  (absent while the loop has no setpoint)
    cryod_flange_error_kelvin              T2 minus the setpoint
    cryod_heater_power_watts               (absent when the heater's state is unknown)
    cryod_ptc_line_amplitude_kelvin        the cooler line on T2
    cryod_ptc_line_limit_kelvin            the least line any heater waveform can leave (feedforward)
    cryod_heater_pi_watts                  PI's part of the heater power
    cryod_heater_feedforward_watts         the feedforward waveform's part
    cryod_loop_lateness_seconds            the last tick's lateness
    cryod_loop_ticks_total, cryod_loop_overruns_total
    cryod_faults_total{cause}              faults since start, by cause
    cryod_state{state}                     1 for the loop's state, 0 for the others
    cryod_alarm{name}                      1 for each alarm raised or latched, 0 for the others that are on
    cryod_info{version, cryostat}          1, with the version and the configured cryostat name

Examples
--------
>>> metrics_address("127.0.0.1:9477")
('127.0.0.1', 9477)
"""

from __future__ import annotations

import asyncio
import logging
import math
import socket

from prometheus_client import CollectorRegistry
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.exposition import choose_encoder

from cryod import __version__
from cryod.listen_address import parse_address
from cryod.service.async_clients import ClientsThread, ConnectionBook
from cryod.service.faults import FaultCause
from cryod.service.live_view import LiveView
from cryod.service.states import LoopState

log = logging.getLogger("cryod.metrics")

#: Connections open at once; one more closes the one that has waited longest for its request.
MAX_CONNECTIONS = 64
#: How long a client has to send its request (line and headers), s.
REQUEST_TIMEOUT_S = 5.0
#: Longest request (line and headers), bytes.
MAX_REQUEST_BYTES = 8192
#: The paths that give the metrics.
METRICS_PATHS = ("/metrics", "/")

#: States reported by ``cryod_state``: the loop's (:class:`cryod.service.states.LoopState`), the start,
#: regulation held at a heater bound, and a fault (its cause is in ``cryod_faults_total``).
STATES = ("starting", *(str(state) for state in LoopState), "closed-limited", "fault")


def metrics_address(text: str) -> tuple[str, int]:
    """``metrics.address`` (``host:port``, ``[v6]:port``; any host name) as (host, port); ValueError says what is wrong."""
    return parse_address(text, host_names=True)


class CryodCollector:
    """A prometheus_client collector reading a :class:`LiveView` at each scrape.

    Parameters
    ----------
    view : LiveView
    cryostat : str
        The name the lab gives this cryostat (the ``cryostat`` label of ``cryod_info``).
    alarms : callable, optional
        Returns ``{name: 1.0 or 0.0}`` for each alarm that is on
        (:meth:`cryod.service.alarms.AlarmMonitor.states`).
    """

    def __init__(self, view: LiveView, cryostat: str = "", alarms=None):
        self.view = view
        self.cryostat = cryostat
        self.alarms = alarms

    def collect(self):
        snapshot = self.view.snapshot()
        info = GaugeMetricFamily("cryod_info", "cryod version and the cryostat it regulates",
                                 labels=["version", "cryostat"])
        info.add_metric([__version__, self.cryostat], 1.0)
        yield info
        for name, key, scale, help_text in (
                ("cryod_flange_temperature_kelvin", "T2_K", 1.0, "flange temperature T2"),
                ("cryod_ptc_stage_temperature_kelvin", "T5_K", 1.0, "cooler second-stage temperature T5"),
                ("cryod_setpoint_kelvin", "setpoint_K", 1.0, "setpoint in use (ramp included)"),
                ("cryod_flange_error_kelvin", "error_K", 1.0, "T2 minus the setpoint"),
                ("cryod_heater_power_watts", "heater_W", 1.0, "heater power commanded and confirmed"),
                ("cryod_ptc_line_amplitude_kelvin", "line_amplitude_K", 1.0,
                 "amplitude of the cooler line on T2"),
                ("cryod_ptc_line_limit_kelvin", "line_limit_K", 1.0,
                 "least cooler line on T2 any heater waveform can leave at this setpoint"),
                ("cryod_heater_pi_watts", "pi_W", 1.0, "PI's part of the heater power"),
                ("cryod_heater_feedforward_watts", "ff_W", 1.0, "the feedforward waveform's part of the heater power"),
                ("cryod_loop_lateness_seconds", "lateness_ms", 1e-3, "lateness of the last tick")):
            value = snapshot.get(key, math.nan)
            if value is not None and math.isfinite(value):
                yield GaugeMetricFamily(name, help_text, value=value * scale)
        yield CounterMetricFamily("cryod_loop_ticks", "loop ticks since start", value=snapshot["ticks"])
        yield CounterMetricFamily("cryod_loop_overruns", "ticks that overran the period",
                                  value=snapshot["overruns"])
        faults = CounterMetricFamily("cryod_faults", "faults since start, by cause", labels=["cause"])
        counts = snapshot["faults"]
        for cause in [str(cause) for cause in FaultCause] + sorted(set(counts) - {str(c) for c in FaultCause}):
            faults.add_metric([cause], counts.get(cause, 0))
        yield faults
        state = GaugeMetricFamily("cryod_state", "1 for the loop's state", labels=["state"])
        current = str(snapshot["state"]).split(":", 1)[0]
        for name in STATES + ((current,) if current not in STATES else ()):
            state.add_metric([name], 1.0 if name == current else 0.0)
        yield state
        if self.alarms is not None:
            alarms = GaugeMetricFamily("cryod_alarm", "1 while the alarm is raised or latched", labels=["name"])
            for name, value in self.alarms().items():
                alarms.add_metric([name], value)
            yield alarms


class MetricsEndpoint:
    """The HTTP endpoint serving :class:`CryodCollector` (start, stop), from one thread.

    Parameters
    ----------
    view : LiveView
    address : str
        ``host:port`` to listen on (port 0: any free port; see :attr:`port`).
    cryostat : str
        Label of ``cryod_info``.
    alarms : callable, optional
        The alarms' states for ``cryod_alarm`` (:class:`CryodCollector`).
    max_connections : int, optional
        Connections open at once (default :data:`MAX_CONNECTIONS`).
    request_timeout_s : float, optional
        How long a client has to send its request (default :data:`REQUEST_TIMEOUT_S`).
    """

    def __init__(self, view: LiveView, address: str, cryostat: str = "", max_connections: int = MAX_CONNECTIONS,
                 request_timeout_s: float = REQUEST_TIMEOUT_S, alarms=None):
        self.host, self.port = metrics_address(address) if not str(address).endswith(":0") \
            else (str(address).rpartition(":")[0], 0)
        self.registry = CollectorRegistry(auto_describe=False)
        self.registry.register(CryodCollector(view, cryostat, alarms))
        self.request_timeout_s = request_timeout_s
        #: The connections open now, the most at once, those closed to make room.
        self.connections = ConnectionBook(max_connections)
        self._clients = ClientsThread("metrics endpoint", lambda listener: asyncio.start_server(
            self._serve_client, sock=listener, limit=MAX_REQUEST_BYTES))

    def start(self) -> None:
        """Listen; an address in use or not on this host raises OSError naming it."""
        try:
            family = socket.getaddrinfo(self.host, self.port, type=socket.SOCK_STREAM)[0][0]
            listener = socket.socket(family, socket.SOCK_STREAM)
            listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                listener.bind((self.host, self.port))
                listener.listen(128)
            except OSError:
                listener.close()
                raise
        except OSError as error:
            raise OSError(f"metrics.address {self.host}:{self.port}: {error.strerror or error}") from error
        self.port = listener.getsockname()[1]
        self._clients.start(listener)

    async def _serve_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        place = self.connections.arrived()
        try:
            if place is ConnectionBook.FULL:        # every connection open is being answered: no room now
                return
            try:
                head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), self.request_timeout_s)
            except (asyncio.IncompleteReadError, asyncio.TimeoutError, asyncio.LimitOverrunError, OSError):
                return                          # no request (in time, or at all): nothing to answer
            self.connections.request_received()
            status, headers, body = self._answer(head)
            lines = [f"HTTP/1.1 {status}", *(f"{name}: {value}" for name, value in headers),
                     f"Content-Length: {len(body)}", "Connection: close", "", ""]
            writer.write("\r\n".join(lines).encode("latin-1") + (b"" if head.startswith(b"HEAD ") else body))
            await asyncio.wait_for(writer.drain(), self.request_timeout_s)
        except (asyncio.CancelledError, asyncio.TimeoutError, OSError):
            pass                                # closed for room, the daemon stopping, a client gone
        except Exception as error:              # one client's trouble never ends the endpoint
            log.warning("metrics endpoint: answering a client failed: %s: %s", type(error).__name__, error)
        finally:
            writer.close()
            self.connections.left()

    def _answer(self, head: bytes) -> tuple[str, list[tuple[str, str]], bytes]:
        """Status, headers and body for one request (its line and headers)."""
        request_line, *header_lines = head.decode("latin-1").split("\r\n")
        parts = request_line.split()
        if len(parts) != 3 or not parts[2].startswith("HTTP/"):
            return "400 Bad Request", [("Content-Type", "text/plain")], b"not an HTTP request\n"
        method, target, _ = parts
        if method not in ("GET", "HEAD"):
            return "405 Method Not Allowed", [("Allow", "GET, HEAD"), ("Content-Type", "text/plain")], \
                b"GET /metrics\n"
        if target.split("?", 1)[0] not in METRICS_PATHS:
            return "404 Not Found", [("Content-Type", "text/plain")], b"the metrics are at /metrics\n"
        accept = next((line.split(":", 1)[1].strip() for line in header_lines
                       if line.lower().startswith("accept:")), "")
        encoder, content_type = choose_encoder(accept)
        return "200 OK", [("Content-Type", content_type)], encoder(self.registry)

    def stop(self) -> None:
        """Stop serving and close the port."""
        self._clients.stop()
