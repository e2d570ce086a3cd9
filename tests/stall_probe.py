"""How long the machine kept this process from running, measured while a real-time test runs.

:class:`StallProbe` is a thread that asks to wake every few milliseconds and keeps the longest it
overslept. A wake-up needs a core and the interpreter's lock, as a simulated instrument's reply or
the daemon's next tick does, so the probe's longest stall is the longest any of them could have
been held up by the machine (other people's runs on a shared machine) rather than by the code
under test. A real-time test compares it with the waits it judges: a run in which the process was
stalled for a good part of the loop's reply wait says nothing about the daemon's timing, and is run
again (see ``tests/fault_drills.py``).
"""

from __future__ import annotations

import threading
import time


class StallProbe:
    """A ``with`` block during which :attr:`largest_s` is the longest this process could not run (s).

    Parameters
    ----------
    interval_s : float
        How often the probe asks to wake (s).
    """

    def __init__(self, interval_s: float = 0.01):
        self.interval_s = interval_s
        self.largest_s = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="stall-probe", daemon=True)

    def _watch(self) -> None:
        before = time.monotonic()
        while not self._stop.wait(self.interval_s):
            now = time.monotonic()
            self.largest_s = max(self.largest_s, now - before - self.interval_s)
            before = now

    def __enter__(self) -> "StallProbe":
        self._thread.start()
        return self

    def __exit__(self, *exc_info) -> None:
        self._stop.set()
        self._thread.join(5.0)
