"""``cryod init DIR``: a new lab's configuration in a folder of its own, ready for ``cryod run --check``.

The example configuration names its calibration files relative to its own folder, so it cannot be
copied alone. ``cryod init`` writes, into a folder that holds none of them yet:

* ``cryod.yaml``: the example configuration (every key with its comment), with the instruments on
  the connection the lab names (a GPIB card, a Prologix GPIB-USB or GPIB-ETHERNET adapter, with the
  trigger that connection gives both DMMs at once) and the web page on 127.0.0.1 (read-only, its
  token ready);
* ``calibration/``: the example's two calibration files, to be replaced by the lab's own sensors';
* ``web.token``: a random token, owner and group only (mode 0640), for a writable web page;
* ``cryod.service``: the systemd unit, running this installation's ``cryod`` on this configuration.

Examples
--------
>>> print(instrument_lines("prologix-lan", "192.168.1.40", 16))
prologix: {host: 192.168.1.40, address: 16}
"""

from __future__ import annotations

import argparse
import os
import secrets
import shutil
import sys
from importlib import resources
from pathlib import Path

#: The example's instruments and their GPIB addresses (the ``resource`` lines it holds).
EXAMPLE_RESOURCES = {"flange_dmm": 16, "ptc_stage_dmm": 17, "heater_supply": 12}
#: The files written, relative to the folder.
WRITTEN = ("cryod.yaml", "calibration", "web.token", "cryod.service")


def instrument_lines(connection: str, where: str, gpib_address: int) -> str:
    """The configuration's line for one instrument reached through ``connection`` (``gpib``, ``prologix-usb``,
    ``prologix-lan``) at ``where`` (the card's number, the serial port, the adapter's host)."""
    if connection == "gpib":
        return f"resource: GPIB{where}::{gpib_address}::INSTR"
    if connection == "prologix-usb":
        return f"prologix: {{port: {where}, address: {gpib_address}}}"
    return f"prologix: {{host: {where}, address: {gpib_address}}}"


def configuration_text(example: str, connection: str, where: str) -> str:
    """The example configuration with the lab's instruments and the web page on (read-only, token ready)."""
    text = example
    for key, address in EXAMPLE_RESOURCES.items():
        old = f"resource: GPIB0::{address}::INSTR"
        if old not in text:
            raise ValueError(f"the example configuration has no {old!r} for {key}")
        text = text.replace(old, instrument_lines(connection, where, address), 1)
    if connection != "gpib":                    # both DMMs triggered at once through the adapter
        trigger = "trigger: gpib-group             # gpib-group | prologix | external | sequential"
        if trigger not in text:
            raise ValueError("the example configuration has no 'trigger: gpib-group' line")
        text = text.replace(trigger, "trigger: prologix               # gpib-group | prologix | external | sequential",
                            1)
    web_off = "web: null                         # the live page"
    if web_off not in text:
        raise ValueError("the example configuration has no 'web: null' line")
    text = text.replace(web_off, 'web: {address: "127.0.0.1:8336", writable: false, token_file: web.token}'
                                 "\n                                  # the live page", 1)
    return text


def unit_text(template: str, cryod_program: Path, config: Path) -> str:
    """The shipped unit, running ``cryod_program`` on ``config``."""
    return (template.replace("/opt/cryod/venv/bin/cryod", str(cryod_program))
            .replace("/etc/cryod/cryod.yaml", str(config)))


def where_and_card(folder: Path | None, card: str | None) -> tuple[Path | None, str | None]:
    """The folder and the GPIB card as meant: ``cryod init --gpib lab`` names the folder ``lab`` on card 0.

    ``--gpib`` takes an optional card number, so a folder written right after it is read as the card;
    with no folder given otherwise, a card that is not a number is the folder.

    Examples
    --------
    >>> where_and_card(None, "lab")
    (PosixPath('lab'), '0')
    >>> where_and_card(Path("lab"), "1")
    (PosixPath('lab'), '1')
    """
    if folder is None and card is not None and not card.isdigit():
        return Path(card), "0"
    return folder, card


def add_parser(commands) -> argparse.ArgumentParser:
    parser = commands.add_parser("init", help="write a new lab's configuration, calibration files, web token and "
                                              "systemd unit into a folder")
    parser.add_argument("folder", type=Path, metavar="DIR", nargs="?",
                        help="where to write them (made if missing)")
    how = parser.add_mutually_exclusive_group(required=True)
    how.add_argument("--gpib", metavar="CARD", nargs="?", const="0", default=None,
                     help="the instruments on a GPIB card (its number, default 0; needs linux-gpib or NI-VISA)")
    how.add_argument("--prologix-usb", metavar="PORT", help="the instruments on a Prologix GPIB-USB adapter "
                                                           "at this serial port (e.g. /dev/ttyUSB0)")
    how.add_argument("--prologix-lan", metavar="HOST", help="the instruments on a Prologix GPIB-ETHERNET adapter "
                                                           "at this host name or IP address")
    return parser


def run(args) -> int:
    """Write the files; 0 done, 2 when one of them is there already or the arguments do not say where (nothing
    is written then)."""
    folder, card = where_and_card(args.folder, args.gpib)
    if isinstance(card, str) and not card.isdigit():
        print(f"cryod init: --gpib takes a GPIB card's number, not {card!r}; e.g. cryod init DIR --gpib", file=sys.stderr)
        return 2
    if folder is None:
        print("cryod init: say where to write the files: cryod init DIR --gpib|--prologix-usb PORT|--prologix-lan "
              "HOST", file=sys.stderr)
        return 2
    existing = [name for name in WRITTEN if (folder / name).exists()]
    if existing:
        print(f"cryod init: {folder} holds {', '.join(existing)} already; nothing was written (choose an empty "
              f"folder, or move them away)", file=sys.stderr)
        return 2
    connection, where = (("gpib", card) if card is not None else
                         ("prologix-usb", args.prologix_usb) if args.prologix_usb else
                         ("prologix-lan", args.prologix_lan))
    data = resources.files("cryod").joinpath("data")
    config = folder / "cryod.yaml"
    try:
        text = configuration_text(data.joinpath("cryod.yaml").read_text(encoding="utf-8"), connection, where)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "calibration").mkdir()
        for name in ("X186279.340", "X207058.340"):
            (folder / "calibration" / name).write_bytes(data.joinpath("calibration", name).read_bytes())
        config.write_text(text, encoding="utf-8")
        token = folder / "web.token"
        descriptor = os.open(token, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o640)
        with os.fdopen(descriptor, "w") as stream:
            stream.write(secrets.token_hex(32) + "\n")
        os.chmod(token, 0o640)
        program = Path(shutil.which("cryod") or Path(sys.executable).parent / "cryod").absolute()
        template = data.joinpath("systemd", "cryod.service").read_text(encoding="utf-8")
        (folder / "cryod.service").write_text(unit_text(template, program, config.absolute()), encoding="utf-8")
    except (OSError, ValueError) as error:
        print(f"cryod init: could not write into {folder}: {error}", file=sys.stderr)
        return 2
    print(f"{config}: the configuration, with the instruments on {connection} {where}; set their GPIB addresses, "
          f"the heater and the limits, and put your sensors' calibration files into {folder / 'calibration'}\n"
          f"{folder / 'web.token'}: the web page's token (owner and group only)\n"
          f"{folder / 'cryod.service'}: the systemd unit (sudo cp it to /etc/systemd/system/, docs/how-to/install.md)\n"
          f"check it:  cryod run --check --config {config}\n"
          f"try it:    cryod --simulate --config {config} --duration 600 --speed max")
    return 0


__all__ = ["add_parser", "run", "configuration_text", "instrument_lines", "unit_text", "where_and_card"]
