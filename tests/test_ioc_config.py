"""The ``ioc`` section: what ``cryod ioc`` serves, validated like every other section (file, line, key)."""

import dataclasses

import pytest

from cryod.config import MAX_PV_PREFIX, load_config
from cryod.yaml_source import FileFormatError
from tests.example_config import line_of, written

OFF = "ioc: null"


def test_absent_means_off_and_a_section_gives_its_settings(tmp_path):
    path, _ = written(tmp_path, OFF, OFF)
    assert load_config(path).ioc is None
    path, _ = written(tmp_path, OFF, 'ioc: {prefix: "CRYO1:", writable: true, stable_hold_s: 30}')
    ioc = load_config(path).ioc
    assert (ioc.prefix, ioc.writable, ioc.stable_hold_s, ioc.stable_tolerance_K) == ("CRYO1:", True, 30.0, 1e-4)
    assert ioc.access_security_file is None and ioc.settle_timeout_s == 3600.0


def test_the_access_security_file_is_relative_to_the_configuration_and_must_exist(tmp_path):
    (tmp_path / "cryod.acf").write_text("ASG(DEFAULT) { RULE(1, READ) }\n")
    path, _ = written(tmp_path, OFF, 'ioc: {prefix: "C:", writable: true, access_security_file: cryod.acf}')
    assert load_config(path).ioc.access_security_file == tmp_path / "cryod.acf"
    path, text = written(tmp_path, OFF, 'ioc: {prefix: "C:", writable: true, access_security_file: gone.acf}')
    with pytest.raises(FileFormatError, match=rf":{line_of(text, 'ioc:')}: ioc.access_security_file: file not found"):
        load_config(path)


@pytest.mark.parametrize("section, key, reason", [
    ('ioc: {prefix: "CRYO 1:"}', "ioc.prefix", r"not the start of an EPICS record name.*not ' '"),
    ('ioc: {prefix: "CRYO.1:"}', "ioc.prefix", r"not '\.'"),
    ('ioc: {prefix: ""}', "ioc.prefix", "not the start of an EPICS record name"),
    (f'ioc: {{prefix: "{"A" * (MAX_PV_PREFIX + 1)}"}}', "ioc.prefix", f"give at most {MAX_PV_PREFIX}"),
    ("ioc: {writable: true}", "ioc.prefix", "missing required key"),
    ('ioc: {prefix: "C:", stable_tolerance_K: 0}', "ioc.stable_tolerance_K", "greater than 0"),
    ('ioc: {prefix: "C:", writeable: true}', "ioc.writeable", "unknown key"),
    ('ioc: {prefix: "C:", writable: maybe}', "ioc.writable", "true or false"),
])
def test_a_bad_ioc_section_is_refused_at_its_key(tmp_path, section, key, reason):
    path, text = written(tmp_path, OFF, section)
    with pytest.raises(FileFormatError, match=rf":{line_of(text, 'ioc:')}: {key}: .*{reason}"):
        load_config(path)


def test_a_changed_ioc_section_needs_a_restart_as_the_other_interfaces(tmp_path):
    path, _ = written(tmp_path, OFF, 'ioc: {prefix: "CRYO1:"}')
    config = load_config(path)
    moved = dataclasses.replace(config, ioc=dataclasses.replace(config.ioc, prefix="CRYO2:"))
    assert config.restart_needed_for(moved) == ["ioc"]
