"""SCPI as the simulated instruments parse it: headers, parameters, the error queue.

A command is registered in the manuals' own notation, optional nodes in
brackets and numeric suffixes where the manual has them::

    commands.add("[:SENSe[1]]:FRESistance:NPLCycles", write=set_nplc, query=get_nplc)
    commands.add(":ARM[:SEQuence[1]]:LAYer2:SOURce", write=..., query=...)

and a header matches in its short form (``FRES``) or long form
(``FRESISTANCE``), in any case, with optional nodes left out, as IEEE 488.2
and SCPI 1999 (section 6, "Program headers") specify. A program message is
split into units at ``;``; a unit without a leading ``:`` continues at the
level of the previous one.

Errors are SCPI's own numbers and texts as Keithley's manuals list them
(Model 2002 User's Manual, Table 2-4 and ``:SYSTem:ERRor?``, p. 3-138;
Model 2400 Series User's Manual, Appendix B; Model 622x Reference Manual,
Appendix B): a header the instrument does not know is ``-113,"Undefined
header"``.

An error inside a program message ends it, as the three manuals' "command
execution rules" state in the same words (2002 User's Manual p. 3-27, rule
6; 2400 User's Manual section 14, "Command execution rules"; 6220/6221
Reference Manual p. 10-17): commands execute in order, an invalid command
is not executed and goes to the error queue, the valid commands before it
are executed (their replies are sent) and the commands after it are
ignored (their queries send nothing).

Examples
--------
>>> commands = CommandTable()
>>> state = {"nplc": 1.0}
>>> commands.add("[:SENSe[1]]:FRESistance:NPLCycles",
...              write=lambda args: state.update(nplc=parse_number(args, 0.01, 50)),
...              query=lambda args: f"{state['nplc']:g}")
>>> errors = ErrorQueue()
>>> commands.execute(":sens:fres:nplc 2;nplc?", errors)
'2'
>>> commands.execute("SENSE1:FRESISTANCE:NPLCYCLES?", errors)
'2'
>>> commands.execute(":FRES:NPLC 99", errors) is None
True
>>> errors.pop(), errors.pop()
((-222, 'Parameter data out of range'), (0, 'No error'))
>>> commands.execute(":FRES:NPLX?", errors) is None, errors.pop()
(True, (-113, 'Undefined header'))
>>> commands.execute(":FRES:NPLC?;:FRES:NPLX 3;:FRES:NPLC 4;:FRES:NPLC?", errors), state["nplc"]
('2', 2.0)
"""

from __future__ import annotations

import math
import re
from collections import deque
from dataclasses import dataclass
from typing import Callable, Sequence


class ScpiError(Exception):
    """An error the instrument puts in its error queue: ``(code, message)``."""

    def __init__(self, code: int, message: str):
        super().__init__(code, message)
        self.code = code
        self.message = message


# SCPI errors, numbers and texts as the Keithley manuals print them.
NO_ERROR = (0, "No error")
SYNTAX_ERROR = (-102, "Syntax error")
DATA_TYPE_ERROR = (-104, "Data type error")
PARAMETER_NOT_ALLOWED = (-108, "Parameter not allowed")
MISSING_PARAMETER = (-109, "Missing parameter")
UNDEFINED_HEADER = (-113, "Undefined header")
TRIGGER_IGNORED = (-211, "Trigger ignored")
INIT_IGNORED = (-213, "Init ignored")
SETTINGS_CONFLICT = (-221, "Settings conflict")
PARAMETER_OUT_OF_RANGE = (-222, "Parameter data out of range")
ILLEGAL_PARAMETER_VALUE = (-224, "Illegal parameter value")
DATA_CORRUPT_OR_STALE = (-230, "Data corrupt or stale")
QUEUE_OVERFLOW = (-350, "Queue overflow")


def scpi_error(entry: tuple[int, str]) -> ScpiError:
    """The :class:`ScpiError` for one of the constants above."""
    return ScpiError(*entry)


class ErrorQueue:
    """First in, first out, ten entries; a full queue ends in ``-350,"Queue overflow"``.

    Model 2002 User's Manual, ``:SYSTem:ERRor?`` (p. 3-138): "The Error
    Queue is a first-in, first-out (FIFO) register that can hold up to 10
    messages ... When the Error Queue is empty, the message 0, 'No error' is
    placed in the Error Queue."
    """

    capacity = 10

    def __init__(self) -> None:
        self._entries: deque[tuple[int, str]] = deque()

    def push(self, code: int, message: str) -> None:
        if len(self._entries) >= self.capacity:
            self._entries[-1] = QUEUE_OVERFLOW
            return
        self._entries.append((code, message))

    def pop(self) -> tuple[int, str]:
        return self._entries.popleft() if self._entries else NO_ERROR

    def clear(self) -> None:
        self._entries.clear()

    def __len__(self) -> int:
        return len(self._entries)

    @staticmethod
    def format(entry: tuple[int, str]) -> str:
        """The reply text of one entry: ``-113,"Undefined header"``."""
        return f'{entry[0]},"{entry[1]}"'


# ---------------------------------------------------------------------------
# headers
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class _Node:
    long: str            # upper case long form, e.g. "FRESISTANCE"
    short: str           # upper case short form, e.g. "FRES"
    optional: bool       # the whole node may be left out
    suffix: int | None   # numeric suffix this node stands for (None: none allowed)
    suffix_required: bool


_NODE_TEXT = re.compile(r"^(\*?[A-Za-z]+)(?:(\d+)|\[(\d+)\])?$")
_HEADER_PART = re.compile(r"^(\*?[A-Za-z]+)(\d*)$")


def _node(text: str, optional: bool) -> _Node:
    match = _NODE_TEXT.match(text)
    if not match:
        raise ValueError(f"cannot read SCPI node {text!r}")
    name, fixed_suffix, optional_suffix = match.groups()
    short = "".join(c for c in name if c.isupper() or c == "*") or name.upper()
    if fixed_suffix is not None:
        return _Node(name.upper(), short, optional, int(fixed_suffix), True)
    if optional_suffix is not None:
        return _Node(name.upper(), short, optional, int(optional_suffix), False)
    return _Node(name.upper(), short, optional, None, False)


def parse_pattern(pattern: str) -> tuple[_Node, ...]:
    """Nodes of a header in manual notation, e.g. ``[:SENSe[1]]:FRESistance:NPLCycles``."""
    nodes: list[_Node] = []
    position = 0
    while position < len(pattern):
        if pattern[position] == "[":
            depth, end = 0, position
            while True:
                depth += {"[": 1, "]": -1}.get(pattern[end], 0)
                if depth == 0:
                    break
                end += 1
            inner = pattern[position + 1:end].lstrip(":")
            nodes.append(_node(inner, optional=True))
            position = end + 1
        else:
            if pattern[position] == ":":
                position += 1
            end = position
            while end < len(pattern) and pattern[end] not in ":[":
                end += 1
            if pattern[end:end + 3].startswith("[") and re.match(r"\[\d+\]", pattern[end:]):
                end = pattern.index("]", end) + 1
            nodes.append(_node(pattern[position:end], optional=False))
            position = end
    return tuple(nodes)


def _part_matches(node: _Node, part: str) -> bool:
    match = _HEADER_PART.match(part)
    if not match:
        return False
    name, digits = match.group(1).upper(), match.group(2)
    if name not in (node.long, node.short):
        return False
    if not digits:
        return not node.suffix_required
    return node.suffix is not None and int(digits) == node.suffix


def _matches(nodes: Sequence[_Node], parts: Sequence[str]) -> bool:
    if not nodes:
        return not parts
    node = nodes[0]
    if parts and _part_matches(node, parts[0]) and _matches(nodes[1:], parts[1:]):
        return True
    return node.optional and _matches(nodes[1:], parts)


# ---------------------------------------------------------------------------
# parameters
# ---------------------------------------------------------------------------
def _split_outside_quotes(text: str, separator: str) -> list[str]:
    if "'" not in text and '"' not in text:       # the usual case: nothing quoted
        return text.split(separator)
    pieces, current, quote = [], [], ""
    for character in text:
        if quote:
            current.append(character)
            if character == quote:
                quote = ""
        elif character in "'\"":
            quote = character
            current.append(character)
        elif character == separator:
            pieces.append("".join(current))
            current = []
        else:
            current.append(character)
    if quote:
        raise scpi_error(SYNTAX_ERROR)
    pieces.append("".join(current))
    return pieces


def single_argument(arguments: Sequence[str]) -> str:
    """The one parameter of a command (``-109`` if none, ``-108`` if more)."""
    if not arguments:
        raise scpi_error(MISSING_PARAMETER)
    if len(arguments) > 1:
        raise scpi_error(PARAMETER_NOT_ALLOWED)
    return arguments[0]


def parse_number(arguments: Sequence[str], low: float, high: float, *,
                 default: float | None = None, allow_infinity: bool = False) -> float:
    """A numeric parameter within ``[low, high]``; ``MINimum``, ``MAXimum``, ``DEFault`` accepted.

    A value outside the range is refused with ``-222,"Parameter data out of range"``.
    """
    text = single_argument(arguments).strip().upper()
    if text in ("MIN", "MINIMUM"):
        return low
    if text in ("MAX", "MAXIMUM"):
        return high
    if text in ("DEF", "DEFAULT") and default is not None:
        return default
    if allow_infinity and text in ("INF", "INFINITE"):
        return math.inf
    try:
        value = float(text)
    except ValueError:
        raise scpi_error(DATA_TYPE_ERROR) from None
    if not math.isfinite(value):
        raise scpi_error(DATA_TYPE_ERROR)
    if not low <= value <= high:
        raise scpi_error(PARAMETER_OUT_OF_RANGE)
    return value


def parse_boolean(arguments: Sequence[str]) -> bool:
    """``ON``/``OFF``/``1``/``0``."""
    text = single_argument(arguments).strip().upper()
    if text in ("ON", "1"):
        return True
    if text in ("OFF", "0"):
        return False
    try:
        float(text)
    except ValueError:
        raise scpi_error(ILLEGAL_PARAMETER_VALUE) from None
    raise scpi_error(PARAMETER_OUT_OF_RANGE)


def parse_choice(arguments: Sequence[str], choices: Sequence[str]) -> str:
    """One of ``choices`` (manual notation, e.g. ``REPeat``); returns the long form in upper case."""
    text = single_argument(arguments).strip().strip("'\"").upper()
    for choice in choices:
        node = _node(choice, optional=False)
        if text in (node.long, node.short):
            return node.long
    raise scpi_error(ILLEGAL_PARAMETER_VALUE)


def short_form(choice: str) -> str:
    """Short form of a mnemonic in manual notation (``REPeat`` -> ``REP``): what queries return."""
    return _node(choice, optional=False).short


# ---------------------------------------------------------------------------
# the command table
# ---------------------------------------------------------------------------
Handler = Callable[[list[str]], "str | None"]


@dataclass(frozen=True)
class _Command:
    nodes: tuple[_Node, ...]
    write: Handler | None
    query: Handler | None


class CommandTable:
    """Headers an instrument knows, with what it does on each."""

    def __init__(self) -> None:
        self._commands: list[_Command] = []
        self._found: dict[tuple[tuple[str, ...], bool], Handler | None] = {}
        self._by_header: dict[str, tuple[Handler, bool]] = {}   # exact absolute header text -> handler
        self._paths: dict[str, list[str] | None] = {}
        # whole messages of one absolute header without parameters seen before (``:INITiate``, ``:FETCh?``)
        self._whole: dict[str, tuple[Handler, bool]] = {}
        #: Replies of the message being executed that are waiting to be sent (IEEE 488.2 MAV).
        self.pending_replies = 0

    def add(self, pattern: str, *, write: Handler | None = None, query: Handler | None = None) -> None:
        """Register a header; ``write`` for the command form, ``query`` for ``HEADER?``."""
        self._commands.append(_Command(parse_pattern(pattern), write, query))
        self._found.clear()
        self._by_header.clear()
        self._paths.clear()
        self._whole.clear()

    def _find(self, parts: list[str], is_query: bool) -> Handler:
        key = (tuple(part.upper() for part in parts), is_query)
        if key not in self._found:
            self._found[key] = next(
                (handler for command in self._commands if _matches(command.nodes, parts)
                 for handler in [command.query if is_query else command.write] if handler is not None), None)
        handler = self._found[key]
        if handler is None:
            raise scpi_error(UNDEFINED_HEADER)
        return handler

    def execute(self, message: str, errors: ErrorQueue) -> str | None:
        """Run one program message; replies of its queries joined by ``;`` (None: no query).

        The first error goes to ``errors`` and ends the message: the units after it are
        not executed (the manuals' command execution rules, module docstring).
        """
        self.pending_replies = 0
        whole = self._whole.get(message)
        if whole is not None:        # the same text always means the same command, and it has no parameters
            handler, is_query = whole
            try:
                reply = handler([])
            except ScpiError as error:
                errors.push(error.code, error.message)
                return None
            if is_query and reply is not None:
                self.pending_replies = 1
                return reply
            return None
        replies: list[str] = []
        previous_path: list[str] = []
        by_header = self._by_header
        try:
            text = message.strip()
            quoted = "'" in text or '"' in text
            units = _split_outside_quotes(text, ";") if quoted else text.split(";")
            if len(units) == 1:
                header, _, parameter_text = units[0].strip().partition(" ")
                if header[:1] in ":*" and header in by_header and not parameter_text.strip():
                    self._whole[message] = by_header[header]
            for unit in units:
                unit = unit.strip()
                if not unit:
                    continue
                header, _, parameter_text = unit.partition(" ")
                known = by_header.get(header) if header[:1] in ":*" else None
                if known is not None:            # an absolute header seen before
                    handler, is_query = known
                    path = self._paths[header]
                    if path is not None:         # common (*) commands leave the path as it was
                        previous_path = path
                    if not parameter_text.strip():
                        arguments = []
                    elif quoted:
                        arguments = [a.strip() for a in _split_outside_quotes(parameter_text, ",")]
                    else:
                        arguments = [a.strip() for a in parameter_text.split(",")]
                    reply = handler(arguments)
                    if is_query and reply is not None:
                        replies.append(reply)
                        self.pending_replies = len(replies)
                    continue
                full_header = header
                is_query = header.endswith("?")
                header = header[:-1] if is_query else header
                if header.startswith("*"):
                    parts, absolute = [header], True
                else:
                    absolute = header.startswith(":")
                    parts = header.lstrip(":").split(":")
                    if not absolute and previous_path:
                        parts = previous_path + parts
                    previous_path = parts[:-1]
                if any(not part for part in parts):
                    raise scpi_error(SYNTAX_ERROR)
                arguments = ([a.strip() for a in _split_outside_quotes(parameter_text, ",")]
                             if parameter_text.strip() else [])
                handler = self._find(parts, is_query)
                if absolute:                     # the same text always means the same command
                    self._by_header[full_header] = (handler, is_query)
                    self._paths[full_header] = None if header.startswith("*") else previous_path
                reply = handler(arguments)
                if is_query and reply is not None:
                    replies.append(reply)
                    self.pending_replies = len(replies)
        except ScpiError as error:
            errors.push(error.code, error.message)
        return ";".join(replies) if replies else None
