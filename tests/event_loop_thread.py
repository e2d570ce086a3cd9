"""An asyncio event loop on a thread of its own, for servers of the interfaces process tested in the test's process."""

from __future__ import annotations

import asyncio
import threading


class EventLoopThread:
    """``with EventLoopThread() as loop: loop.run(coroutine)``: the coroutine runs on the thread, its result here."""

    def __init__(self):
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, name="test-event-loop", daemon=True)

    def __enter__(self) -> "EventLoopThread":
        self._thread.start()
        return self

    def run(self, coroutine, timeout_s: float = 20.0):
        """Run ``coroutine`` on the loop and wait for its result (its exception is raised here)."""
        return asyncio.run_coroutine_threadsafe(coroutine, self.loop).result(timeout_s)

    def __exit__(self, *exc) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(10)
