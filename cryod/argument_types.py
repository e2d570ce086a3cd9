"""Argument types for cryod's command lines: finite numbers, with their sign checked.

``float`` alone takes ``nan``, ``inf`` and ``1_5``; a lab's command line takes plain
decimal numbers (``5``, ``-0.5``, ``2.5e-3``), and says which it refused.

Examples
--------
>>> positive("0.5")
0.5
>>> positive("1_5")
Traceback (most recent call last):
...
argparse.ArgumentTypeError: expected a number, got '1_5'
"""

from __future__ import annotations

import argparse
import re

#: Optional sign, digits with an optional fraction (or a fraction alone), optional exponent: ASCII only.
_PLAIN_DECIMAL = re.compile(r"[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?", re.ASCII)


def number(text: str) -> float:
    """A finite plain decimal number."""
    if not _PLAIN_DECIMAL.fullmatch(text.strip()):
        raise argparse.ArgumentTypeError(f"expected a number, got {text[:40]!r}")
    value = float(text)
    if value in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text[:40]!r}")
    return value


def positive(text: str) -> float:
    """A number above 0."""
    value = number(text)
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return value


def not_negative(text: str) -> float:
    """A number at least 0."""
    value = number(text)
    if value < 0.0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return value
