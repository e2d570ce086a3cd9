"""The simulated lab in one object: cryostat, two Keithley 2002s, a heater supply, trigger wiring.

:class:`SimulatedBench` builds what ``cryod --simulate`` runs against: the
simulated cryostat of the shipped model, a Keithley 2002 on the flange Cernox
(T2) and one on the PTC-stage Cernox (T5) through their calibration curves
(``config/calibration/X186279.340`` and ``X207058.340`` by default), a
Keithley 6221 or 2400 on the flange heater, a trigger wire teed to both DMMs'
EXTERNAL TRIGGER inputs and a simulated GPIB board. The instruments are
reached either in process (:meth:`SimulatedBench.in_process_transports`) or
over TCP on 127.0.0.1 through pyvisa-py (:meth:`SimulatedBench.serve_tcp`,
:meth:`SimulatedBench.serve_prologix`).

In-process transports run on any clock, a VirtualClock included. Over TCP
the instruments answer from server threads, so the clock's waits must take
real time (:class:`drivers.clock.MonotonicClock`, ``ScaledClock``, or the
:class:`drivers.paced_clock.PacedClock` of a dry run faster than real
time): on a VirtualClock a trigger could be processed after the driver has
already moved the clock on.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import cryod
from cryod.model import CryostatModel, load_model
from drivers.clock import Clock
from drivers.transports.in_process import InProcessTransport
from simulated_hw.cryostat import SimulatedCryostat
from simulated_hw.keithley2002 import Keithley2002Emulator, ResistanceCurve
from simulated_hw.keithley2400 import Keithley2400Emulator
from simulated_hw.keithley6221 import Keithley6221Emulator
from simulated_hw.prologix_server import PrologixServer
from simulated_hw.scpi_server import ScpiServer
from simulated_hw.trigger_wiring import SimulatedGpibInterface, SimulatedSerialPort, SimulatedTriggerLine

#: The shipped calibrations (``config/calibration``, installed as ``cryod/data/calibration``).
CALIBRATION_DIRECTORY = Path(cryod.__file__).resolve().parent / "data" / "calibration"
FLANGE_CALIBRATION = CALIBRATION_DIRECTORY / "X186279.340"
PTC_STAGE_CALIBRATION = CALIBRATION_DIRECTORY / "X207058.340"
SUPPLIES = {"6221": Keithley6221Emulator, "2400": Keithley2400Emulator}
#: GPIB addresses on the simulated Prologix bus.
PROLOGIX_ADDRESSES = {"flange": 16, "ptc_stage": 17, "heater": 24}


@dataclass(frozen=True)
class BenchTransports:
    """Transports to the three instruments (any :class:`drivers.transports.base.Transport`)."""

    flange_dmm: Any
    ptc_stage_dmm: Any
    heater_supply: Any


class SimulatedBench:
    """The simulated cryostat and its instruments.

    Parameters
    ----------
    clock : Clock
        Clock of the whole bench.
    flange_calibration, ptc_stage_calibration : object with ``resistance_ohm(T)``, optional
        Sensor curves; the shipped ``.340`` files by default.
    model : CryostatModel, optional
        Cryostat physics (the shipped model by default).
    heater_resistance_ohm : float
        Flange heater resistance (ohm).
    supply : {'6221', '2400'}
        Which heater supply is simulated.
    seed : int, optional
        Sensor-noise seed.
    noise : bool
        Add sensor noise.
    line_frequency_hz : float
        Mains frequency the DMMs integrate over.
    initial_heater_power_w : float
        Heater power the cryostat has settled at before the start (W).
    """

    def __init__(self, clock: Clock, flange_calibration: ResistanceCurve | None = None,
                 ptc_stage_calibration: ResistanceCurve | None = None, *, model: CryostatModel | None = None,
                 heater_resistance_ohm: float = 50.0, supply: str = "6221", seed: int | None = None,
                 noise: bool = True, line_frequency_hz: float = 50.0, initial_heater_power_w: float = 0.0):
        if supply not in SUPPLIES:
            raise ValueError(f"supply must be one of {sorted(SUPPLIES)}, got {supply!r}")
        if flange_calibration is None or ptc_stage_calibration is None:
            from cryod.thermometry import load_calibration
            flange_calibration = flange_calibration or load_calibration(FLANGE_CALIBRATION)
            ptc_stage_calibration = ptc_stage_calibration or load_calibration(PTC_STAGE_CALIBRATION)
        self.clock = clock
        self.cryostat = SimulatedCryostat(model or load_model(), clock, seed=seed, noise=noise,
                                          initial_heater_power_w=initial_heater_power_w)
        self.flange_dmm = Keithley2002Emulator(self.cryostat, "flange", flange_calibration,
                                               line_frequency_hz=line_frequency_hz, serial_number="0000002")
        self.ptc_stage_dmm = Keithley2002Emulator(self.cryostat, "ptc_stage", ptc_stage_calibration,
                                                  line_frequency_hz=line_frequency_hz, serial_number="0000005")
        self.heater_supply = SUPPLIES[supply](self.cryostat, heater_resistance_ohm)
        self.trigger_line = SimulatedTriggerLine([self.flange_dmm, self.ptc_stage_dmm], kind="external")
        self.trigger_port = SimulatedSerialPort(self.trigger_line, wired="rts")
        self.gpib_interface = SimulatedGpibInterface()
        self._servers: list = []             # the TCP servers running now (serve_tcp, serve_prologix)

    @property
    def instruments(self) -> tuple:
        return self.flange_dmm, self.ptc_stage_dmm, self.heater_supply

    def in_process_transports(self, *, timeout_s: float = 1.0) -> BenchTransports:
        """Transports calling the simulated instruments directly (any clock)."""
        return BenchTransports(InProcessTransport(self.flange_dmm, "simulated flange DMM", timeout_s=timeout_s),
                               InProcessTransport(self.ptc_stage_dmm, "simulated PTC-stage DMM",
                                                  timeout_s=timeout_s),
                               InProcessTransport(self.heater_supply, "simulated heater supply",
                                                  timeout_s=timeout_s))

    def drop_every_connection(self) -> None:
        """Fault: every connection to the bench drops at once, as when a Prologix or LAN adapter that all
        three instruments share resets (new connections are taken)."""
        for instrument in self.instruments:
            instrument.drop_connections()
        for server in list(self._servers):
            server.drop_connections()

    @contextlib.contextmanager
    def serve_tcp(self) -> Iterator[dict[str, str]]:
        """Each instrument on its own 127.0.0.1 port; yields their VISA resource names."""
        servers = [ScpiServer(instrument).start() for instrument in self.instruments]
        self._servers += servers
        try:
            yield dict(zip(("flange_dmm", "ptc_stage_dmm", "heater_supply"),
                           (server.resource_name for server in servers)))
        finally:
            for server in servers:
                self._servers.remove(server)
                server.stop()

    @contextlib.contextmanager
    def serve_prologix(self) -> Iterator[PrologixServer]:
        """All three instruments behind one simulated Prologix GPIB-ETHERNET controller."""
        server = PrologixServer({PROLOGIX_ADDRESSES["flange"]: self.flange_dmm,
                                 PROLOGIX_ADDRESSES["ptc_stage"]: self.ptc_stage_dmm,
                                 PROLOGIX_ADDRESSES["heater"]: self.heater_supply}).start()
        self._servers.append(server)
        try:
            yield server
        finally:
            self._servers.remove(server)
            server.stop()
