"""The manual's word count: the tutorial, the how-to guides and the reference, as the site builds them.

How the words are counted: each page's markdown with its reference tables generated
(:func:`docs_tools.reference_tables.expand`, as the build does), then without fenced code blocks
(commands, configuration, output, ``--help`` texts), HTML comments, link targets and table rules;
what is left is split on white space, and every piece holding a letter or a digit is a word. Inline code
(`` `T2_K` ``) counts, as does every table cell. The API pages' ``::: name`` lines are the docstrings
mkdocstrings renders: the code's own documentation, counted as the two words of the line.

Run ``python -m docs_tools.manual_words`` for the count of each page.
"""

from __future__ import annotations

import re

from docs_tools.reference_tables import REPOSITORY, expand

DOCS = REPOSITORY / "docs"
#: The manual: what a lab reads to use cryod. The explanation and the developers' pages are not in it.
MANUAL = ("tutorial", "how-to", "reference")
LIMIT = 25_000

FENCE = re.compile(r"^(```|~~~).*?^\1\s*$", re.M | re.S)
COMMENT = re.compile(r"<!--.*?-->", re.S)
LINK_TARGET = re.compile(r"\]\([^)]*\)")
TABLE_RULE = re.compile(r"^\|?[\s:|-]+\|[\s:|-]*$", re.M)
WORD = re.compile(r"[^\W_]", re.U)


def prose(markdown: str) -> str:
    """The text of a page that a reader reads as prose."""
    text = FENCE.sub("", markdown)
    text = COMMENT.sub("", text)
    text = LINK_TARGET.sub("]", text)
    return TABLE_RULE.sub("", text)


def words(markdown: str) -> int:
    return sum(1 for piece in prose(markdown).split() if WORD.search(piece))


def page_words(part: str) -> dict[str, int]:
    """{page: words} of one part of the manual, its markdown as built."""
    return {str(path.relative_to(DOCS)): words(expand(path.read_text(encoding="utf-8")))
            for path in sorted((DOCS / part).glob("*.md"))}


def manual_words() -> dict[str, dict[str, int]]:
    return {part: page_words(part) for part in MANUAL}


if __name__ == "__main__":
    counts = manual_words()
    for part, pages in counts.items():
        for page, count in pages.items():
            print(f"{count:7d}  {page}")
        print(f"{sum(pages.values()):7d}  {part}/ in all\n")
    print(f"{sum(sum(pages.values()) for pages in counts.values()):7d}  the manual (limit {LIMIT})")
    for part in ("explanation", "developer"):
        print(f"{sum(page_words(part).values()):7d}  {part}/ (not in the manual)")
