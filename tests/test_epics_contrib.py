"""The PV table is the one list: the names checks rely on, the docs' table, the Phoebus screen, the archiver's
list and policy, the example access security file EPICS reads."""

import importlib.util
import json
import re
import subprocess
import sys
import xml.etree.ElementTree as ElementTree

from cryod.ioc.pv_table import LONGEST_NAME, PVS, READINGS, SETTINGS
from tests.conftest import REPOSITORY

CONTRIB = REPOSITORY / "contrib" / "epics"
#: The names after the prefix that checks outside cryod rely on (docs/reference/epics-pvs.md).
CONTRACT = ("T2", "T5", "HEATER", "SETPOINT", "SETPOINT_RBV", "STATE", "LINE", "LINE_LIMIT", "HEATER_OFF", "STABLE")


def test_the_contract_names_are_served_with_their_units_and_fit_a_record_name():
    assert set(CONTRACT) <= set(PVS)
    assert (PVS["HEATER"].unit, PVS["SETPOINT"].unit, PVS["LINE"].unit, PVS["LINE_LIMIT"].unit) == ("W", "K", "K", "K")
    assert PVS["SETPOINT"].writable and PVS["HEATER_OFF"].writable and not PVS["SETPOINT_RBV"].writable
    assert max(len(name) for name in PVS) <= LONGEST_NAME
    assert all(re.fullmatch(r"[A-Z0-9_]+", name) for name in PVS)


def test_every_pv_is_in_the_docs_table_with_its_record_type_and_unit():
    """The reference page's table, as the site builds it (generated from the PV table), holds every PV."""
    from docs_tools.reference_tables import expand

    page = (REPOSITORY / "docs" / "reference" / "epics-pvs.md").read_text()
    assert "<!-- cryod-table pvs -->" in page
    text = expand(page)
    start = text.index("| PV | record | unit | meaning |")
    rows = {}
    for line in text[start:].splitlines()[2:]:
        if not line.startswith("|"):
            break
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        rows[cells[0].strip("`")] = cells
    assert set(rows) == set(PVS), set(rows) ^ set(PVS)
    for name, pv in PVS.items():
        assert rows[name][1] == pv.record and rows[name][2] == pv.unit, (name, rows[name])


def test_the_phoebus_screen_shows_existing_pvs_and_every_contract_name():
    tree = ElementTree.parse(CONTRIB / "cryod.bob")
    names = {element.text for element in tree.iter() if element.tag in ("pv_name", "y_pv")}
    suffixes = {name.removeprefix("$(P)") for name in names}
    assert all(name.startswith("$(P)") for name in names) and suffixes <= set(PVS), suffixes - set(PVS)
    assert set(CONTRACT) <= suffixes
    assert tree.getroot().find("macros/P").text == "CRYO1:"


def test_the_archivers_list_and_policy_hold_every_pv():
    listed = json.loads((CONTRIB / "archiver" / "cryod-pvs.json").read_text())
    assert [entry["pv"] for entry in listed] == [f"CRYO1:{pv.name}" for pv in READINGS + SETTINGS]
    assert {entry["samplingperiod"] for entry in listed if PVS[entry["pv"][6:]].per_row} == {"0.08"}
    spec = importlib.util.spec_from_file_location("policies", CONTRIB / "archiver" / "policies.py")
    policies = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(policies)
    assert set(policies.CRYOD_PVS) == set(PVS)
    assert policies.determinePolicy({"pvName": "CRYO1:T2"})["samplingPeriod"] == 0.08
    assert policies.determinePolicy({"pvName": "CRYO1:STATE"})["policyName"] == "cryod"
    assert policies.determinePolicy({"pvName": "OTHER:T2"})["policyName"] == "default"


def test_epics_reads_the_example_access_security_file_and_not_a_broken_one(tmp_path):
    check = ("import ctypes, sys\n"
             "from epicscorelibs.ioc import Com\n"
             "Com.asInitFile.argtypes = (ctypes.c_char_p, ctypes.c_char_p)\n"
             "sys.exit(1 if Com.asInitFile(sys.argv[1].encode(), None) else 0)\n")
    result = subprocess.run([sys.executable, "-c", check, str(CONTRIB / "cryod.acf")], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
    broken = tmp_path / "broken.acf"
    broken.write_text((CONTRIB / "cryod.acf").read_text().replace("RULE(1, READ)", "RULE(1, READ", 1))
    result = subprocess.run([sys.executable, "-c", check, str(broken)], capture_output=True, text=True, timeout=60)
    assert result.returncode != 0
