"""Whole-record results kept for the next call with the same inputs.

The analysis replays one record hundreds of times through models that differ
in one part: a thermometer's lag leaves the PTC stage's heater path as it was,
a dead time leaves the stage alone and shifts only the flange's input, the
cooler's causes leave both heater paths alone. A path's response over an hour
(45,000 samples) is the same array for the same path, state and input, so it is
made once and kept, keyed by the inputs' contents (a digest, not their
identity: a caller may change an array between calls).

Examples
--------
>>> import numpy as np
>>> kept = KeptResults(2)
>>> made = []
>>> def square(values):
...     made.append(1)
...     return values ** 2
>>> values = np.arange(3.0)
>>> first = kept.get_or_make(digest(values), lambda: square(values))
>>> second = kept.get_or_make(digest(np.arange(3.0)), lambda: square(values))
>>> len(made), second.tolist(), second.flags.writeable
(1, [0.0, 1.0, 4.0], False)
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict

import numpy as np


def digest(*parts) -> bytes:
    """A digest of arrays (by dtype, shape and contents) and other values (by ``repr``).

    Parameters
    ----------
    *parts : numpy.ndarray, sequence or scalar
        Arrays and lists of numbers are hashed by their contents, everything else by its ``repr``.

    Returns
    -------
    bytes
        20 bytes; equal for equal contents.
    """
    hashed = hashlib.sha1(usedforsecurity=False)       # the fastest of hashlib's here (no collisions sought)
    for part in parts:
        if isinstance(part, np.ndarray) and part.size >= _LARGE:
            hashed.update(_array_digest(part))
        elif isinstance(part, (np.ndarray, list)):
            array = np.ascontiguousarray(part)
            hashed.update(repr((array.dtype.str, array.shape)).encode())
            hashed.update(array.data if array.size else b"")
        else:
            hashed.update(repr(part).encode())
        hashed.update(b"|")
    return hashed.digest()


#: Arrays of at least this many elements have their digest kept with a copy of their bytes: comparing the bytes
#: of the same array asked again is some ten times faster than hashing them again.
_LARGE = 4096
_LARGE_DIGESTS: OrderedDict = OrderedDict()
_LARGE_KEPT = 16
_LARGE_LOCK = threading.Lock()


def _array_digest(array: np.ndarray) -> bytes:
    array = np.ascontiguousarray(array)
    header = repr((array.dtype.str, array.shape)).encode()
    contents = array.reshape(-1).view(np.uint64 if array.nbytes % 8 == 0 and array.itemsize % 8 == 0 else np.uint8)
    with _LARGE_LOCK:
        kept = _LARGE_DIGESTS.get(id(array))
    if kept is not None and kept[0] == header and np.array_equal(kept[1], contents):
        with _LARGE_LOCK:
            if id(array) in _LARGE_DIGESTS:
                _LARGE_DIGESTS.move_to_end(id(array))        # the least recently asked is dropped first
        return kept[2]
    hashed = hashlib.sha1(header, usedforsecurity=False)
    hashed.update(array.data)
    found = hashed.digest()
    with _LARGE_LOCK:
        _LARGE_DIGESTS[id(array)] = (header, contents.copy(), found)
        while len(_LARGE_DIGESTS) > _LARGE_KEPT:
            _LARGE_DIGESTS.popitem(last=False)
    return found


def _read_only(value):
    if isinstance(value, np.ndarray):
        value.setflags(write=False)
    elif isinstance(value, tuple):
        for item in value:
            _read_only(item)
    return value


class KeptResults:
    """The last ``kept`` results by key, least recently used dropped first; thread-safe.

    Arrays in a result (alone or in a tuple) are made read-only: every caller gets the same object.

    Parameters
    ----------
    kept : int
        Results kept at most.
    """

    def __init__(self, kept: int):
        self.kept = kept
        self._results: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def get_or_make(self, key, make):
        """The result kept under ``key``, or ``make()``'s, kept under it."""
        with self._lock:
            found = self._results.get(key)
            if found is not None:
                self._results.move_to_end(key)
                return found
        made = _read_only(make())
        with self._lock:
            self._results[key] = made
            while len(self._results) > self.kept:
                self._results.popitem(last=False)
        return made

    def __len__(self) -> int:
        return len(self._results)

    def clear(self) -> None:
        """Forget every result."""
        with self._lock:
            self._results.clear()
