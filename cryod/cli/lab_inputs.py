"""What the model tools take from the lab's configuration unless the command line says otherwise.

``cryod feedforward-limit`` and ``cryod tune`` both start from a model, a setpoint and a heater:
the command line's ``--model``, ``--setpoint``, ``--heater-ohm`` and ``--max-current`` where given,
the configuration's (``--config``, the example by default) otherwise.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

from cryod.argument_types import positive
from cryod.config import DaemonConfig, load_config
from cryod.model import CryostatModel, load_model
from cryod.yaml_source import FileFormatError


class InputsNotUsable(ValueError):
    """A file that cannot be read, or no setpoint anywhere; the message says which."""


@dataclass(frozen=True)
class LabInputs:
    """The configuration, the model, and the setpoint (K) and heater (Ω, A) a tool works at."""

    config: DaemonConfig
    model: CryostatModel
    setpoint_K: float
    heater_ohm: float
    max_current_A: float

    @property
    def heater_max_w(self) -> float:
        """R·I_max², the most the heater can give (W)."""
        return self.heater_ohm * self.max_current_A ** 2


def add_heater_arguments(parser: argparse.ArgumentParser) -> None:
    """``--heater-ohm`` and ``--max-current``, which :func:`lab_inputs` takes over the configuration's heater."""
    parser.add_argument("--heater-ohm", type=positive, default=None, metavar="R",
                        help="heater resistance in ohm (default: the configuration's)")
    parser.add_argument("--max-current", type=positive, default=None, metavar="A",
                        help="heater current limit in A (default: the configuration's)")


def lab_inputs(args: argparse.Namespace) -> LabInputs:
    """The inputs from ``args`` (``config``, ``model``, ``setpoint``, ``heater_ohm``, ``max_current``).

    Raises
    ------
    InputsNotUsable
        The configuration or the model cannot be read, or neither the command line nor the
        configuration gives a setpoint.
    """
    try:
        config = load_config(args.config)
        model = load_model(args.model)
    except (FileFormatError, OSError) as error:
        raise InputsNotUsable(str(error)) from None
    setpoint = args.setpoint if args.setpoint is not None else config.control.setpoint_K
    if setpoint is None:
        raise InputsNotUsable(f"{args.config} sets no setpoint: give --setpoint K")
    return LabInputs(config, model, setpoint,
                     args.heater_ohm if args.heater_ohm is not None else config.heater.resistance_ohm,
                     args.max_current if args.max_current is not None else config.heater.max_current_A)
