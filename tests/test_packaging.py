"""What a lab installs and what git leaves alone: the analysis extra, the files the tools write."""

import subprocess
import tomllib

import pytest

from tests.conftest import REPOSITORY


def test_pandas_comes_with_the_analysis_extra_and_record_frame_says_so():
    project = tomllib.loads((REPOSITORY / "pyproject.toml").read_text())["project"]
    assert any(requirement.startswith("pandas") for requirement in project["optional-dependencies"]["analysis"])
    assert "pandas" not in " ".join(project["dependencies"])         # the daemon itself does not need it
    source = (REPOSITORY / "cryod" / "records" / "dataframe.py").read_text()
    assert "pip install 'cryod[analysis]'" in source
    assert "pip install 'cryod[analysis]'" in (REPOSITORY / "docs" / "reference" / "python-api.md").read_text()


@pytest.mark.parametrize("path, ignored", [("cryod-simulate/data/cryod-2026-11-25.csv", True),
                                           ("cryod-identify/cryod-2026-11-25.csv", True),
                                           ("lab-model.yaml", True), ("notes/lab-model.yaml", True),
                                           ("docs/figures/commissioning/lab-model.yaml", False),
                                           ("config/cryod.yaml", False)])
def test_what_the_tools_write_where_they_run_is_ignored_by_git(path, ignored):
    check = subprocess.run(["git", "check-ignore", "--no-index", "-q", path], cwd=REPOSITORY)
    assert check.returncode == (0 if ignored else 1)
