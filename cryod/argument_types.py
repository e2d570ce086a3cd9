"""Numbers typed by a person: one rule for cryod's command lines and its control socket.

``float`` alone takes ``nan``, ``inf``, ``1_5`` (15) and digits of any script (``١٥``);
cryod takes plain decimal numbers only (``5``, ``-0.5``, ``2.5e-3``: an optional sign,
ASCII digits with an optional point, an optional exponent), finite, and says which
text it refused. :func:`plain_decimal` is the rule; the command-line types below and
the control-socket commands (:mod:`cryod.service.commands`) both use it.

Examples
--------
>>> plain_decimal("2.5e-3")
0.0025
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
_PLAIN_DECIMAL = re.compile(r"[+-]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)?", re.ASCII)
#: Digits only (a count, a seed), not more than a seed needs.
_WHOLE_NUMBER = re.compile(r"[0-9]{1,30}", re.ASCII)
#: Whitespace a shell argument may carry around a number (ASCII only, as the digits).
_ASCII_SPACE = " \t\n\r\v\f"
#: At most this much of a refused text is repeated in a message.
SHOWN_CHARACTERS = 40


def shown(text: str) -> str:
    """``text`` quoted for a message, cut to :data:`SHOWN_CHARACTERS` characters."""
    if len(text) <= SHOWN_CHARACTERS:
        return repr(text)
    return f"{text[:SHOWN_CHARACTERS]!r}... ({len(text)} characters)"


def plain_decimal(text: str) -> float:
    """The value of a finite plain decimal number, exactly as typed (no surrounding space).

    Parameters
    ----------
    text : str
        ``5``, ``-0.5``, ``.5``, ``5.``, ``2.5e-3``.

    Returns
    -------
    float

    Raises
    ------
    ValueError
        The text is not a plain decimal number (``1_5``, ``nan``, ``inf``, ``0x10``, non-ASCII
        digits, anything else), or it is too large for a float (``1e999``). The message says
        which, without repeating the text (the caller names the argument).

    Examples
    --------
    >>> plain_decimal("-0.5")
    -0.5
    >>> plain_decimal("nan")
    Traceback (most recent call last):
    ...
    ValueError: not a number (plain decimal digits only, e.g. 5.2 or 2.5e-3)
    """
    if not _PLAIN_DECIMAL.fullmatch(text):
        raise ValueError("not a number (plain decimal digits only, e.g. 5.2 or 2.5e-3)")
    value = float(text)
    if value in (float("inf"), float("-inf")):
        raise ValueError("not a finite number (too large)")
    return value


def number(text: str) -> float:
    """A finite plain decimal number (command-line type; ASCII space around it is ignored)."""
    try:
        return plain_decimal(text.strip(_ASCII_SPACE))
    except ValueError as error:
        expected = "a finite number" if "finite" in str(error) else "a number"
        raise argparse.ArgumentTypeError(f"expected {expected}, got {shown(text)}") from None


def positive(text: str) -> float:
    """A number above 0."""
    value = number(text)
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {shown(text)}")
    return value


def not_negative(text: str) -> float:
    """A number at least 0."""
    value = number(text)
    if value < 0.0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {shown(text)}")
    return value


def whole_number(text: str) -> int:
    """A whole number at least 0, in ASCII digits (a seed, a count)."""
    stripped = text.strip(_ASCII_SPACE)
    if not _WHOLE_NUMBER.fullmatch(stripped):
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0 (at most 30 digits), got {shown(text)}")
    return int(stripped)


def setpoint_list(text: str) -> tuple[float, ...]:
    """Setpoints in K separated by commas, increasing, each above 0 K (command-line type: ``--setpoints 5,8,12``).

    Examples
    --------
    >>> setpoint_list("5, 8,12")
    (5.0, 8.0, 12.0)
    """
    try:
        values = tuple(number(part) for part in text.split(","))
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"give setpoints in K separated by commas, e.g. 5,8,12; got {shown(text)}") \
            from None
    if not all(value > 0.0 for value in values) or any(b <= a for a, b in zip(values, values[1:])):
        raise argparse.ArgumentTypeError(f"give increasing setpoints above 0 K, got {shown(text)}")
    return values


def speed(text: str) -> float | str:
    """Simulated seconds per real second (a number > 0), or ``"max"``: virtual time, as fast as the CPU allows."""
    if text == "max":
        return "max"
    try:
        return positive(text)
    except argparse.ArgumentTypeError as error:
        raise argparse.ArgumentTypeError(f"speed must be a number > 0 or 'max': {error}") from None
