"""MkDocs hooks (mkdocs.yml ``hooks:``): the reference tables the code holds, and the benchmarks' results.

* every ``<!-- cryod-table NAME -->`` line of a page becomes the table :mod:`docs_tools.reference_tables`
  generates from the code;
* every ``benchmarks/results/*.md`` becomes a page under ``developer/results/``: the benchmarks write
  their results there, outside the manual, and the site shows them as they are.
"""

from __future__ import annotations

import sys
from pathlib import Path

from mkdocs.structure.files import File

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))     # this checkout's cryod and docs_tools

from docs_tools.reference_tables import REPOSITORY, expand  # noqa: E402

RESULTS = REPOSITORY / "benchmarks" / "results"


def on_files(files, config):
    for path in sorted(RESULTS.glob("*.md")):
        text = path.read_text(encoding="utf-8").replace("](../../docs/", "](../../")  # its links, as on the site
        files.append(File.generated(config, f"developer/results/{path.name}", content=text))
    return files


def on_page_markdown(markdown, page, config, files):
    return expand(markdown)
