"""The operator's commands: one table with each command's arguments, parsing, checks, effect and help.

The control socket parses a command line with :func:`parse_command`; the
loop applies it at its next tick boundary with :func:`apply_command` (the
configured limits are checked there, against the configuration in force);
``cryod ctl --help`` lists :data:`COMMANDS`. A command is answered once
applied or refused, with the reason.

Examples
--------
>>> command = parse_command("setpoint 5.2")
>>> command.name, command.value
('setpoint', 5.2)
>>> parse_command("setpoint 1_5")
Traceback (most recent call last):
...
ValueError: 'setpoint' argument K: '1_5' is not a number (plain decimal digits only, e.g. 5.2 or 2.5e-3); usage: setpoint K
"""

from __future__ import annotations

import re
import threading
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable

from cryod.argument_types import plain_decimal, shown
from cryod.control.ramp import MIN_RATE_K_PER_MIN, rate_refusal
from cryod.control.regulator import RegulatorMode
from cryod.service.answer_words import SnapshotAnswer

if TYPE_CHECKING:
    from cryod.service.loop import ControlLoop

#: The words of a command line: separated by ASCII space or tabs only (not by other scripts' spaces).
_WORD = re.compile(r"[^ \t\n\r\v\f]+")
_WORD_SEPARATORS = re.compile(r"[ \t\n\r\v\f]+")


class CommandRefused(ValueError):
    """A command the loop does not carry out, with the reason."""


#: Where a command is between its client and the loop: waiting in the queue, taken by the loop (it will be
#: carried out and answered), or withdrawn by a client that stopped waiting (it will never be carried out).
PENDING, TAKEN, WITHDRAWN = "pending", "taken", "withdrawn"


@dataclass
class Command:
    """A request to the loop, answered at the next tick boundary.

    A command is carried out at most once, and only while its client still waits for it: the loop
    :meth:`take` s it before carrying it out, a client that stops waiting :meth:`withdraw` s it, and
    of the two only the first succeeds (one claim under a lock). A withdrawn command is answered as
    withdrawn and never applied; a taken one is always answered, within the tick that took it.

    ``on_answer``, when given, is called once the command is answered, on the thread that
    answers it (the loop's): it must return at once and never raise (the control socket
    uses it to wake its own thread).
    """

    name: str
    value: Any = None           # what its CommandSpec's parse gave
    done: threading.Event = field(default_factory=threading.Event)
    ok: bool = False
    message: str = ""
    on_answer: Callable[[], None] | None = field(default=None, repr=False, compare=False)
    #: Who asked: ``uid 1000 (alice), pid 4242`` for the control socket, ``SIGHUP`` for a reload signal.
    sender: str = ""
    #: More of the answer, as keys of the control socket's reply (``alarms`` for ``cryod ctl alarms``).
    reply: dict | None = None
    #: :data:`PENDING`, :data:`TAKEN` or :data:`WITHDRAWN`.
    claim: str = PENDING
    #: The command line it was parsed from (:func:`parse_command`), to pass it on as it was given.
    line: str = ""
    _claim_lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def answer(self, ok: bool, message: str) -> None:
        self.ok, self.message = ok, message
        self.done.set()
        if self.on_answer is not None:
            self.on_answer()

    def take(self) -> bool:
        """The loop claims the command to carry it out; False when its client withdrew it first."""
        return self._settle(TAKEN)

    def withdraw(self) -> bool:
        """The client stops waiting: True when the command will never be carried out, False when the loop
        has taken it already (its answer follows within the tick that took it)."""
        return self._settle(WITHDRAWN)

    def _settle(self, outcome: str) -> bool:
        with self._claim_lock:
            if self.claim == PENDING:
                self.claim = outcome
            return self.claim == outcome


#: How long a client that gave up on the loop still waits for a command the loop had taken already (s): the
#: rest of the tick that carries it out.
TAKEN_ANSWER_WAIT_S = 2.0


def no_answer(command: Command, timeout_s: float) -> Command:
    """A command whose client waited ``timeout_s`` in vain, withdrawn so that it never takes effect later.

    When the loop took it meanwhile (it is being carried out), its answer is not owed to a withdrawal: the
    caller waits :data:`TAKEN_ANSWER_WAIT_S` more for it (:func:`wait_for`, :func:`loop_answer`) and this
    only says what is known when even that does not come."""
    if command.withdraw():
        command.ok, command.message = False, (f"no answer from the control loop within {timeout_s:g} s: withdrawn, "
                                              f"it will not be carried out")
    elif not command.done.is_set():
        command.ok, command.message = False, (f"taken by the control loop, but not answered within {timeout_s:g} s "
                                              f"and {TAKEN_ANSWER_WAIT_S:g} s more: it may have taken effect; "
                                              f"check the status")
    return command


def wait_for(command: Command, timeout_s: float = 5.0) -> Command:
    """Block until the loop has answered ``command``; after ``timeout_s`` it is withdrawn (:func:`no_answer`)."""
    if command.done.wait(timeout_s):
        return command
    if not command.withdraw() and command.done.wait(TAKEN_ANSWER_WAIT_S):
        return command
    return no_answer(command, timeout_s)


# -- what each command does to the loop ------------------------------------------------
def _setpoint(loop: "ControlLoop", value: float) -> str:
    control = loop.config.control
    if not control.setpoint_min_K <= value <= control.setpoint_max_K:
        raise CommandRefused(f"setpoint {value:g} K refused: outside {control.setpoint_min_K:g}.."
                             f"{control.setpoint_max_K:g} K (control.setpoint_min_K/max_K)")
    regulator = loop.regulator
    regulator.ramp.target_K = value
    warning = loop.warn_about_setpoint(value)
    said = f"; warning: {warning}" if warning else ""
    if loop.state.waits_for_readings:
        regulator.mode = RegulatorMode.CLOSED
        return f"setpoint {value:g} K, applied once readings are valid{said}"
    if regulator.mode is not RegulatorMode.CLOSED:
        loop.close_loop_now()
    ramp = regulator.ramp.rate_K_per_min
    return f"setpoint {value:g} K" + (f", ramping at {ramp:g} K/min" if ramp else "") + said


def _ramp(loop: "ControlLoop", value: float) -> str:
    limit = loop.config.control.max_ramp_K_per_min
    refusal = rate_refusal(value)
    if refusal is not None:
        raise CommandRefused(f"ramp refused: {refusal}")
    if not 0.0 <= value <= limit:
        raise CommandRefused(f"ramp {value:g} K/min refused: outside 0..{limit:g} K/min (control.max_ramp_K_per_min)")
    loop.regulator.ramp.rate_K_per_min = value
    return f"ramp {value:g} K/min"


def _heater_off(loop: "ControlLoop", value: None) -> str:
    loop.regulator.switch_off()
    loop.follow_regulator()
    return "heater off; give a setpoint to regulate again"


def _manual(loop: "ControlLoop", value: float) -> str:
    try:
        loop.regulator.set_manual(value)
    except ValueError as error:
        raise CommandRefused(str(error)) from None
    loop.follow_regulator()
    return f"open loop, heater {value:g} W"


def _modulate(loop: "ControlLoop", value) -> str:
    from cryod.control.regulator import HeaterModulation

    try:
        modulation = value if isinstance(value, HeaterModulation) else HeaterModulation(*value)
        loop.regulator.set_modulated(modulation)
    except (ValueError, TypeError) as error:
        raise CommandRefused(str(error)) from None
    loop.follow_regulator()
    return (f"open loop, heater {modulation.mean_w:g} +- {modulation.amplitude_w:g} W at "
            f"{modulation.angular_frequency_rad_s:g} rad/s")


def _feedforward(loop: "ControlLoop", value: str) -> str | SnapshotAnswer:
    from cryod.control.feedforward.status_text import status_text  # numpy: not for cryod ctl's import
    from cryod.control.feedforward.term import FeedforwardTerm

    term = loop.regulator.term("feedforward")
    if not isinstance(term, FeedforwardTerm):
        raise CommandRefused("this daemon has no feedforward term")
    if value in ("on", "off"):
        term.switch(value == "on")
        locked = term.phase_locked
        return (f"feedforward {value}: fading {'in' if value == 'on' else 'out'} over "
                f"{term.settings.fade_time_s:g} s" + ("" if value == "off" or locked
                                                        else " once the cooler's phase is locked (a few seconds)"))
    return SnapshotAnswer(term.status_snapshot(), status_text)     # words off the loop's thread


def _note(loop: "ControlLoop", value) -> str:
    raise CommandRefused("a note is written into the record by the daemon (cryod ctl note TEXT), not by the loop")


def note_text(text: str) -> str:
    """A note's text as the record takes it: printable, on one line, not empty (ValueError otherwise)."""
    text = text.strip(" \t")
    if not text:
        raise ValueError("empty")
    bad = next((character for character in text if not character.isprintable()), None)
    if bad is not None:
        raise ValueError(f"not printable text (holds {bad!r})")
    return text


def _choice(*choices: str) -> Callable[[str], str]:
    def parse(text: str) -> str:
        if text not in choices:
            raise ValueError(f"not one of {', '.join(choices)}")
        return text
    return parse


def _alarm_request(text: str) -> tuple[str, str]:
    """``ack NAME`` or ``ack all``: ("ack", NAME)."""
    from cryod.alarms.settings import ALARM_NAMES

    words = text.split()
    if words[0] != "ack":
        raise ValueError("not 'ack NAME' or 'ack all'")
    if words[1] not in (*ALARM_NAMES, "all"):
        raise ValueError(f"names no alarm: give one of {', '.join(ALARM_NAMES)}, or all")
    return "ack", words[1]


def _reload(loop: "ControlLoop", value) -> str:
    if value is None:          # the socket's "reload": the daemon reads the file and hands the result here
        raise CommandRefused("reload needs the configuration the daemon has read and checked; "
                             "ask the daemon (cryod ctl reload), not the loop")
    return loop.reload(value)


@dataclass(frozen=True)
class CommandSpec:
    """One command.

    Attributes
    ----------
    name : str
    argument : str or None
        The argument's name and unit in the help (``K``), or None for none.
    help : str
    apply : callable or None
        ``apply(loop, value) -> message``, run on the loop thread; raises
        :class:`CommandRefused`. The message is the answer's text, or, for a command that only reads
        (``feedforward status``), a :class:`~cryod.service.answer_words.SnapshotAnswer` the loop has put
        in words off its thread (:mod:`cryod.service.answer_words`). None: answered by the socket itself
        (``status``) or the daemon (``alarms``: :class:`cryod.service.alarms.AlarmMonitor`).
    from_socket : bool
        Offered on the control socket (``modulate`` is for ``cryod identify --acquire`` only).
    parse : callable
        Argument text to value (ValueError when malformed); numbers follow the command line's
        rule, :func:`cryod.argument_types.plain_decimal`.
    word_counts : tuple of int, optional
        How many words the argument may have (given, it takes the words joined by a space;
        0 among them: the argument may be left out, and the value is None). Default: one
        word when there is an argument, none otherwise.
    rest_of_line : bool
        The argument is the rest of the line, spaces included (a note's text).
    """

    name: str
    argument: str | None
    help: str
    apply: Callable[["ControlLoop", Any], str | SnapshotAnswer] | None      # takes what parse gives
    from_socket: bool = True
    parse: Callable[[str], object] = plain_decimal
    word_counts: tuple[int, ...] | None = None
    rest_of_line: bool = False

    @property
    def counts(self) -> tuple[int, ...]:
        """How many words the argument may have."""
        return self.word_counts if self.word_counts is not None else ((1,) if self.argument else (0,))

    @property
    def usage(self) -> str:
        return f"{self.name} {self.argument}" if self.argument else self.name


#: Every command, in the order of the help.
COMMANDS: dict[str, CommandSpec] = {spec.name: spec for spec in (
    CommandSpec("status", None, "the loop's state, temperatures, heater, setpoint and timing", None),
    CommandSpec("setpoint", "K", "regulate to K (within control.setpoint_min_K..setpoint_max_K)", _setpoint),
    CommandSpec("ramp", "K_PER_MIN", f"setpoint ramp rate, 0 for steps (at least {MIN_RATE_K_PER_MIN:g}, at most "
                "control.max_ramp_K_per_min)", _ramp),
    CommandSpec("heater-off", None, "heater to 0 W, loop open, until a new setpoint", _heater_off),
    CommandSpec("manual", "W", "open loop at W (at most R * I_max^2)", _manual),
    CommandSpec("feedforward", "on|off|status", "switch the feedforward locked to the cooler (fades in or out), "
                "or show its state", _feedforward, parse=_choice("on", "off", "status")),
    CommandSpec("alarms", "[ack NAME|all]", "the alarms that are on and what stands; ack NAME (or all) acknowledges: "
                "a latched alarm clears, a raised one clears when its condition is over", None,
                parse=_alarm_request, word_counts=(0, 2)),
    CommandSpec("reload", None, "read the configuration file again and apply it if it is valid and needs no "
                "restart (as systemctl reload)", _reload),
    CommandSpec("note", "TEXT", "write TEXT into the record being written (# event: note: TEXT, with who sent it) "
                "and the journal", _note, parse=note_text, rest_of_line=True),
    CommandSpec("modulate", "(MEAN_W, AMPLITUDE_W, RAD_S)", "open loop, heater modulated about a mean "
                "(cryod identify --acquire)", _modulate, from_socket=False),
)}


def socket_usage() -> str:
    """``status | setpoint K | ...``: the commands the socket takes."""
    return " | ".join(spec.usage for spec in COMMANDS.values() if spec.from_socket)


def parse_command(line: str) -> Command:
    """Turn a control-socket line into a :class:`Command`, or raise ValueError with the reason.

    Parameters
    ----------
    line : str
        One command line: the command's name and its argument, if any, separated by ASCII
        space or tabs.

    Returns
    -------
    Command

    Raises
    ------
    ValueError
        Empty, unknown command, wrong number of arguments, or an argument its parser refuses
        (the message names the command, the argument and what was wrong with it).
    """
    words = _WORD.findall(line)
    spec = COMMANDS.get(words[0]) if words else None
    if spec is None or not spec.from_socket:
        what = "empty command" if not words else f"unknown command {shown(words[0])}"
        raise ValueError(f"{what}; commands: {socket_usage()}")
    arguments = words[1:]
    if spec.rest_of_line and arguments:
        arguments = [_WORD_SEPARATORS.split(line.strip(" \t\n\r\v\f"), maxsplit=1)[1]]
    if len(arguments) not in spec.counts:
        counts = " or ".join(str(count) for count in spec.counts)
        raise ValueError(f"'{spec.name}' takes {counts} argument(s): {spec.usage}")
    if not arguments:
        return Command(spec.name, line=spec.name)
    text = " ".join(arguments)
    try:
        value = spec.parse(text)
    except ValueError as error:
        raise ValueError(f"'{spec.name}' argument {spec.argument}: {shown(text)} is {error}; "
                         f"usage: {spec.usage}") from None
    return Command(spec.name, value, line=f"{spec.name} {text}")


def apply_command(loop: "ControlLoop", command: Command) -> tuple[bool, str | SnapshotAnswer]:
    """Carry out ``command`` on the loop (loop thread, tick boundary): (accepted, message: the answer's text, or a
    snapshot to put in words off the loop's thread)."""
    spec = COMMANDS.get(command.name)
    if spec is None or spec.apply is None:
        return False, f"unknown command {command.name!r}"
    try:
        return True, spec.apply(loop, command.value)
    except (CommandRefused, ValueError, TypeError) as error:     # a malformed value from a caller in process
        return False, str(error)
