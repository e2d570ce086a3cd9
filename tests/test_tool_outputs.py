"""The tools never write over their input, and never over a file cryod did not write unless told to."""

import hashlib
import json
import os

import pytest

from cryod import cli
from cryod.cli.analyze import analysis_files
from cryod.analysis.paper_table1 import regenerated_record
from cryod.output_files import MANIFEST_NAME
from cryod.records.record import write_record

from tests.conftest import CONFIG


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    return write_record(tmp_path_factory.mktemp("paper") / "table1.csv", regenerated_record(duration_s=600.0, seed=3),
                        {"source": "Pan et al. Part 1, Table 1, regenerated"})


def _digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _run(capsys, *arguments):
    status = cli.main([*map(str, arguments)])
    return status, capsys.readouterr().err


def test_analyze_keeps_a_file_of_someone_elses_in_its_directory_even_with_force(record, tmp_path, capsys):
    out = tmp_path / "results"
    out.mkdir()
    mine = out / "overview.png"
    mine.write_bytes(b"a figure of my own")
    for force in ([], ["--force"]):
        status, err = _run(capsys, "analyze", record, "--out", out, *force)
        assert status == 2
        assert f"{mine} is in the way: cryod did not write it" in err
        assert mine.read_bytes() == b"a figure of my own"
    assert sorted(path.name for path in out.iterdir()) == ["overview.png"]      # refused before anything


def test_analyze_replaces_its_own_earlier_analysis_with_force_and_lists_what_it_wrote(record, tmp_path, capsys):
    out = tmp_path / "results"
    status, err = _run(capsys, "analyze", record, "--out", out, "--model", CONFIG / "model-paper-printed.yaml")
    assert status == 0, err
    written = {path.name for path in out.iterdir()}
    assert written - {MANIFEST_NAME} <= set(analysis_files(figures=True))    # every file it writes is planned
    listed = json.loads((out / MANIFEST_NAME).read_text())["files"]
    assert set(listed) == written - {MANIFEST_NAME}
    assert all(listed[name]["sha256"] == _digest(out / name) for name in listed)
    status, err = _run(capsys, "analyze", record, "--out", out, "--no-figures")
    assert status == 2 and "holds an earlier analysis (analysis.json); give --force" in err
    (out / "report.md").write_text("my notes on it")                       # changed since: no longer cryod's
    status, err = _run(capsys, "analyze", record, "--out", out, "--no-figures", "--force")
    assert status == 2 and f"{out / 'report.md'} is in the way: cryod did not write it (or it changed since)" in err
    (out / "report.md").unlink()
    status, err = _run(capsys, "analyze", record, "--out", out, "--no-figures", "--force")
    assert status == 0, err


def test_identify_keeps_a_report_directorys_files_it_did_not_write(record, tmp_path, capsys):
    report = tmp_path / "report"
    report.mkdir()
    for name in ("report.md", "fit_T2.png"):
        (report / name).write_text(f"{name} of my own")
    for force in ([], ["--force"]):
        status, err = _run(capsys, "identify", record, "--out", tmp_path / "model.yaml", "--report", report,
                            "--bootstrap", "0", *force)
        assert status == 2 and "is in the way: cryod did not write it" in err
    assert [(report / name).read_text() for name in ("report.md", "fit_T2.png")] == \
        ["report.md of my own", "fit_T2.png of my own"]
    assert not (tmp_path / "model.yaml").exists()                           # refused before the fit


@pytest.mark.parametrize("spelling", ["same path", "hard link", "symbolic link", "another spelling"])
def test_no_tool_writes_over_the_record_it_reads_even_with_force(record, tmp_path, capsys, spelling):
    copy = tmp_path / "records" / "rec.csv"
    copy.parent.mkdir()
    copy.write_bytes(record.read_bytes())
    before = _digest(copy)
    target = {"same path": copy, "another spelling": tmp_path / "records" / ".." / "records" / "rec.csv"}.get(spelling)
    if spelling == "hard link":
        target = tmp_path / "alias.csv"
        os.link(copy, target)
    elif spelling == "symbolic link":
        target = tmp_path / "alias.csv"
        target.symlink_to(copy)
    for arguments in (["identify", copy, "--out", target, "--force", "--bootstrap", "0"],
                      ["plot", copy, "--out", target, "--force"]):
        status, err = _run(capsys, *arguments)
        assert status == 2 and "it never writes over its input, even with --force" in err
        assert _digest(copy) == before


def test_analyze_never_writes_its_record_even_when_the_record_bears_an_output_name(record, tmp_path, capsys):
    out = tmp_path / "results"
    out.mkdir()
    named = out / "analysis.json"
    named.write_bytes(record.read_bytes())
    before = _digest(named)
    status, err = _run(capsys, "analyze", named, "--out", out, "--force")
    assert status == 2 and f"{named} is a file cryod analyze reads" in err
    assert _digest(named) == before


@pytest.mark.parametrize("tool", ["cryod analyze", "cryod identify"])
def test_a_list_of_the_files_written_that_cannot_be_saved_is_one_warning_also_when_the_tool_fails(tmp_path, capsys,
                                                                                                  tool):
    """The files stay written, and the user learns that a later --force will keep them: the same warning from
    either tool, after a run that succeeded and after one that failed half-way."""
    from cryod.cli.output_files import listed_when_written
    from cryod.output_files import OutputFiles

    outputs = OutputFiles(tool, tmp_path, ["report.md"])
    with listed_when_written(outputs):
        (tmp_path / "report.md").write_text("written")
        (tmp_path / MANIFEST_NAME).mkdir()                     # the list cannot be replaced
    warning = (f"{tool}: warning: the list of the files written could not be saved as {tmp_path / MANIFEST_NAME}: ")
    assert capsys.readouterr().err.startswith(warning)
    with pytest.raises(OSError):
        with listed_when_written(outputs):
            raise OSError("disk full")
    err = capsys.readouterr().err
    assert err.startswith(warning) and err.count("\n") == 1
    assert (tmp_path / "report.md").read_text() == "written"
