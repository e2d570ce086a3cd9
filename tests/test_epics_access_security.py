"""The lab's EPICS access security file deciding who writes, on an IOC of its own.

A module apart from ``test_epics_ioc.py``: every IOC of this test process serves on the same ports
(tests/ioc_bench.py), and that module's IOC lives until the module ends; a second IOC beside it would
share its UDP search port, and a search could reach the one without these PVs.
"""

from __future__ import annotations

import math
import time

import pytest

from tests.conftest import REPOSITORY
from tests.ioc_bench import IocProcess, daemon_status, ioc_lab_config, wait_until

epics = pytest.importorskip("epics")
pytestmark = pytest.mark.system

from tests.dry_run_process import DryRunProcess  # noqa: E402


@pytest.mark.slow
def test_the_labs_access_security_file_decides_who_writes(tmp_path):
    """contrib/epics/cryod.acf as ioc.access_security_file: this test's user is not among its operators, so
    EPICS refuses the put (no write access) and the daemon never hears of it; reads go on."""
    import getpass
    import shutil

    acf = tmp_path / "cryod.acf"
    shutil.copy(REPOSITORY / "contrib" / "epics" / "cryod.acf", acf)
    assert getpass.getuser() not in ("alice", "bob", "cryod")
    prefix = "CRYOACF:"
    config = ioc_lab_config(tmp_path, prefix=prefix)
    text = config.read_text().replace("stable_hold_s: 5}", "stable_hold_s: 5, access_security_file: cryod.acf}")
    config.write_text(text)
    dry_run = DryRunProcess(tmp_path, config, "--speed", "10", "--duration", "100000", interfaces=False)
    ioc = None
    try:
        wait_until(lambda: daemon_status(dry_run.socket).get("state", "").startswith("closed"), what="regulation")
        ioc = IocProcess(tmp_path, dry_run.socket, prefix)
        assert "the lab's access security file" in ioc.journal()
        setpoint = epics.get_pv(prefix + "SETPOINT")
        assert setpoint.wait_for_connection(10) and math.isfinite(epics.caget(prefix + "T2", timeout=5))
        assert setpoint.write_access is False
        held = daemon_status(dry_run.socket)["target_K"]
        try:
            setpoint.put(5.3, wait=True, timeout=5)       # pyepics may say so or raise; EPICS refuses it either way
        except Exception:
            pass
        time.sleep(1.0)
        assert daemon_status(dry_run.socket)["target_K"] == held and "command setpoint" not in dry_run.journal()
    finally:
        if ioc is not None:
            ioc.stop()
        dry_run.stop()
