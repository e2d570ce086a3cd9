"""What a model tool says about the files it wrote, once for every tool.

:class:`cryod.output_files.OutputFiles` keeps the list of what cryod wrote into an output
directory (so that a later ``--force`` replaces those and nothing else); a tool adds its
files to the list when it has written them, whether it then succeeded or failed. When the
list cannot be saved, the files stay, and the user is told, on stderr, that a later
``--force`` will keep them.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager

from cryod.output_files import OutputFiles


@contextmanager
def listed_when_written(outputs: OutputFiles) -> Iterator[OutputFiles]:
    """Run the body, then add the files it wrote to the directory's list, also when the body failed.

    A list that cannot be saved is a warning on stderr (``cryod analyze: warning: the list of the
    files written could not be saved as ...``), not a failure: the files themselves are written.

    Parameters
    ----------
    outputs : OutputFiles
        The run's files (its ``tool`` names the program in the warning).
    """
    try:
        yield outputs
    finally:
        warning = outputs.note_written()
        if warning is not None:
            print(f"{outputs.tool}: warning: {warning}", file=sys.stderr)


__all__ = ["listed_when_written"]
