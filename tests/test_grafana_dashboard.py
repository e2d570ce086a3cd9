"""The Grafana dashboard (contrib/grafana/cryod-dashboard.json) queries only metrics the endpoint serves."""

import json
import math
import re

from prometheus_client import CollectorRegistry, generate_latest

from cryod.records.columns import Event, Row
from cryod.service.live_view import LiveView
from cryod.interfaces.metrics import CryodCollector
from tests.conftest import REPOSITORY

DASHBOARD = REPOSITORY / "contrib" / "grafana" / "cryod-dashboard.json"
#: PromQL's own words, which look like metric names but are not.
PROMQL = {"min_over_time", "max_over_time", "increase", "rate", "label_values", "instance", "state", "cause"}


def served_metric_names() -> set[str]:
    """Every sample name the endpoint serves while the feedforward runs and after a fault."""
    view = LiveView(period_s=0.08, line_rad_s=10.83)
    for tick in range(400):
        t = 0.08 * tick
        view(Row(time_s=t, lateness_ms=0.1, state="closed", T2_K=5.0 + 0.0015 * math.sin(10.83 * t), T5_K=3.4,
                 heater_W=0.113, setpoint_K=5.0, T2_sample_s=t,
                 control={"pi_proportional_W": 0.01, "pi_integral_W": 0.1, "ff_W": 0.02, "ff_line_K": 5e-4,
                          "ff_scale": 1.0, "ff_limit_K": 4.9e-4}))
    view(Event("fault", "instrument_timeout: no reply"))
    registry = CollectorRegistry(auto_describe=False)
    registry.register(CryodCollector(view, "test", alarms=lambda: {"deviation": 1.0, "cooler_line_lost": 0.0}))
    text = generate_latest(registry).decode()
    return {line.split("{")[0].split(" ")[0] for line in text.splitlines() if line and not line.startswith("#")}


def queries(node) -> list[str]:
    if isinstance(node, dict):
        found = [node[key] for key in ("expr", "definition") if isinstance(node.get(key), str)]
        query = node.get("query")
        if isinstance(query, dict) and isinstance(query.get("query"), str):
            found.append(query["query"])
        return found + [expr for value in node.values() for expr in queries(value)]
    if isinstance(node, list):
        return [expr for value in node for expr in queries(value)]
    return []


def test_every_metric_the_dashboard_queries_exists_and_the_page_panels_are_there():
    dashboard = json.loads(DASHBOARD.read_text())
    expressions = queries(dashboard)
    assert len(expressions) >= 15
    served = served_metric_names()
    used = set()
    for expression in expressions:
        assert expression.count("(") == expression.count(")") and expression.count("{") == expression.count("}")
        names = set(re.findall(r"\b(cryod_[a-z_]+)\b", expression))
        assert names, expression
        used |= names
    missing = used - served
    assert not missing, f"queried but not served: {sorted(missing)}"
    # the web page's panels: state, faults and alarms, T2 and its error, T5, heater with PI's part and the
    # feedforward's band, the cooler line against its limit; the alarms over time
    for name in ("cryod_state", "cryod_faults_total", "cryod_flange_temperature_kelvin", "cryod_setpoint_kelvin",
                 "cryod_flange_error_kelvin", "cryod_ptc_stage_temperature_kelvin", "cryod_heater_power_watts",
                 "cryod_heater_pi_watts", "cryod_heater_feedforward_watts", "cryod_ptc_line_amplitude_kelvin",
                 "cryod_ptc_line_limit_kelvin", "cryod_alarm"):
        assert name in used, name
    assert not PROMQL & used
    titles = [panel["title"] for panel in dashboard["panels"]]
    assert len(titles) == len(set(titles)) and len({panel["id"] for panel in dashboard["panels"]}) == len(titles)
