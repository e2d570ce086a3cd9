"""The flange and PTC-stage thermometers read together: one trigger, two resistances.

:class:`ThermometerPair` owns the two Keithley 2002s and a trigger strategy
(:mod:`drivers.pair_triggers`). It sets both DMMs' trigger model for the
strategy's source, and each :meth:`ThermometerPair.measure`:

1. ``:INITiate`` to both DMMs (they wait for the trigger),
2. fires the trigger and notes its clock time (and skew, if not simultaneous),
3. waits on the injected clock until the readings exist (free on a
   VirtualClock) and fetches both, each checked for staleness, overflow
   and garbage.

It knows thermometers only as resistances: converting to temperature is the
caller's (cryod.thermometry's) job.

Examples
--------
>>> from drivers.clock import VirtualClock
>>> from drivers.keithley2002 import FourWireSettings, Keithley2002
>>> from drivers.pair_triggers import HardwareTrigger
>>> from drivers.trigger_lines import SerialControlLine
>>> from simulated_hw.bench import SimulatedBench
>>> clock = VirtualClock()
>>> bench = SimulatedBench(clock, seed=1)
>>> links = bench.in_process_transports()
>>> flange = Keithley2002(links.flange_dmm, clock, "flange DMM")
>>> stage = Keithley2002(links.ptc_stage_dmm, clock, "PTC-stage DMM")
>>> flange.configure_four_wire_resistance(FourWireSettings(range_ohm=20e3, nplc=1))
>>> stage.configure_four_wire_resistance(FourWireSettings(range_ohm=2e3, nplc=1))
>>> trigger = HardwareTrigger(SerialControlLine(bench.trigger_port, clock), clock)
>>> pair = ThermometerPair(flange, stage, trigger, clock)
>>> reading = pair.measure()
>>> reading.skew_s, 2700 < reading.flange_resistance_ohm < 2800, 650 < reading.ptc_stage_resistance_ohm < 750
(0.0, True, True)
"""

from __future__ import annotations

from typing import NamedTuple

from drivers.clock import Clock
from drivers.keithley2002 import Keithley2002
from drivers.pair_triggers import PairTrigger


class PairReading(NamedTuple):
    """Both thermometer resistances of one trigger.

    A named tuple: immutable, and made many times a second (a frozen dataclass costs four times as much to make).

    Attributes
    ----------
    trigger_time_s : float
        Clock time of the trigger (of the flange DMM's, if not simultaneous).
    skew_s : float
        PTC-stage trigger time minus flange trigger time (0 when simultaneous).
    flange_resistance_ohm : float
        T2, the flange Cernox (ohm).
    ptc_stage_resistance_ohm : float
        T5, the PTC second-stage Cernox (ohm).
    fetched_time_s : float
        Clock time when both readings were in.
    flange_sample_time_s, ptc_stage_sample_time_s : float
        Clock time each reading stands for: the middle of its A/D conversions
        (:attr:`drivers.keithley2002.DmmReading.sample_time_s`). It follows the
        trigger by a delay that an autozero or a line-sync wait can change from
        reading to reading.
    """

    trigger_time_s: float
    skew_s: float
    flange_resistance_ohm: float
    ptc_stage_resistance_ohm: float
    fetched_time_s: float
    flange_sample_time_s: float
    ptc_stage_sample_time_s: float


class ThermometerPair:
    """Two Keithley 2002s triggered together.

    Parameters
    ----------
    flange_dmm, ptc_stage_dmm : Keithley2002
        Configured for 4-wire resistance (:meth:`Keithley2002.configure_four_wire_resistance`).
    trigger : PairTrigger
        How to trigger them.
    clock : Clock
        The injected clock.
    """

    def __init__(self, flange_dmm: Keithley2002, ptc_stage_dmm: Keithley2002, trigger: PairTrigger,
                 clock: Clock):
        self.flange_dmm = flange_dmm
        self.ptc_stage_dmm = ptc_stage_dmm
        self.trigger = trigger
        self.clock = clock
        self._prepared = False

    @property
    def dmms(self) -> tuple[Keithley2002, Keithley2002]:
        return self.flange_dmm, self.ptc_stage_dmm

    def prepare(self) -> None:
        """Set both DMMs' trigger model for the trigger strategy's source."""
        for dmm in self.dmms:
            dmm.configure_trigger(self.trigger.dmm_trigger_source,
                                  link_input_line=self.trigger.link_input_line,
                                  link_output_line=1 if self.trigger.link_input_line != 1 else 2)
        self._prepared = True

    @property
    def reading_delay_s(self) -> float:
        """Longest time from trigger to both readings (s); the cycle needs more than this."""
        return max(dmm.reading_delay_s for dmm in self.dmms)

    def measure(self) -> PairReading:
        """Trigger both DMMs once and fetch both resistances."""
        if not self._prepared:
            self.prepare()
        for dmm in self.dmms:
            dmm.initiate(confirm=self.trigger.bypasses_command_stream)
        event = self.trigger.fire()
        flange = self.flange_dmm.fetch_new_reading(event.time_s)
        stage = self.ptc_stage_dmm.fetch_new_reading(event.time_s + event.skew_s)
        # fetch_new_reading knows the trigger, so it always dates the reading
        assert flange.sample_time_s is not None and stage.sample_time_s is not None
        return PairReading(event.time_s, event.skew_s, flange.resistance_ohm, stage.resistance_ohm,
                           self.clock.now(), flange.sample_time_s, stage.sample_time_s)

    def close(self) -> None:
        """Shut both DMMs down (best effort)."""
        for dmm in self.dmms:
            dmm.shutdown()
