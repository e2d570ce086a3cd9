"""Who put a value: the Channel Access or pvAccess client's user and host, as EPICS' access security sees them.

softioc hands a put to Python without its client. EPICS' access security knows it: for every put
to a record whose access security group has a ``RULE(1, WRITE, TRAPWRITE)``, both servers (Channel
Access's rsrv and pvAccess's QSRV) call the trap-write listeners with the client's user and host
before the put. :class:`ClientIdentity` is such a listener (``asTrapWriteRegisterListener`` of
EPICS base, through ctypes): it keeps the last writer of each record, which the put's handling
takes when it sends the command on, so that the daemon's journal and record name the person.
cryod's own access security rules trap every write; a lab's file that leaves TRAPWRITE out gets
puts sent as from "EPICS IOC".
"""

from __future__ import annotations

import ctypes
import threading

from epicscorelibs.ioc import dbCore


class _TrapWriteMessage(ctypes.Structure):
    """``asTrapWriteMessage`` of EPICS base's asTrapWrite.h."""

    _fields_ = [("userid", ctypes.c_char_p), ("hostid", ctypes.c_char_p), ("serverSpecific", ctypes.c_void_p),
                ("userPvt", ctypes.c_void_p), ("dbrType", ctypes.c_int), ("no_elements", ctypes.c_int),
                ("data", ctypes.c_void_p)]


_LISTENER = ctypes.CFUNCTYPE(None, ctypes.POINTER(_TrapWriteMessage), ctypes.c_int)
#: Who a put is from when its client is not known (no TRAPWRITE rule, or a put from the IOC's own shell).
UNKNOWN_CLIENT = "EPICS IOC"


class ClientIdentity:
    """The last client that put to each record, kept by an access security trap-write listener.

    Register it before ``iocInit`` (:meth:`register`); :meth:`take` then gives the client of the put
    being handled.
    """

    def __init__(self):
        self._writers: dict[str, str] = {}
        self._lock = threading.Lock()
        self._callback = _LISTENER(self._before_or_after)      # kept: EPICS holds only the pointer

    def register(self) -> None:
        """Become a trap-write listener of this process's EPICS database."""
        register = dbCore.asTrapWriteRegisterListener
        register.argtypes = (_LISTENER,)
        register.restype = ctypes.c_void_p
        self._id = register(self._callback)

    def _before_or_after(self, message, after: int) -> None:
        if after:
            return
        try:
            content = message.contents
            channel = ctypes.cast(content.serverSpecific, ctypes.POINTER(ctypes.c_char_p))[0]   # dbChannel's name
            record = (channel or b"").decode("utf-8", "replace").split(".", 1)[0]
            user = (content.userid or b"?").decode("utf-8", "replace")
            host = (content.hostid or b"?").decode("utf-8", "replace")
        except (ValueError, AttributeError):
            return
        with self._lock:
            self._writers[record] = f"{user}@{host}"

    def take(self, record_name: str) -> str:
        """The client of the latest put to ``record_name`` (``user@host``), forgotten once taken; else
        :data:`UNKNOWN_CLIENT`."""
        with self._lock:
            return self._writers.pop(record_name, UNKNOWN_CLIENT)


__all__ = ["ClientIdentity", "UNKNOWN_CLIENT"]
