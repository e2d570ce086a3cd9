"""``cryod ioc`` against a dry run, through real EPICS clients: pyepics (Channel Access), p4p (pvAccess), Bluesky.

One dry run (paced at 10 times real time, so that STABLE comes in seconds) and one IOC serve the whole
module, on loopback and on ports of this test process's own (tests/ioc_bench.py). Its alarms are set
so that they stand at 5 K: ``ptc_stage_warm`` below T5 (always raised: T5 MAJOR/HIGH) and
``heater_near_top`` at 15 % of the heater (raised while regulating at 5 K, where the heater's level
is about 23 %; cleared by a heater-off).
"""

from __future__ import annotations

import asyncio
import json
import math
import re
import time

import pytest

from tests.ioc_bench import EPICS_ENVIRONMENT, IocProcess, daemon_status, ioc_lab_config, wait_until

epics = pytest.importorskip("epics")
pytestmark = pytest.mark.system

from tests.dry_run_process import DryRunProcess  # noqa: E402

PREFIX = "CRYOTEST:"
ALARMS = "alarms: {ptc_stage_warm: {threshold_K: 3.0, delay_s: 0}, heater_near_top: {fraction: 0.15, delay_s: 0}}"
MINOR, MAJOR, INVALID = 1, 2, 3
STAT_WRITE, STAT_HIGH, STAT_COMM = 2, 4, 9


def pv(name: str, **options):
    return epics.get_pv(PREFIX + name, form="time", **options)


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    folder = tmp_path_factory.mktemp("epics")
    dry_run = DryRunProcess(folder, ioc_lab_config(folder, alarms=ALARMS), "--speed", "10", "--duration", "100000",
                            interfaces=False)
    ioc = None
    try:
        wait_until(lambda: daemon_status(dry_run.socket).get("state", "").startswith("closed"), what="regulation")
        ioc = IocProcess(folder, dry_run.socket, PREFIX)
        try:
            wait_until(lambda: pv("STABLE").get(timeout=5) == 1, timeout_s=120, what="STABLE at the start setpoint")
        except AssertionError as error:
            raise AssertionError(f"{error}; STABLE connected {pv('STABLE').connected}, STABLE {pv('STABLE').get()} "
                                 f"(without the monitor {pv('STABLE').get(use_monitor=False)}), STABLE_FOR "
                                 f"{pv('STABLE_FOR').get(use_monitor=False)}, STATE {pv('STATE').get(as_string=True)}, "
                                 f"T2_AVG "
                                 f"{pv('T2_AVG').get(timeout=5)}, daemon {daemon_status(dry_run.socket)}; "
                                 f"IOC: {ioc.journal()[-1500:]}") from None
        yield dry_run, ioc
    finally:
        if ioc is not None:
            ioc.stop()
        dry_run.stop()


def test_channel_access_reads_the_readings_with_units_and_the_daemons_timestamps(bench):
    dry_run, _ = bench
    for name, unit in (("T2", "K"), ("T5", "K"), ("HEATER", "W"), ("LINE", "K"), ("LINE_LIMIT", "K"),
                       ("SETPOINT_RBV", "K"), ("SETPOINT", "K"), ("T2_AVG", "K")):
        channel = pv(name)
        assert math.isfinite(channel.get(timeout=5)), name
        assert channel.get_ctrlvars()["units"] == unit, name
    assert abs(pv("T2").get() - 5.0) < 0.01 and 3.0 < pv("T5").get() < 4.5
    assert 0.0 < pv("HEATER_MEAN").get() < pv("HEATER_MAX").get() == pytest.approx(0.5)
    assert pv("STATE").get(as_string=True) in ("closed", "closed-limited") and pv("CONNECTED").get() == 1
    assert pv("RECORD_PATH").get(as_string=True).startswith(str(dry_run.data))
    assert pv("SETPOINT").get_ctrlvars()["upper_ctrl_limit"] == math.nextafter(20.0, math.inf)   # setpoint_max_K

    # each reading's timestamp is its row's sample instant on the daemon's clock, mapped to the wall clock
    rows, hello = {}, {}

    async def subscribe(seconds: float):
        reader, writer = await asyncio.open_unix_connection(str(dry_run.socket), limit=1 << 24)
        writer.write(b"subscribe\n")
        first = json.loads(await reader.readline())
        hello.update(first["hello"])
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for row in json.loads(await reader.readline())["rows"]:
                rows.setdefault(row["T2_K"], []).append(row["time_s"])
        writer.close()

    seen = []
    monitor = epics.PV(PREFIX + "T2", form="time", callback=lambda value, timestamp, **kw: seen.append((value, timestamp)))
    monitor.wait_for_connection(5)
    asyncio.run(subscribe(2.0))
    monitor.clear_callbacks()
    offset = hello["clock_offset_s"]
    first_s = min(min(instants) for instants in rows.values()) + offset
    matched = [(timestamp, [time_s + offset for time_s in rows[value]]) for value, timestamp in seen
               if value in rows and timestamp >= first_s - 1e-6]      # what the monitor got once the rows were read
    assert len(matched) >= 10, (len(seen), len(rows))
    # a reading's value may come twice (the DMM's digits); its timestamp is one of its rows' instants
    assert all(min(abs(shown - sampled) for sampled in instants) < 1e-6 for shown, instants in matched), matched[:3]


def test_pvaccess_reads_the_same_pvs(bench):
    from p4p.client.thread import Context

    conf = {key: value for key, value in EPICS_ENVIRONMENT.items() if key.startswith("EPICS_PVA_")}
    with Context("pva", conf=conf, useenv=False) as context:
        t2, setpoint, state, stable = context.get([PREFIX + name for name in ("T2", "SETPOINT_RBV", "STATE",
                                                                                "STABLE")], timeout=5)
        assert abs(float(t2) - pv("T2").get()) < 0.01
        assert t2.raw.display.units == "K" and float(setpoint) == pv("SETPOINT_RBV").get()
        assert state.raw.value.choices[state.raw.value.index] in ("closed", "closed-limited")
        assert int(stable.raw.value.index) in (0, 1)


def test_a_put_above_setpoint_max_is_refused_in_epics_terms_and_the_record_shows_what_the_daemon_holds(bench):
    dry_run, _ = bench
    setpoint = pv("SETPOINT")
    held = daemon_status(dry_run.socket)["target_K"]
    setpoint.put(30.0, wait=True, timeout=10)
    wait_until(lambda: setpoint.get(use_monitor=False) == held and setpoint.severity == MINOR, timeout_s=10,
               what="the refusal's alarm")
    assert setpoint.status == STAT_WRITE
    assert "refused: outside 3..20 K" in pv("MESSAGE").get(as_string=True, use_monitor=False)
    assert daemon_status(dry_run.socket)["target_K"] == held                    # nothing changed
    assert "command setpoint refused" in dry_run.journal() and "by EPICS client " in dry_run.journal()
    setpoint.put(held, wait=True, timeout=60)                                   # a put taken clears the alarm
    wait_until(lambda: setpoint.severity == 0, timeout_s=10, what="the alarm's end")


def test_a_put_with_completion_on_setpoint_returns_only_when_stable(bench):
    dry_run, _ = bench
    stable, setpoint = pv("STABLE"), pv("SETPOINT")
    seen_unstable = []
    stable.add_callback(lambda value, **kw: seen_unstable.append(value) if value == 0 else None)
    started = time.monotonic()
    assert setpoint.put(5.02, wait=True, timeout=120) == 1
    took_s = time.monotonic() - started
    assert stable.get(use_monitor=False) == 1 and seen_unstable, took_s          # it was not stable, then it was
    status = daemon_status(dry_run.socket)
    assert status["target_K"] == 5.02 and abs(status["T2_average_K"] - 5.02) < 5e-4
    assert pv("SETPOINT_RBV").get(use_monitor=False) == 5.02
    stable.clear_callbacks()


def test_severities_follow_cryods_alarms(bench):
    dry_run, _ = bench
    t5, heater, heater_off = pv("T5"), pv("HEATER"), pv("HEATER_OFF")
    wait_until(lambda: (t5.severity, t5.status) == (MAJOR, STAT_HIGH), what="ptc_stage_warm on T5")
    wait_until(lambda: (heater.severity, heater.status) == (MINOR, STAT_HIGH), what="heater_near_top on HEATER")
    assert "heater_near_top raised" in pv("ALARMS").get(as_string=True, use_monitor=False)
    heater_off.put(1, wait=True)
    wait_until(lambda: heater.severity == 0, what="heater_near_top cleared by the heater-off")
    assert pv("STATE").get(as_string=True, use_monitor=False) == "off" and heater_off.get(use_monitor=False) == 1
    assert "heater_near_top" not in pv("ALARMS").get(as_string=True, use_monitor=False)
    heater_off.put(0, wait=True)                                                # regulate again at the last target
    wait_until(lambda: daemon_status(dry_run.socket)["state"].startswith("closed"), what="regulation again")
    wait_until(lambda: heater.severity == MINOR, what="heater_near_top raised again")


def test_a_bluesky_plan_moves_then_counts(bench):
    from bluesky import RunEngine
    from bluesky import plan_stubs as bps
    from bluesky import plans as bp
    from bluesky.run_engine import call_in_bluesky_event_loop
    from ophyd_async.plan_stubs import ensure_connected

    from cryod.bluesky import Cryostat

    cryostat = Cryostat(PREFIX, name="cryostat")
    engine = RunEngine({})
    documents = []
    engine.subscribe(lambda name, document: documents.append((name, document)))
    engine(ensure_connected(cryostat))
    engine(bps.mv(cryostat, 5.01))
    assert pv("STABLE").get(use_monitor=False) == 1 and pv("SETPOINT_RBV").get(use_monitor=False) == 5.01
    engine(bp.count([cryostat], num=3))
    names = [name for name, _ in documents]
    assert names == ["start", "descriptor", "event", "event", "event", "stop"], names
    (descriptor,) = [document for name, document in documents if name == "descriptor"]
    keys = descriptor["data_keys"]
    assert {"cryostat-flange", "cryostat-ptc_stage", "cryostat-heater", "cryostat-line"} <= set(keys)
    assert keys["cryostat-flange"]["units"] == "K" and keys["cryostat-heater"]["units"] == "W"
    assert keys["cryostat-flange"]["source"] == f"ca://{PREFIX}T2"
    assert descriptor["configuration"]["cryostat"]["data"]["cryostat-target"] == 5.01
    events = [document for name, document in documents if name == "event"]
    assert all(abs(event["data"]["cryostat-flange"] - 5.01) < 0.01 for event in events)
    assert documents[-1][1]["exit_status"] == "success"
    # on the RunEngine's own event loop, where the device's channels live (a loop of its own would close under them)
    limits = call_in_bluesky_event_loop(cryostat.limits())
    assert limits == (math.nextafter(3.0, -math.inf), math.nextafter(20.0, math.inf))


def test_the_ioc_killed_and_started_again_leaves_the_daemon_regulating(bench):
    dry_run, ioc = bench
    before = daemon_status(dry_run.socket)
    level_before = pv("HEATER_MEAN").get(use_monitor=False)
    journal_before = len(dry_run.journal())
    ioc.kill()
    wait_until(lambda: pv("T2").connected is False, timeout_s=30, what="the PVs gone")
    time.sleep(1.0)
    ioc.start()
    wait_until(lambda: pv("T2").connected and pv("CONNECTED").get(timeout=5) == 1, timeout_s=30,
               what="the PVs back")
    after = daemon_status(dry_run.socket)
    assert after["state"].startswith("closed") and after["target_K"] == before["target_K"]
    assert after["overruns"] == before["overruns"], (before["overruns"], after["overruns"])
    assert abs(pv("HEATER_MEAN").get(use_monitor=False) - level_before) < 0.01      # the heater's level as it was
    assert not re.search(r"command \S+ (accepted|refused)", dry_run.journal()[journal_before:])  # nothing asked
