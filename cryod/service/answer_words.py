"""Answers the loop gives as a snapshot, put in words on a thread of their own.

A command that only reads (``cryod ctl feedforward status``) costs the loop's thread a snapshot
taken at its tick boundary (values and immutable objects: microseconds); its words (the
feedforward's waveform over a period, its plant per harmonic, what binds its limit: a tenth of a
millisecond and more) are put together here, on a worker thread at normal priority, while the tick
reads the instruments and sets the heater. After the tick the loop takes them and answers, journals
and records the command as it does every command (``# event: command: ...``, with who sent it),
waiting for them at most :data:`WORDS_WAIT_S`: a worker that has not finished by then (a machine so
loaded that a normal thread gets no time) has the command answered as refused, with the reason,
rather than the 80 ms cycle held up.

Examples
--------
>>> words = AnswerWords()
>>> pending = words.put(SnapshotAnswer((4.2, 5.0), lambda pair: f"from {pair[0]:g} K to {pair[1]:g} K"))
>>> pending.result()
'from 4.2 K to 5 K'
>>> words.close()
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Callable

from cryod.thread_priority import at_normal_priority

#: The loop waits this long at most after its tick for a snapshot's words (s): a period of the default loop.
WORDS_WAIT_S = 0.08


@dataclass(frozen=True)
class SnapshotAnswer:
    """An answer as the loop's thread gives it: a snapshot (immutable) and the function that puts it in words.

    Attributes
    ----------
    snapshot : object
        What the loop took at its tick boundary.
    words : callable
        ``words(snapshot)``: the answer's text (run on the words' thread, never the loop's).
    """

    snapshot: Any
    words: Callable[[Any], str]


class AnswerWords:
    """The thread that puts snapshots in words (started at the first, at normal priority)."""

    def __init__(self) -> None:
        self._executor: ThreadPoolExecutor | None = None

    def put(self, answer: SnapshotAnswer) -> Future:
        """Put ``answer`` in words on the words' thread; its text is the future's result."""
        if self._executor is None:        # started by the loop's thread: back to normal priority first
            self._executor = ThreadPoolExecutor(1, thread_name_prefix="cryod-words", initializer=at_normal_priority)
        return self._executor.submit(answer.words, answer.snapshot)

    def close(self) -> None:
        """End the thread once what it was given is in words."""
        if self._executor is not None:
            self._executor.shutdown(wait=True)
            self._executor = None


__all__ = ["AnswerWords", "SnapshotAnswer", "WORDS_WAIT_S"]
