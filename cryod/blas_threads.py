"""One BLAS thread for cryod's processes.

cryod's matrices are tall and narrow (a few columns by up to a few hundred
thousand rows in the model tools) or tiny (the loop's estimators). OpenBLAS's
threads bring nothing there and cost much: a QR of a tall matrix split over
two threads took twice the time of one, and idle BLAS threads spin on the
cryostat PC's cores, which the daemon's loop needs. Each ``cryod`` process
therefore asks for one BLAS thread, unless the user's environment chose a
number (an explicit ``OPENBLAS_NUM_THREADS`` is kept).

The request only works before numpy is first imported, which is why the
command line calls :func:`use_one_blas_thread` before importing anything else.
"""

from __future__ import annotations

import os
import sys
from typing import MutableMapping

#: The variables the BLAS builds numpy and scipy ship with read for their thread count.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def use_one_blas_thread(environ: MutableMapping[str, str] | None = None) -> list[str]:
    """Ask the BLAS library for one thread where the environment does not say.

    Parameters
    ----------
    environ : mapping, optional
        The environment to change (``os.environ`` by default).

    Returns
    -------
    list of str
        The variables set here; empty when numpy was imported already (too
        late: its BLAS has started its threads) or every variable was set.

    Examples
    --------
    >>> environment = {"OPENBLAS_NUM_THREADS": "2"}
    >>> set_here = use_one_blas_thread(environment)
    >>> environment["OPENBLAS_NUM_THREADS"]          # the user's choice is kept
    '2'
    """
    environ = os.environ if environ is None else environ
    if "numpy" in sys.modules:
        return []
    chosen = [name for name in BLAS_THREAD_VARIABLES if name not in environ]
    for name in chosen:
        environ[name] = "1"
    return chosen
