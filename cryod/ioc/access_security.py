"""Who may write: ``ioc.writable`` and the lab's EPICS access security file.

Every record of the IOC is in one of two access security groups: the readings in ``DEFAULT``, the
settings (SETPOINT, RAMP, FEEDFORWARD, HEATER_OFF, NOTE, ALARM_ACK) in ``SETTINGS``. Without
``ioc.writable: true`` the IOC runs on cryod's read-only rules and any file named is not used: every
put is refused by EPICS itself (a CA client gets "no write access"). With it, the lab's file
(``ioc.access_security_file``, e.g. ``contrib/epics/cryod.acf``) says who may write from where;
without a file, cryod's rules let every client that reaches the IOC write. A group the file does
not define falls back to its ``DEFAULT``, as EPICS does.

A file EPICS cannot parse makes ``iocInit`` fail before any server starts; the IOC then checks that
access security is on and ends (exit 2) saying which file.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

from epicscorelibs.ioc import Com, dbCore

#: The access security group of the settings records.
SETTINGS_GROUP = "SETTINGS"
#: cryod's rules without ioc.writable: everyone reads, nobody writes.
READ_ONLY_RULES = """\
# cryod's rules with ioc.writable false: every client reads, no client writes.
ASG(DEFAULT) {
    RULE(1, READ)
}
"""
#: cryod's rules with ioc.writable and no file: every client reads, writes to the settings (trapped, so that the
#: daemon's journal names who wrote).
READ_WRITE_RULES = """\
# cryod's rules with ioc.writable true and no access_security_file: every client reads and writes the settings.
ASG(DEFAULT) {
    RULE(1, READ)
}
ASG(SETTINGS) {
    RULE(1, READ)
    RULE(1, WRITE, TRAPWRITE)
}
"""


class AccessSecurityError(RuntimeError):
    """The rules cannot be used; the message says why."""


def rules_in_force(writable: bool, lab_file: Path | None, folder: Path) -> tuple[Path, str]:
    """The access security file the IOC runs on, and how to say it: the lab's when writes are on and one is
    named, else cryod's own rules written into ``folder``."""
    if writable and lab_file is not None:
        return Path(lab_file), f"the lab's access security file {lab_file}"
    path = Path(folder) / "cryod-ioc.acf"
    path.write_text(READ_WRITE_RULES if writable else READ_ONLY_RULES)
    said = ("writes on for every client (ioc.writable; no ioc.access_security_file)" if writable
            else "read-only (ioc.writable is false" + (f"; {lab_file} not used)" if lab_file else ")"))
    return path, said


def use_rules(path: Path) -> None:
    """Make ``path`` the rules of this IOC (before ``iocInit``, which reads it)."""
    set_filename = dbCore.asSetFilename
    set_filename.argtypes = (ctypes.c_char_p,)
    set_filename.restype = ctypes.c_int
    set_filename(str(path).encode())


def check_active(path: Path) -> None:
    """After ``iocInit``: access security is on (AccessSecurityError otherwise: EPICS could not read ``path``, and
    ``iocInit`` then serves nothing)."""
    if not ctypes.c_int.in_dll(Com, "asActive").value:
        raise AccessSecurityError(f"{path} is not an access security file EPICS can read (the lines above say "
                                  f"where); nothing is served")


__all__ = ["AccessSecurityError", "SETTINGS_GROUP", "rules_in_force", "use_rules", "check_active"]
