"""The feedforward's estimator and learning steps, on a thread of their own.

The loop's thread only hands the T2 readings over (a list append, and a queue
put every :data:`HANDOFF` readings: each put wakes the worker, and a wake-up
costs the loop's thread more than the append) and, every
``update_interval_s``, asks for a learning step; a worker thread feeds the
readings to the :class:`~cryod.control.feedforward.SynchronousEstimator` (a
Kalman filter, tens of µs a reading) and computes the step (a small quadratic
programme, a fraction of a ms, with an iteration count that depends on the
data). So the 80 ms cycle stays lean and its time bounded.

Results are deterministic whatever the threads' timing: a step sees exactly
the readings handed over before it was asked for, and the loop takes its
result at the next tick, waiting for it if the worker is behind (in service it
never is: it has a whole period; on virtual time the loop runs ahead).

Examples
--------
>>> import numpy as np
>>> from cryod.control.feedforward import SynchronousEstimator
>>> worker = LearningWorker(SynchronousEstimator(1))
>>> for k in range(500):
...     phase = 10.83 * 0.08 * k
...     worker.reading(phase, 5.0 + 1e-3 * np.cos(phase), np.zeros(1, dtype=complex))
>>> worker.step(1, lambda estimator: round(abs(complex(estimator.line[0])) * 1e3, 2))
>>> worker.result(1)
1.0
>>> worker.close()
"""

from __future__ import annotations

import queue
import threading
import weakref
from typing import TYPE_CHECKING, Any, Callable

from cryod.thread_priority import at_normal_priority

if TYPE_CHECKING:
    from cryod.control.feedforward.synchronous_estimator import SynchronousEstimator

_GAP = object()
_STOP = object()
#: Readings handed to the worker at once (a step, a gap or a change hands over what is waiting first).
HANDOFF = 8


def _work(inbox: queue.SimpleQueue, estimator, results: dict, ready: threading.Condition) -> None:
    """The worker thread: readings into the estimator, steps computed in their turn."""
    at_normal_priority()         # started by the loop thread on a reload: never at the loop's priority
    while True:
        item = inbox.get()
        if item is _STOP:
            return
        if item is _GAP:
            estimator.forget_last()
        elif type(item) is list:
            for reading in item:
                estimator.add(*reading)
        elif len(item) == 1:
            item[0](estimator)
        else:
            step_id, compute = item
            try:
                result = compute(estimator)
            except Exception as error:          # noqa: BLE001 - handed to the loop, which raises it
                result = error
            with ready:
                results[step_id] = result
                ready.notify_all()


class LearningWorker:
    """A thread that owns an estimator: readings in, learning steps out.

    Parameters
    ----------
    estimator : SynchronousEstimator
        Used only by the worker thread from now on.
    """

    def __init__(self, estimator: SynchronousEstimator) -> None:
        self.estimator = estimator
        self._inbox: queue.SimpleQueue = queue.SimpleQueue()
        self._results: dict[int, Any] = {}
        self._ready = threading.Condition()
        self._thread = threading.Thread(target=_work, args=(self._inbox, estimator, self._results, self._ready),
                                        name="cryod-feedforward", daemon=True)
        self._thread.start()
        self._waiting: list[tuple] = []                     # readings not handed over yet
        weakref.finalize(self, self._inbox.put, _STOP)      # a term dropped without close(): the thread ends

    def reading(self, phase: float, flange_K: float, effect) -> None:
        """A T2 reading at its cooler phase, with the waveform's modelled effect (non-blocking)."""
        waiting = self._waiting
        waiting.append((phase, flange_K, effect))
        if len(waiting) >= HANDOFF:
            self._hand_over()

    def _hand_over(self) -> None:
        if self._waiting:
            self._inbox.put(self._waiting)
            self._waiting = []

    def gap(self) -> None:
        """The next reading is not to be differenced against the last ones."""
        self._hand_over()
        self._inbox.put(_GAP)

    def apply(self, change: Callable[[Any], None]) -> None:
        """Do ``change(estimator)`` after every reading handed over so far (non-blocking; a reset, a rescaling)."""
        self._hand_over()
        self._inbox.put((change,))

    def step(self, step_id: int, compute: Callable[[Any], Any]) -> None:
        """Compute ``compute(estimator)`` after every reading handed over so far (non-blocking)."""
        self._hand_over()
        self._inbox.put((step_id, compute))

    def result(self, step_id: int, timeout_s: float | None = 60.0):
        """The result of step ``step_id``, waiting for it; an error in the step is raised here."""
        with self._ready:
            if not self._ready.wait_for(lambda: step_id in self._results, timeout_s):
                raise TimeoutError(f"feedforward learning step {step_id} not done within {timeout_s} s")
            result = self._results.pop(step_id)
        if isinstance(result, Exception):
            raise result
        return result

    def close(self) -> None:
        """End the thread once what was handed over is done."""
        self._hand_over()
        self._inbox.put(_STOP)
