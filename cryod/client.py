"""A Python client of a running cryod, for notebooks and experiment scripts.

It speaks the control socket's protocol (one command line in, one JSON line
out; :mod:`cryod.service.control_socket`), exactly as ``cryod ctl`` does, and
finds the daemon the same way (:func:`cryod.service.discovery.find_daemon_socket`)
when no socket is given. The daemon checks every value against its configured
limits; a refusal raises :class:`CommandRefused` with the daemon's reason.

Examples
--------
A gas-thermometry script that steps the flange and waits for it (not run here)::

    import cryod

    flange = cryod.connect()                        # or cryod.connect("/run/cryod/control.sock")
    flange.ramp(0.5)                                # K/min
    flange.setpoint(5.2)
    flange.wait_until_stable(tolerance_K=50e-6, hold_s=120, timeout_s=3600)
    print(flange.status()["T2_K"])
"""

from __future__ import annotations

import math
import time
from pathlib import Path

from cryod.service.control_socket import send_command
from cryod.service.daemon_status import status_from_json
from cryod.service.discovery import find_daemon_socket
from cryod.service.settling import SettlingWatch


class CommandRefused(RuntimeError):
    """The daemon refused a command; the message is its reason."""


class NotStable(TimeoutError):
    """:meth:`DaemonClient.wait_until_stable` gave up: out of time, the loop stopped regulating, or the
    daemon went away; the message says why and how far it got."""


class DaemonClient:
    """Commands and status of one running daemon.

    Parameters
    ----------
    socket : str or pathlib.Path, optional
        The daemon's control socket; by default the one ``cryod ctl`` would find.
    timeout_s : float
        How long to wait for each reply (s).
    """

    def __init__(self, socket: str | Path | None = None, timeout_s: float = 10.0):
        self.socket = Path(socket) if socket is not None else find_daemon_socket()
        self.timeout_s = timeout_s

    def __repr__(self) -> str:
        return f"DaemonClient({str(self.socket)!r})"

    def command(self, line: str) -> dict:
        """Send one command line; the daemon's reply (``ok``, ``message``, ``status``).

        Raises
        ------
        CommandRefused
            The daemon refused it (the message says why).
        ConnectionError
            No daemon answers at :attr:`socket`.
        """
        reply = send_command(self.socket, line, timeout_s=self.timeout_s)
        if not reply.get("ok"):
            raise CommandRefused(reply.get("message", "refused without a reason"))
        return reply

    def status(self) -> dict:
        """The loop's state, ``T2_K``, ``T5_K``, ``heater_W``, ``setpoint_K``, ``target_K``, timing, ...

        Values the daemon does not have are None (e.g. ``setpoint_K`` while the loop is open).
        """
        return self.command("status")["status"]

    def record_path(self) -> str | None:
        """The path of the record the daemon is writing now (None before its first row).

        A restart on the same day writes a new file (``cryod-DATE.2.csv``, ...): ask, rather than
        build the name from the date.
        """
        return status_from_json(self.status()).record_path

    def note(self, text: str) -> dict:
        """Write ``text`` into the record being written (``# event: note: TEXT (by ...)``) and the journal.

        Raises
        ------
        CommandRefused
            Empty text, text with control characters, or a line longer than the socket takes.
        ValueError
            ``text`` holds a line break.
        """
        return self.command(f"note {text}")["status"]

    def setpoint(self, kelvin: float) -> dict:
        """Regulate to ``kelvin`` (ramped at the configured rate); the status after the command took effect."""
        return self.command(f"setpoint {_plain(kelvin, 'kelvin')}")["status"]

    def ramp(self, kelvin_per_minute: float) -> dict:
        """Setpoint ramp rate (K/min; 0 for steps); the status after it took effect."""
        return self.command(f"ramp {_plain(kelvin_per_minute, 'kelvin_per_minute')}")["status"]

    def heater_off(self) -> dict:
        """Heater to 0 W and the loop open until a new setpoint."""
        return self.command("heater-off")["status"]

    def manual(self, watts: float) -> dict:
        """Open loop at ``watts`` of heater power (within R·I_max²)."""
        return self.command(f"manual {_plain(watts, 'watts')}")["status"]

    def feedforward(self, on: bool) -> dict:
        """Switch the feedforward locked to the cooler on or off (it fades in or out)."""
        return self.command(f"feedforward {'on' if on else 'off'}")["status"]

    def reload(self) -> dict:
        """Have the daemon read its configuration file again (as ``systemctl reload``); the status after it.

        Raises
        ------
        CommandRefused
            The file is not valid, or a change in it needs a restart: the message says which
            and the daemon keeps the configuration it runs on.
        """
        return self.command("reload")["status"]

    def alarms(self) -> list[dict]:
        """Every alarm that is on (``alarms`` section), each a dict: ``name``, ``state`` (``clear``, ``pending``,
        ``raised`` or ``latched``), ``acknowledged``, ``since_s`` (the daemon's clock), ``value``, ``message`` (its
        figure now) and ``raised_message`` (its figure when raised). The status' ``alarms`` holds those raised
        or latched."""
        return self.command("alarms")["alarms"]

    def acknowledge_alarm(self, name: str = "all") -> list[dict]:
        """Acknowledge the alarm ``name`` (or every one standing, ``all``): a latched alarm clears, a raised one
        clears when its condition is over; the alarms after it.

        Raises
        ------
        CommandRefused
            No such alarm is on, or it is not raised (the message says which).
        """
        return self.command(f"alarms ack {name}")["alarms"]

    def wait(self, seconds: float, poll_s: float = 0.5, sleep=time.sleep) -> dict:
        """Wait ``seconds`` of the daemon's clock; the status that ended the wait.

        On the real cryostat that is real time; a dry run at ``--speed 20`` waits a twentieth of it.

        Raises
        ------
        ConnectionError
            The daemon went away meanwhile.
        """
        start = None
        while True:
            status = self.status()
            now = status_from_json(status).loop.time_s
            if math.isfinite(now):
                start = now if start is None else start
                if now - start >= seconds:
                    return status
            sleep(poll_s)

    def wait_until_stable(self, tolerance_K: float = 1e-4, hold_s: float = 60.0, timeout_s: float = 3600.0,
                          poll_s: float = 0.5, wall_timeout_s: float | None = None, sleep=time.sleep,
                          wall=time.monotonic) -> dict:
        """Wait until the flange has settled at its setpoint.

        Settled is :class:`cryod.service.settling.SettlingWatch`'s rule (the IOC's STABLE is the same): the
        loop is closed, the ramp has reached the target, and for
        ``hold_s`` of the daemon's clock every status polled (each ``poll_s`` of wall
        time) had T2 averaged over its last 10 s (``T2_average_K``: 17 cooler periods,
        so the cooler's 0.5 to 1.8 mK line averages out) within ``tolerance_K`` of the
        setpoint. Time is the daemon's own clock, so a sped-up dry run settles as fast
        as it runs; ``wall_timeout_s`` of real time (default: as many seconds as ``timeout_s``)
        bounds the wait too, whatever the daemon's clock does.

        Returns
        -------
        dict
            The status that completed the wait.

        Raises
        ------
        NotStable
            ``timeout_s`` of the daemon's clock or ``wall_timeout_s`` of real time passed first, the
            loop left the closed state (heater off, fault), or the daemon stopped or its socket went
            away: the message says why and where T2 was.
        """
        watch = SettlingWatch(tolerance_K, hold_s)
        start = None
        where = "not settled"
        wall_limit_s = timeout_s if wall_timeout_s is None else wall_timeout_s
        wall_start = wall()
        while True:
            try:
                status = self.status()
            except ConnectionError as lost:
                raise NotStable(f"the daemon went away while waiting ({lost}); last seen: {where}") from None
            settling = watch.observe(status_from_json(status))
            if settling.cannot_settle is not None:
                raise NotStable(settling.cannot_settle)
            if settling.stable:
                return status
            now = settling.time_s
            start = now if start is None else start
            where = settling.where()
            if now - start > timeout_s:
                raise NotStable(f"not stable within {tolerance_K * 1e6:g} µK after {timeout_s:g} s: {where}")
            if wall() - wall_start > wall_limit_s:
                raise NotStable(f"not stable within {tolerance_K * 1e6:g} µK after {wall_limit_s:g} s of real time "
                                f"({now - start:.0f} s of the daemon's clock): {where}")
            sleep(poll_s)


def connect(socket: str | Path | None = None, timeout_s: float = 10.0) -> DaemonClient:
    """A :class:`DaemonClient` of the daemon at ``socket`` (default: found as ``cryod ctl`` finds it)."""
    return DaemonClient(socket, timeout_s)


def _plain(value: float, name: str) -> str:
    """A number as the socket accepts it (plain decimal), or ValueError naming the argument."""
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return repr(number)
