"""What ``cryod run`` needs of this computer beyond a valid file, checked before anything starts.

:func:`cryod.config.load_config` checks the file itself. What it names must also be there
and usable by the user the daemon runs as: the VISA library and the packages it needs for
each instrument's interface, the serial devices, the socket's owner and group, the folders
of the control socket and of the data. ``cryod run --check`` and ``cryod run`` make the
same checks, so a configuration the check passes does not fail when the service starts;
each problem is a :class:`~cryod.yaml_source.FileFormatError` naming the file, the line
and the key, exit 2, which systemd does not restart (``RestartPreventExitStatus``).

Nothing here touches an instrument or keeps anything: a folder is tried with a file that
has no name (or a folder removed at once) and left as it was.
"""

from __future__ import annotations

import grp
import ipaddress
import os
import pwd
import socket
import stat
import sys
import tempfile
from pathlib import Path

from cryod.config import INSTRUMENT_KEYS, DaemonConfig, located_error
from cryod.regular_files import kind_of
from cryod.yaml_source import FileFormatError, shown
from drivers.transports.addresses import network_host, serial_device
from drivers.transports.visa import missing_support, resource_manager

#: Where systemd creates a system service's ``RuntimeDirectory=`` and ``StateDirectory=`` when it
#: starts it (systemd.exec): a folder missing there is made for the service, not by it.
SYSTEMD_DIRECTORY_ROOTS = (Path("/run"), Path("/var/lib"))


def check_before_run(config: DaemonConfig, *, before_systemd_start: bool = False) -> list[str]:
    """Check what ``config`` needs of this computer; the notes a check could not settle.

    Parameters
    ----------
    config : DaemonConfig
    before_systemd_start : bool
        ``cryod run --check``: a folder that does not exist yet in /run or /var/lib, which the
        unit's ``RuntimeDirectory=``/``StateDirectory=`` make at start, is a note, not a problem.

    Returns
    -------
    list of str
        Notes for the user (a folder systemd will make).

    Raises
    ------
    cryod.yaml_source.FileFormatError
        The first problem, at its key.
    """
    _check_visa_library(config)
    _check_interfaces(config)
    _check_serial_devices(config)
    _check_socket_owner_and_group(config)
    notes = _check_host_names(config)
    for key, directory in (("control_socket.path", config.control_socket.path.parent),
                           ("data.directory", config.data.directory),
                           ("instruments.lock_directory", config.instruments.lock_directory)):
        note = _check_directory(config, key, directory, before_systemd_start)
        if note:
            notes.append(note)
    _check_socket_path_is_free(config)
    return notes


def _instruments(config: DaemonConfig):
    """(key, address) of each instrument."""
    for key in INSTRUMENT_KEYS:
        yield key, getattr(config.instruments, key)


def _check_visa_library(config: DaemonConfig) -> None:
    library = config.instruments.visa_library
    try:
        resource_manager(library)
    except Exception as error:  # noqa: BLE001 - pyvisa raises OSError, ValueError or its own for a library it cannot load
        raise located_error(config, "instruments.visa_library",
                            f"{shown(library)} cannot be loaded as a VISA library ({type(error).__name__}: "
                            f"{str(error).strip()[:200]}): give \"@py\" (pyvisa-py, installed with cryod) or \"\" "
                            f"(NI-VISA or another installed VISA)") from None


def _check_interfaces(config: DaemonConfig) -> None:
    """Each resource's interface reachable by the VISA library (a GPIB card needs its Python binding)."""
    library = config.instruments.visa_library
    for key, address in _instruments(config):
        if address.resource is None:
            continue
        missing = missing_support(address.resource, library)
        if not missing:
            continue
        if address.resource.upper().startswith("GPIB"):
            reason = (f"{address.resource} is on a GPIB card, which pyvisa-py cannot reach from the installation in "
                      f"{sys.prefix} ({missing.rstrip('.')}): install linux-gpib with its Python binding into this "
                      f"environment (docs/how-to/install.md, 'GPIB card'), or use NI-VISA (instruments.visa_library: "
                      f"\"\") or a Prologix adapter")
        elif missing.startswith("pyvisa-py has no support"):
            reason = (f"{address.resource}: {missing}: give a resource of another kind, or a VISA library that has "
                      f"them (instruments.visa_library)")
        else:
            reason = (f"{address.resource} is out of pyvisa-py's reach from the installation in {sys.prefix} "
                      f"({missing.rstrip('.')}): install what it names into this environment")
        raise located_error(config, f"instruments.{key}.resource", reason)


def _check_serial_devices(config: DaemonConfig) -> None:
    """Serial devices named (a Prologix GPIB-USB controller, an ASRL resource, the trigger wire) exist and
    this user may read and write them."""
    devices = []
    for key, address in _instruments(config):
        if address.prologix_port is not None:
            devices.append((f"instruments.{key}.prologix.port", address.prologix_port))
        elif address.resource is not None and serial_device(address.resource):
            devices.append((f"instruments.{key}.resource", serial_device(address.resource)))
    output = config.instruments.trigger_output
    if config.instruments.trigger == "external" and output is not None:
        devices.append(("instruments.trigger_output.port", output.port))
    for key, device in devices:
        problem = _serial_device_problem(device)
        if problem:
            raise located_error(config, key, problem)


def _check_host_names(config: DaemonConfig) -> list[str]:
    """Each instrument's host name known to the name service; the notes a lookup could not settle.

    A name the name service says does not exist (a misspelt host) is refused at its key: left to
    the start, it would be waited on as an instrument outage for ``safety.instruments_wait_s``,
    without end by default. A name service that cannot answer now (no network yet at boot) settles
    nothing: that is a note, and the start waits for the instruments as for any outage.
    """
    notes = []
    for key, address in _instruments(config):
        if address.prologix_host is not None:
            host_key, host = f"instruments.{key}.prologix.host", address.prologix_host
        else:
            host_key, host = f"instruments.{key}.resource", network_host(address.resource or "")
        if host is None or _is_ip_address(host):
            continue
        try:
            socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
        except socket.gaierror as error:
            if error.errno in (socket.EAI_NONAME, getattr(socket, "EAI_NODATA", socket.EAI_NONAME)):
                raise located_error(config, host_key,
                                    f"host {shown(host)} is not known to the name service ({error.strerror}): "
                                    f"check its spelling, or give the instrument's IP address") from None
            notes.append(f"{host_key}: host {host} could not be looked up now ({error.strerror}); the daemon "
                         f"waits for the instrument at start as for an outage")
    return notes


def _is_ip_address(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


def _serial_device_problem(device: str) -> str | None:
    try:
        status = os.stat(device)
    except FileNotFoundError:
        return (f"{device}: no such device: is the adapter plugged in? (ls /dev/serial/by-id: a name there stays "
                f"the same across plugging and reboots)")
    except OSError as error:
        return f"{device}: {error.strerror or error}"
    if not stat.S_ISCHR(status.st_mode):
        return f"{device} is {kind_of(status.st_mode)}, not a serial device"
    device_class = kernel_device_class(status.st_rdev)
    if device_class is not None and device_class != "tty":
        return (f"{device} is a character device of the kernel's {device_class!r} class, not a serial device (the "
                f"'tty' class): give the adapter's serial port (ls /dev/serial/by-id)")
    if not os.access(device, os.R_OK | os.W_OK):
        return (f"{device}: user {_user()} may not read and write it: add {_user()} to the device's group "
                f"(dialout for serial adapters; SupplementaryGroups= in the unit)")
    return None


def kernel_device_class(device_number: int) -> str | None:
    """The kernel's class of a character device (``tty`` for serial ports and terminals, ``mem`` for
    /dev/null), from /sys/dev/char without opening the device (opening a serial port moves its DTR and RTS
    lines); None where sysfs does not list it (pseudo-terminals, a system without sysfs).

    Parameters
    ----------
    device_number : int
        ``st_rdev`` of the device file.
    """
    link = Path("/sys/dev/char") / f"{os.major(device_number)}:{os.minor(device_number)}" / "subsystem"
    try:
        return Path(os.readlink(link)).name
    except OSError:
        return None


def _user() -> str:
    try:
        return pwd.getpwuid(os.geteuid()).pw_name
    except KeyError:
        return f"uid {os.geteuid()}"


def _check_socket_owner_and_group(config: DaemonConfig) -> None:
    """The socket's owner and group exist, and this user may give the socket to them (only root gives
    a file to another user, and a user gives it only to a group of their own)."""
    socket_config = config.control_socket
    privileged = os.geteuid() == 0
    if socket_config.owner is not None:
        uid = _known_id(config, "control_socket.owner", socket_config.owner, "user")
        if not privileged and uid != os.geteuid():
            raise located_error(config, "control_socket.owner",
                                f"the daemon runs as {_user()} and cannot give the socket to {socket_config.owner}: "
                                f"only root can; leave owner out (the socket is then {_user()}'s)")
    if socket_config.group is not None:
        gid = _known_id(config, "control_socket.group", socket_config.group, "group")
        if not privileged and gid != os.getegid() and gid not in os.getgroups():
            raise located_error(config, "control_socket.group",
                                f"the daemon runs as {_user()}, who is not in the group {socket_config.group}: add "
                                f"{_user()} to it (SupplementaryGroups= in the unit), or give one of its groups")


def _known_id(config: DaemonConfig, key: str, name: str, kind: str) -> int:
    """The id of the user or group ``name`` on this computer, or the error at ``key``."""
    try:
        return pwd.getpwnam(name).pw_uid if kind == "user" else grp.getgrnam(name).gr_gid
    except KeyError:
        raise located_error(config, key, f"no {kind} {shown(name)} on this computer") from None


def _nearest_existing(directory: Path) -> Path:
    place = directory
    while not os.path.lexists(place) and place != place.parent:
        place = place.parent
    return place


def directory_problem(config: DaemonConfig, key: str, directory: Path) -> str | None:
    """None when ``directory`` (named at ``key``) takes files or can be made by this user, else why not, at its
    file, line and key."""
    try:
        _check_directory(config, key, directory, before_systemd_start=False)
    except FileFormatError as error:
        return str(error)
    return None


def _check_directory(config: DaemonConfig, key: str, directory: Path, before_systemd_start: bool) -> str | None:
    """``directory`` takes files, or can be made; a note when systemd makes it for the service."""
    place = _nearest_existing(directory)
    if not place.is_dir():
        what = kind_of(os.stat(place).st_mode) if place.exists() else "a link to nothing"
        raise located_error(config, key, f"{directory} cannot be made: {place} is {what}, not a directory")
    try:
        if place == directory:
            with tempfile.TemporaryFile(dir=directory):
                pass
        else:
            os.rmdir(tempfile.mkdtemp(prefix=".cryod-check-", dir=place))
    except OSError as error:
        reason = error.strerror or str(error)
        if place != directory and before_systemd_start and place in SYSTEMD_DIRECTORY_ROOTS:
            return (f"{directory} ({key}) does not exist yet and user {_user()} cannot make it in {place} "
                    f"({reason}): systemd makes it when it starts the service (the unit's RuntimeDirectory= "
                    f"and StateDirectory=); `cryod run` by hand needs it made first")
        what = f"cannot be written by user {_user()}" if place == directory else \
            f"does not exist and user {_user()} cannot make it in {place}"
        raise located_error(config, key, f"{directory} {what} ({reason})") from None
    return None


def _check_socket_path_is_free(config: DaemonConfig) -> None:
    """Only a socket left behind is replaced at the socket's path, never another kind of file."""
    path = config.control_socket.path
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(mode):
        raise located_error(config, "control_socket.path",
                            f"{path} exists and is {kind_of(mode)}: cryod binds its socket "
                            f"there and replaces only a socket left behind; remove it or give another path")


__all__ = ["check_before_run", "directory_problem", "FileFormatError"]
