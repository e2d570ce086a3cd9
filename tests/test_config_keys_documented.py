"""Every key of the example configuration is in the configuration reference's key table, under its section."""

import re

import yaml

from cryod.control.feedforward import FeedforwardSettings
from tests.conftest import CONFIG, REPOSITORY


def leaf_keys(mapping, prefix=()):
    for key, value in mapping.items():
        if isinstance(value, dict):
            yield from leaf_keys(value, prefix + (key,))
        else:
            yield prefix + (key,)


def key_table():
    """{section: the text of its rows} of the configuration's key table."""
    text = (REPOSITORY / "docs" / "reference" / "configuration.md").read_text()
    start = text.index("| section | key | meaning |")
    rows, section = {}, None
    for line in text[start:].splitlines()[2:]:
        if not line.startswith("|"):
            break
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        section = cells[0].strip("`") or section
        rows[section] = rows.get(section, "") + " " + " ".join(cells[1:])
    return rows


def test_every_key_of_the_example_configuration_is_in_the_key_table():
    example = yaml.safe_load((CONFIG / "cryod.yaml").read_text())
    table = key_table()
    missing = [".".join(path) for path in leaf_keys(example) if path[0] != "format" and not (
        path[0] in table if len(path) == 1                      # a section off by default (web: null)
        else re.search(rf"\b{re.escape(path[-1])}\b", table.get(path[0], "")))]
    assert not missing, f"keys of config/cryod.yaml not in docs/reference/configuration.md's table: {missing}"


def test_every_feedforward_setting_is_in_the_example_configuration_and_the_key_table():
    example = yaml.safe_load((CONFIG / "cryod.yaml").read_text())["control"]["feedforward"]
    settings = set(FeedforwardSettings.__dataclass_fields__) - {"model_source", "period_s"}
    assert settings == set(example)
    for name in settings:
        assert f"`feedforward.{name}`" in key_table()["control"], name
