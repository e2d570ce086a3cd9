"""The daemon's live state as Prometheus metrics, for labs that watch many cryostats.

Off unless the configuration gives ``metrics.address`` (``host:port``). Served by the interfaces
process on an :class:`~cryod.interfaces.http_server.HttpServer` (every client on one event loop, a
bound on connections, the connection that has waited longest for its request closed to make room);
each scrape reads the :class:`~cryod.service.live_view.LiveView` the interfaces process keeps from
the daemon's stream, so the daemon does no work for it, and prometheus_client encodes it. Metric
names follow Prometheus' conventions (base units, ``_total`` for counters)::

    cryod_flange_temperature_kelvin        T2
    cryod_ptc_stage_temperature_kelvin     T5
    cryod_setpoint_kelvin                  (absent while the loop has no setpoint)
    cryod_flange_error_kelvin              T2 minus the setpoint
    cryod_heater_power_watts               (absent when the heater's state is unknown)
    cryod_heater_level_watts               its power over the last 10 cooler cycles
    cryod_ptc_line_amplitude_kelvin        the cooler line on T2 (harmonics 1-6 together)
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

import logging
import math

from prometheus_client import CollectorRegistry
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.exposition import choose_encoder

from cryod import __version__
from cryod.interfaces.http_server import HttpServer, Request, Response
from cryod.listen_address import parse_address
from cryod.service.faults import FaultCause
from cryod.service.live_view import LiveView
from cryod.service.states import LoopState

log = logging.getLogger("cryod.metrics")

#: Connections open at once; one more closes the one that has waited longest for its request.
MAX_CONNECTIONS = 64
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
                ("cryod_heater_level_watts", "heater_mean_W", 1.0,
                 "heater power over the last 10 cooler cycles (without the feedforward's waveform)"),
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
    """The HTTP endpoint serving :class:`CryodCollector` on the interfaces process's event loop.

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
    """

    def __init__(self, view: LiveView, address: str, cryostat: str = "", alarms=None,
                 max_connections: int = MAX_CONNECTIONS):
        self.registry = CollectorRegistry(auto_describe=False)
        self.registry.register(CryodCollector(view, cryostat, alarms))
        self.server = HttpServer("metrics endpoint", address, self.route, max_connections, max_body=0,
                                 error_body=lambda status, message: (message.encode("utf-8") + b"\n", "text/plain"))

    @property
    def port(self) -> int:
        return self.server.port

    async def start(self) -> None:
        """Listen; an address in use or not on this host raises OSError naming ``metrics.address``."""
        try:
            await self.server.start()
        except OSError as error:
            raise OSError(f"metrics.address {self.server.host}:{self.server.port}: {error.strerror or error}") \
                from error

    async def stop(self) -> None:
        await self.server.stop()

    async def route(self, request: Request) -> Response:
        """The metrics for ``GET /metrics`` (or ``/``), in the format the client accepts."""
        if request.method not in ("GET", "HEAD"):
            return Response(405, b"GET /metrics\n", "text/plain", (("Allow", "GET, HEAD"),))
        if request.path not in METRICS_PATHS:
            return Response(404, b"the metrics are at /metrics\n", "text/plain")
        encoder, content_type = choose_encoder(request.headers.get("accept", ""))
        return Response(200, b"" if request.method == "HEAD" else encoder(self.registry), content_type)


__all__ = ["CryodCollector", "MetricsEndpoint", "metrics_address", "STATES"]
