"""The docs site: the manual's length, the reference tables generated from the code, the README's front door.

The site itself is built by ``.ci/run`` (``mkdocs build --strict``: every link, anchor and generated table);
these tests need no MkDocs.
"""

import re

import pytest

from docs_tools.manual_words import LIMIT, MANUAL, manual_words, words
from docs_tools.reference_tables import MARKER, TABLES, expand
from tests.conftest import REPOSITORY

DOCS = REPOSITORY / "docs"


def test_the_manual_is_under_its_word_limit():
    """Tutorial, how-to and reference, their tables generated, their prose counted (docs_tools.manual_words)."""
    counts = manual_words()
    total = sum(sum(pages.values()) for pages in counts.values())
    parts = ", ".join(f"{part} {sum(pages.values())}" for part, pages in counts.items())
    print(f"the manual: {total} words ({parts})")
    assert set(counts) == set(MANUAL) and all(counts.values())
    assert total < LIMIT, f"the manual has {total} words ({parts}); the limit is {LIMIT}"


def test_the_count_leaves_out_code_comments_and_link_targets():
    page = ("# Title\n\nTwo words [here](../a/b.md).\n\n```sh\ncryod ctl status\n```\n<!-- a comment -->\n"
            "| a | b |\n|---|---|\n| `T2_K` | c |\n")
    assert words(page) == 1 + 3 + 2 + 2


@pytest.mark.parametrize("name", sorted(TABLES))
def test_every_reference_table_is_on_a_page_and_generates(name):
    pages = [path for path in DOCS.rglob("*.md") if f"<!-- cryod-table {name} -->" in path.read_text()]
    assert pages, f"no page shows the {name} table"
    assert MARKER.search(f"<!-- cryod-table {name} -->")
    assert len(expand(f"<!-- cryod-table {name} -->").splitlines()) >= 1


def test_an_unknown_table_fails_the_build():
    with pytest.raises(KeyError, match="no reference table"):
        expand("<!-- cryod-table no-such-table -->")


def test_the_generated_tables_hold_the_codes_names():
    from cryod.analysis.summary import CAUSES
    from cryod.service.commands import COMMANDS
    from cryod.service.faults import ExitCode, FaultCause

    causes = TABLES["causes"]()
    assert all(f"| `{cause}` |" in causes for cause in CAUSES)           # every cause the code has, and only those
    assert causes.count("\n| `") == len(CAUSES)
    commands = TABLES["commands"]().replace("\\|", "|")
    assert all(f"`{spec.usage}`" in commands for spec in COMMANDS.values() if spec.from_socket)
    assert "modulate" not in commands                                   # not offered on the socket
    codes = TABLES["exit-codes"]()
    assert all(f"| {int(code)} |" in codes for code in ExitCode)
    assert all(f"`{cause}`" in TABLES["fault-causes"]() for cause in FaultCause)
    status = TABLES["status-keys"]()
    assert all(f"| `{key}` |" in status for key in ("T2_K", "setpoint_K", "state", "record_path", "T2_average_K"))


def test_no_page_tells_the_history_of_changes():
    """The docs say how to use cryod, what and why: not what it was before (a few telling phrases)."""
    history = re.compile(r"before this change|used to be|\bthis round\b|earlier (?:versions|configurations)|\bas before\b"
                         r"|\bformerly\b|times before\)|\bnow chooses\b|merged after", re.I)
    found = [f"{path.relative_to(REPOSITORY)}: {match.group(0)}"
             for path in sorted(DOCS.rglob("*.md")) + [REPOSITORY / "README.md"] if "figures" not in path.parts
             for match in history.finditer(path.read_text())]
    assert found == []


def test_no_page_cites_a_file_outside_the_repository():
    cited = [path for path in sorted(DOCS.rglob("*.md")) + [REPOSITORY / "README.md"]
             if "DESIGN" in path.read_text()]
    assert cited == []


def test_the_readme_starts_with_the_dry_run_then_the_tests_from_the_environment():
    text = (REPOSITORY / "README.md").read_text()
    first = re.search(r"```sh\n(.*?)```", text, re.S).group(1).splitlines()
    assert len(first) == 2
    assert "--simulate" in first[0] and first[0].split("&&")[-1].strip().startswith(".venv/bin/cryod ")
    assert "pytest" in first[1] and first[1].split("&&")[-1].strip().startswith(".venv/bin/python -m pytest")
    tutorial = text.index("docs/tutorial/first-dry-run.md")
    assert tutorial < text.index("docs/how-to/") and tutorial < text.index("docs/developer/architecture.md")
    second = re.findall(r"```sh\n(.*?)```", text, re.S)[1].splitlines()
    assert all(line.startswith(".venv/bin/") for line in second if line.strip())


def test_every_page_the_readme_names_exists():
    text = (REPOSITORY / "README.md").read_text()
    links = re.findall(r"\]\((docs/[^)#]+)", text)
    assert len(links) > 30
    assert [link for link in links if not (REPOSITORY / link).exists()] == []
