"""The Lake Shore Model 336's command set, answered from the daemon's status: what a 336 driver sees.

A lab's existing 336 drivers (PyMeasure, QCoDeS, EPICS, LabVIEW) talk to cryod as to a 336: input
A is the flange (T2), input B the cooler's second stage (T5), output 1 the flange heater. This
module is the protocol only: one message in, the replies out and the commands for the loop; the
TCP server is :mod:`cryod.interfaces.lakeshore336_server`. docs/reference/lakeshore336.md lists every command,
the mapping of each value and the manual's sections (Lake Shore Model 336 user's manual,
chapter 6).

As the manual describes:

* a message is one line of at most :data:`MAX_MESSAGE` characters ending in a line feed (a
  carriage return before it is taken as part of the terminator); several commands may be chained
  with ``;`` and the replies to the queries among them come back in one line, separated by ``;``;
  every reply line ends in carriage return and line feed;
* commands (no ``?``) are never answered; what went wrong is kept in the standard event status
  register, read and cleared with ``*ESR?``: 32 (CME) for a command the 336 does not know or a
  malformed message, 16 (EXE) for a parameter out of its range or a setting cryod refuses (a
  setpoint beyond ``control.setpoint_max_K``, any write while ``lakeshore336.writable`` is false,
  ``*RST``). A query that cannot be answered is not answered, as on the 336.

Each connection has its own status registers, so one client's errors do not show in another's.

Examples
--------
>>> from cryod.service.daemon_status import DaemonStatus, LoopStatus
>>> session = Lakeshore336Session(Lakeshore336Setup.example(), writable=False, peer="127.0.0.1:5000")
>>> status = DaemonStatus(LoopStatus(state="closed", flange_K=5.0001234, ptc_stage_K=3.41, setpoint_K=5.0,
...                                  target_K=5.0, last_target_K=5.0, heater_w=0.125),
...                       flange_ohm=1587.2, ptc_stage_ohm=2011.0)
>>> [session.respond(part, status) for part in split_message("KRDG? A;HTR? 1;RANGE? 1")]
['+5.000123', '+25.000', '3']
>>> session.respond("SETP 1,5.2", status) is None, session.respond("*ESR?", status)
(True, '016')
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass

from cryod import __version__
from cryod.service.commands import Command, parse_command
from cryod.service.daemon_status import DaemonStatus

log = logging.getLogger("cryod.lakeshore336")

#: Longest message (characters, terminator not counted), as the 336 takes.
MAX_MESSAGE = 255
#: Standard event status register bits (manual section 6.2.5, figure 6-2).
OPERATION_COMPLETE, QUERY_ERROR, EXECUTION_ERROR, COMMAND_ERROR = 1, 4, 16, 32
#: The inputs and outputs a 336 has; cryod's are A, B and output 1, the others read as disabled or off.
INPUTS = ("A", "B", "C", "D")
OUTPUTS = ("1", "2", "3", "4")
#: The 336's default gains of an output cryod does not drive (P, I, D).
DEFAULT_PID = (50.0, 20.0, 0.0)


@dataclass(frozen=True)
class CurveHeader:
    """A thermometer's calibration as ``CRVHDR?`` gives it."""

    name: str
    serial: str
    limit_K: float


@dataclass(frozen=True)
class Lakeshore336Setup:
    """What the 336's answers need from the configuration in force (it changes on reload).

    Attributes
    ----------
    heater_max_w : float
        R * I_max^2: 100 % of ``HTR?`` and of the heater range.
    heater_resistance_ohm, heater_max_current_A : float
    proportional_W_per_K, integral_W_per_K_s : float or None
        The PI gains (None without a PI term).
    flange_max_K, ptc_stage_max_K : float
        The over-temperature limits (``TLIMIT?`` of inputs A and B).
    curves : dict
        ``CurveHeader`` of inputs A and B (user curves 21 and 22).
    serial : str
        The third field of ``*IDN?``: the lab's name for the cryostat.
    """

    heater_max_w: float
    heater_resistance_ohm: float
    heater_max_current_A: float
    proportional_W_per_K: float | None
    integral_W_per_K_s: float | None
    flange_max_K: float
    ptc_stage_max_K: float
    curves: dict
    serial: str = "cryod"

    @classmethod
    def from_config(cls, config, flange_curve, ptc_stage_curve) -> "Lakeshore336Setup":
        """From a :class:`cryod.config.DaemonConfig` and the two calibration curves."""
        pi = dict(config.control.terms).get("pi")
        return cls(heater_max_w=config.heater.max_power_w, heater_resistance_ohm=config.heater.resistance_ohm,
                   heater_max_current_A=config.heater.max_current_A,
                   proportional_W_per_K=getattr(pi, "proportional_w_per_K", None),
                   integral_W_per_K_s=getattr(pi, "integral_w_per_K_s", None),
                   flange_max_K=config.safety.flange_max_K, ptc_stage_max_K=config.safety.ptc_stage_max_K,
                   curves={"A": _curve_header(flange_curve), "B": _curve_header(ptc_stage_curve)},
                   serial=_field(config.metrics.cryostat or "cryod", 15))

    @classmethod
    def example(cls) -> "Lakeshore336Setup":
        """The example configuration's heater, gains and limits (tests, doctests)."""
        return cls(0.5, 50.0, 0.1, 10.0, 0.2, 25.0, 15.0,
                   {"A": CurveHeader("CX-1050-SD-HT", "X186279", 325.0),
                    "B": CurveHeader("CX-1050-SD-HT", "X207058", 325.0)})


def _field(text: str, length: int) -> str:
    """Text safe inside a reply field: no separators or terminators, at most ``length`` characters."""
    return re.sub(r"[,;\r\n\"]", " ", str(text)).strip()[:length] or "-"


def _curve_header(curve) -> CurveHeader:
    return CurveHeader(_field(curve.sensor_model or "cryod curve", 15), _field(curve.serial_number or "-", 10),
                       float(curve.temperature_range_K[1]))


def split_message(text: str) -> list[str]:
    """The commands of one message (``;`` separated), without surrounding spaces; empty parts dropped."""
    return [part.strip() for part in text.split(";") if part.strip()]


class _Refused(Exception):
    """A command or query that sets a bit of the event status register and gets no answer."""

    def __init__(self, bit: int):
        super().__init__(bit)
        self.bit = bit


def _number(value: float | None, digits: int) -> str:
    """A reply number: sign, fixed point; the 336's ``+0`` for a value it does not have."""
    if value is None or not math.isfinite(value):
        value = 0.0
    return f"{value:+.{digits}f}"


def _choice(arguments: list[str], index: int, choices) -> str:
    if len(arguments) <= index or arguments[index].upper() not in choices:
        raise _Refused(EXECUTION_ERROR)
    return arguments[index].upper()


def _count(arguments: list[str], count: int) -> None:
    if len(arguments) != count:
        raise _Refused(COMMAND_ERROR)


class Lakeshore336Session:
    """One connection's view of the 336: its status registers, and what each message does.

    Parameters
    ----------
    setup : Lakeshore336Setup or callable
        The configuration's part, or a callable returning it (the one in force after a reload).
    writable : bool
        ``lakeshore336.writable``: whether SETP, RAMP and RANGE reach the loop.
    peer : str
        The client's address (``127.0.0.1:54321``, with its user for a client on this computer), in the journal
        with every write.
    write_refusal : str, optional
        Why this client may not write although the interface is writable (its user may not use the control
        socket, its address is not in ``lakeshore336.write_from``); None: it may.
    """

    def __init__(self, setup, writable: bool, peer: str, write_refusal: str | None = None):
        self._setup = setup if callable(setup) else (lambda: setup)
        self.writable = writable
        self.peer = peer
        self.write_refusal = write_refusal
        #: Standard event status register and its enable mask.
        self.event_status = 0
        self.event_enable = 0

    @property
    def sender(self) -> str:
        """Who sends this connection's commands, as the journal and the record say it."""
        return f"Lake Shore 336 interface, {self.peer}"

    def respond(self, text: str, status: DaemonStatus) -> str | Command | None:
        """What one command of a message does.

        Returns
        -------
        str
            The answer to a query.
        Command
            A command for the loop (hand it over, then call :meth:`answered`).
        None
            Nothing to answer (a command done here, or refused: the register says why).
        """
        mnemonic, _, rest = text.partition(" ")
        mnemonic = mnemonic.upper()
        arguments = [argument.strip() for argument in rest.split(",")] if rest.strip() else []
        handler = _QUERIES.get(mnemonic) or _COMMANDS.get(mnemonic)
        try:
            if handler is None:
                raise _Refused(COMMAND_ERROR)
            return handler(self, arguments, status)
        except _Refused as refused:
            self.event_status |= refused.bit
            return None

    def answered(self, command: Command) -> None:
        """The loop's answer to a command :meth:`respond` gave: a refusal sets EXE."""
        if not command.ok:
            self.event_status |= EXECUTION_ERROR

    def malformed(self) -> None:
        """A message dropped unread: longer than :data:`MAX_MESSAGE`, or not ASCII text."""
        self.event_status |= COMMAND_ERROR

    # -- writes ---------------------------------------------------------------------------
    def _check_writable(self, what: str) -> None:
        if not self.writable:
            log.warning("Lake Shore 336 interface: %s refused: lakeshore336.writable is false (by %s)",
                        what, self.sender)
            raise _Refused(EXECUTION_ERROR)
        if self.write_refusal is not None:
            log.warning("Lake Shore 336 interface: %s refused: %s (by %s)", what, self.write_refusal, self.sender)
            raise _Refused(EXECUTION_ERROR)

    def _write(self, line: str) -> Command:
        """The command line for the loop, checked as the control socket checks it; refused when read-only."""
        self._check_writable(line)
        try:
            command = parse_command(line)
        except ValueError:
            raise _Refused(EXECUTION_ERROR) from None
        command.sender = self.sender
        return command

    # -- the common commands (IEEE 488.2) --------------------------------------------------
    def _identity(self, arguments, status) -> str:
        _count(arguments, 0)
        return f"CRYOD,MODEL336,{self._setup().serial},{__version__}"

    def _operation_complete_query(self, arguments, status) -> str:
        _count(arguments, 0)
        return "1"

    def _operation_complete(self, arguments, status) -> None:
        _count(arguments, 0)
        self.event_status |= OPERATION_COMPLETE

    def _event_status_query(self, arguments, status) -> str:
        _count(arguments, 0)
        value, self.event_status = self.event_status, 0
        return f"{value:03d}"

    def _event_enable_query(self, arguments, status) -> str:
        _count(arguments, 0)
        return f"{self.event_enable:03d}"

    def _event_enable(self, arguments, status) -> None:
        _count(arguments, 1)
        if not arguments[0].isdigit() or int(arguments[0]) > 255:
            raise _Refused(EXECUTION_ERROR)
        self.event_enable = int(arguments[0])

    def _status_byte(self, arguments, status) -> str:
        _count(arguments, 0)
        return f"{32 if self.event_status & self.event_enable else 0:03d}"

    def _clear(self, arguments, status) -> None:
        _count(arguments, 0)
        self.event_status = 0

    def _reset(self, arguments, status) -> None:
        log.warning("Lake Shore 336 interface: *RST refused: cryod's settings come from its configuration, "
                    "not from a reset (by %s)", self.sender)
        raise _Refused(EXECUTION_ERROR)

    # -- inputs ------------------------------------------------------------------------------
    def _input(self, arguments, all_allowed: bool = False) -> str:
        _count(arguments, 1)
        return _choice(arguments, 0, INPUTS + (("0",) if all_allowed else ()))

    def _kelvin(self, arguments, status) -> str:
        which = self._input(arguments, all_allowed=True)
        value = {"A": status.loop.flange_K, "B": status.loop.ptc_stage_K}
        return ",".join(_number(value.get(name), 6) for name in (INPUTS if which == "0" else (which,)))

    def _celsius(self, arguments, status) -> str:
        which = self._input(arguments, all_allowed=True)
        value = {"A": status.loop.flange_K, "B": status.loop.ptc_stage_K}
        return ",".join(_number(None if value.get(name) is None else value[name] - 273.15, 6)
                        for name in (INPUTS if which == "0" else (which,)))

    def _sensor_units(self, arguments, status) -> str:
        which = self._input(arguments, all_allowed=True)
        value = {"A": status.flange_ohm, "B": status.ptc_stage_ohm}
        return ",".join(_number(value.get(name), 4) for name in (INPUTS if which == "0" else (which,)))

    def _reading_status(self, arguments, status) -> str:
        which = self._input(arguments)
        value = {"A": status.loop.flange_K, "B": status.loop.ptc_stage_K}.get(which)
        return "000" if value is not None and math.isfinite(value) else "001"     # bit 0: invalid reading

    def _input_type(self, arguments, status) -> str:
        which = self._input(arguments)
        # sensor type 3 (NTC RTD: a Cernox), autorange on, range 0, no compensation, units kelvin;
        # the inputs cryod does not read are disabled (type 0)
        return "3,1,0,0,1" if which in ("A", "B") else "0,0,0,0,1"

    def _input_name(self, arguments, status) -> str:
        which = self._input(arguments)
        return {"A": "flange T2", "B": "PTC stage T5"}.get(which, "")

    def _input_curve(self, arguments, status) -> str:
        which = self._input(arguments)
        return {"A": "21", "B": "22"}.get(which, "0")

    def _curve_header(self, arguments, status) -> str:
        _count(arguments, 1)
        if not arguments[0].isdigit() or int(arguments[0]) > 59:
            raise _Refused(EXECUTION_ERROR)
        curve = {21: self._setup().curves["A"], 22: self._setup().curves["B"]}.get(int(arguments[0]))
        if curve is None:
            return "No Curve,-,3,+0.000,1"          # an empty slot (curve 0: no curve on that input)
        return f"{curve.name},{curve.serial},4,{_number(curve.limit_K, 3)},1"  # log ohm / K, negative

    def _temperature_limit(self, arguments, status) -> str:
        which = self._input(arguments)
        setup = self._setup()
        return _number({"A": setup.flange_max_K, "B": setup.ptc_stage_max_K}.get(which, 0.0), 3)

    # -- outputs -----------------------------------------------------------------------------
    def _output(self, arguments, count: int = 1, outputs=OUTPUTS) -> str:
        _count(arguments, count)
        return _choice(arguments, 0, outputs)

    def _setpoint_query(self, arguments, status) -> str:
        if self._output(arguments) != "1":
            return _number(0.0, 6)
        # the target the loop heads for, also while the heater is off (the 336 keeps its setpoint)
        loop = status.loop
        return _number(loop.target_K if loop.target_K is not None else loop.last_target_K, 6)

    def _setpoint(self, arguments, status) -> Command:
        if self._output(arguments, 2) != "1":
            raise _Refused(EXECUTION_ERROR)
        return self._write(f"setpoint {arguments[1]}")

    def _ramp_query(self, arguments, status) -> str:
        if self._output(arguments) != "1":
            return "0,+0.0"
        rate = status.loop.ramp_K_per_min or 0.0
        return f"{1 if rate > 0 else 0},{_number(rate, 3)}"

    def _ramp(self, arguments, status) -> Command:
        if self._output(arguments, 3) != "1":
            raise _Refused(EXECUTION_ERROR)
        on = _choice(arguments, 1, ("0", "1"))
        return self._write(f"ramp {arguments[2] if on == '1' else '0'}")

    def _ramp_status(self, arguments, status) -> str:
        if self._output(arguments) != "1":
            return "0"
        setpoint, target = status.loop.setpoint_K, status.loop.target_K
        return "1" if setpoint is not None and target is not None and abs(setpoint - target) > 1e-9 else "0"

    def _heater_percent(self, status) -> float:
        """The output's level in % of R*I_max^2: while regulating, its power over the last whole cooler cycles
        (the level a 336 shows; the feedforward's waveform averages out), else the power set now."""
        heater = status.loop.heater_w
        level = status.recent.heater_mean_W if status.recent is not None else math.nan
        if status.regulating and math.isfinite(level):
            heater = level
        return 100.0 * heater / self._setup().heater_max_w if math.isfinite(heater) else 0.0

    def _heater_output(self, arguments, status) -> str:
        if self._output(arguments) != "1":            # (outputs 3 and 4 are off: 0 %, as AOUT? would say)
            return _number(0.0, 3)
        return _number(self._heater_percent(status), 3)

    def _heater_status(self, arguments, status) -> str:
        if self._output(arguments, outputs=("1", "2")) != "1":
            return "0"
        loop = status.loop
        stopped_on_heater = loop.state == "stopped" and (loop.last_fault or "").startswith("heater_")
        return "1" if stopped_on_heater or not math.isfinite(loop.heater_w) else "0"

    def _range_query(self, arguments, status) -> str:
        if self._output(arguments) != "1":
            return "0"
        return "3" if status.regulating or status.loop.state == "manual" else "0"

    def _range(self, arguments, status) -> Command | None:
        if self._output(arguments, 2) != "1":
            raise _Refused(EXECUTION_ERROR)
        level = _choice(arguments, 1, ("0", "1", "2", "3"))
        if level == "0":
            return self._write("heater-off")
        self._check_writable(f"RANGE 1,{level}")
        if status.regulating:
            return None                             # already regulating: nothing to change
        loop = status.loop
        target = loop.target_K if loop.target_K is not None else loop.last_target_K
        if target is None:
            log.warning("Lake Shore 336 interface: RANGE 1,%s refused: no setpoint to regulate to; give one "
                        "with SETP 1,<K> (by %s)", level, self.sender)
            raise _Refused(EXECUTION_ERROR)
        return self._write(f"setpoint {target!r}")

    def _output_mode(self, arguments, status) -> str:
        if self._output(arguments) != "1":
            return "0,0,0"
        mode = 1 if status.regulating else 3 if status.loop.state == "manual" else 0
        return f"{mode},1,0"                        # controlled from input A, not on at power-up

    def _pid(self, arguments, status) -> str:
        which = self._output(arguments, outputs=("1", "2"))
        setup = self._setup()
        if which != "1" or not setup.proportional_W_per_K:
            p, i, d = DEFAULT_PID
        else:
            # output % of R*I_max^2 per kelvin; integral as the 336's reset, 1000 / (integral time in s)
            p = 100.0 * setup.proportional_W_per_K / setup.heater_max_w
            i = 1000.0 * (setup.integral_W_per_K_s or 0.0) / setup.proportional_W_per_K
            d = 0.0
        return f"{_number(p, 1)},{_number(i, 1)},{_number(d, 0)}"

    def _manual_output(self, arguments, status) -> str:
        if self._output(arguments) != "1" or status.loop.state != "manual":
            return _number(0.0, 3)
        return _number(self._heater_percent(status), 3)

    def _heater_setup(self, arguments, status) -> str:
        which = self._output(arguments)
        setup = self._setup()
        if which != "1":
            return "0,1,0,+0.000,1"
        resistance = 2 if setup.heater_resistance_ohm >= 37.5 else 1        # the 336's 25 or 50 ohm setting
        return f"0,{resistance},0,{_number(setup.heater_max_current_A, 3)},2"   # current, user max, power shown

    def _not_taken(self, arguments, status) -> None:
        """A 336 setting cryod does not take over this interface (its configuration sets it)."""
        raise _Refused(EXECUTION_ERROR)


_QUERIES = {
    "*IDN?": Lakeshore336Session._identity, "*OPC?": Lakeshore336Session._operation_complete_query,
    "*ESR?": Lakeshore336Session._event_status_query, "*ESE?": Lakeshore336Session._event_enable_query,
    "*STB?": Lakeshore336Session._status_byte,
    "KRDG?": Lakeshore336Session._kelvin, "CRDG?": Lakeshore336Session._celsius,
    "SRDG?": Lakeshore336Session._sensor_units, "RDGST?": Lakeshore336Session._reading_status,
    "INTYPE?": Lakeshore336Session._input_type, "INNAME?": Lakeshore336Session._input_name,
    "INCRV?": Lakeshore336Session._input_curve, "CRVHDR?": Lakeshore336Session._curve_header,
    "TLIMIT?": Lakeshore336Session._temperature_limit,
    "SETP?": Lakeshore336Session._setpoint_query, "RAMP?": Lakeshore336Session._ramp_query,
    "RAMPST?": Lakeshore336Session._ramp_status, "HTR?": Lakeshore336Session._heater_output,
    "HTRST?": Lakeshore336Session._heater_status, "RANGE?": Lakeshore336Session._range_query,
    "OUTMODE?": Lakeshore336Session._output_mode, "PID?": Lakeshore336Session._pid,
    "MOUT?": Lakeshore336Session._manual_output, "HTRSET?": Lakeshore336Session._heater_setup,
}
_COMMANDS = {
    "*OPC": Lakeshore336Session._operation_complete, "*ESE": Lakeshore336Session._event_enable,
    "*CLS": Lakeshore336Session._clear, "*RST": Lakeshore336Session._reset,
    "SETP": Lakeshore336Session._setpoint, "RAMP": Lakeshore336Session._ramp, "RANGE": Lakeshore336Session._range,
    **{name: Lakeshore336Session._not_taken for name in ("PID", "MOUT", "OUTMODE", "HTRSET", "INTYPE", "INNAME",
                                                         "INCRV", "TLIMIT", "CRVHDR", "CRVPT", "CRVDEL", "ZONE",
                                                         "ALARM", "RELAY", "DISPLAY", "BRIGT", "LEDS", "LOCK",
                                                         "MODE", "FILTER", "*SRE", "*TRG", "*WAI")},
}

#: Every query and command this module answers (docs/reference/lakeshore336.md lists them).
SUPPORTED = tuple(sorted(_QUERIES)) + tuple(sorted(name for name, handler in _COMMANDS.items()
                                                   if handler is not Lakeshore336Session._not_taken))
