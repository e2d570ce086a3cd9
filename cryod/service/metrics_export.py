"""The daemon's live state as Prometheus metrics, for labs that watch many cryostats.

Off unless the configuration gives ``metrics.address`` (``host:port``). The
endpoint is prometheus_client's own HTTP server on a thread of its own; each
scrape reads a :class:`~cryod.service.live_view.LiveView` snapshot, so the loop
does no work for it. Metric names follow Prometheus' conventions (base units,
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
    cryod_info{version, cryostat}          1, with the version and the configured cryostat name

Examples
--------
>>> parse_address("127.0.0.1:9477")
('127.0.0.1', 9477)
"""

from __future__ import annotations

import math

from prometheus_client import CollectorRegistry, start_http_server
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

from cryod import __version__
from cryod.service.faults import FaultCause
from cryod.service.live_view import LiveView
from cryod.service.states import LoopState

#: States reported by ``cryod_state``: the loop's (:class:`cryod.service.states.LoopState`), the start,
#: regulation held at a heater bound, and a fault (its cause is in ``cryod_faults_total``).
STATES = ("starting", *(str(state) for state in LoopState), "closed-limited", "fault")


def parse_address(text: str) -> tuple[str, int]:
    """``host:port`` (``[v6]:port`` for IPv6) as (host, port); ValueError says what is wrong."""
    host, separator, port = str(text).rpartition(":")
    if not separator or not host:
        raise ValueError(f"{text!r} is not host:port (for example 127.0.0.1:9477)")
    if not port.isascii() or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"{text!r}: the port must be a number from 1 to 65535")
    return host.strip("[]"), int(port)


class CryodCollector:
    """A prometheus_client collector reading a :class:`LiveView` at each scrape.

    Parameters
    ----------
    view : LiveView
    cryostat : str
        The name the lab gives this cryostat (the ``cryostat`` label of ``cryod_info``).
    """

    def __init__(self, view: LiveView, cryostat: str = ""):
        self.view = view
        self.cryostat = cryostat

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


class MetricsEndpoint:
    """The HTTP endpoint serving :class:`CryodCollector` (start, stop).

    Parameters
    ----------
    view : LiveView
    address : str
        ``host:port`` to listen on (port 0: any free port; see :attr:`port`).
    cryostat : str
        Label of ``cryod_info``.
    """

    def __init__(self, view: LiveView, address: str, cryostat: str = ""):
        self.host, self.port = parse_address(address) if not str(address).endswith(":0") \
            else (str(address).rpartition(":")[0], 0)
        self.registry = CollectorRegistry(auto_describe=False)
        self.registry.register(CryodCollector(view, cryostat))
        self._server = None
        self._thread = None

    def start(self) -> None:
        """Listen; an address in use or not on this host raises OSError naming it."""
        try:
            self._server, self._thread = start_http_server(self.port, addr=self.host, registry=self.registry)
        except OSError as error:
            raise OSError(f"metrics.address {self.host}:{self.port}: {error.strerror or error}") from error
        self.port = self._server.server_port

    def stop(self) -> None:
        """Stop serving and close the port."""
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._thread.join(timeout=5.0)
            self._server = None
