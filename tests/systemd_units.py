"""The shipped systemd unit files and their settings, as the tests read them."""

import configparser
from pathlib import Path

from tests.conftest import REPOSITORY

UNIT = REPOSITORY / "systemd" / "cryod.service"
#: One instance per cryostat: ``cryod@<name>`` reads /etc/cryod/<name>.yaml.
TEMPLATE = REPOSITORY / "systemd" / "cryod@.service"


def unit_sections(unit: Path = UNIT) -> configparser.ConfigParser:
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str
    parser.read_string(unit.read_text())
    return parser

#: cryod's EPICS IOC, beside cryod.service.
IOC_UNIT = REPOSITORY / "systemd" / "cryod-ioc.service"
