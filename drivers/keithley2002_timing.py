"""How long a Keithley 2002 takes from a trigger to a reading it can send.

One model, used twice: by the driver, to know when to fetch (and by the
daemon, to check that a configuration fits in the 80 ms cycle), and by the
simulated 2002, to make a reading available no earlier than the real one
would. The parts come from the Model 2002 User's Manual:

* integration: NPLC power-line cycles (section 3.18, ``:NPLCycles``, pp. 3-94, 3-95);
* offset-compensated ohms: a second A/D conversion with the test current
  off for every reading (resistance configuration, "OFFSETCOMP", p. 2-28 ff.);
* autozero (section 3.21, ``:SYSTem:AZERo:TYPE``, p. 3-138): SYNChronous takes a zero
  reading with every reading; NORMal "every 200 msec", which delays the
  reading that falls due by one more integration;
* line synchronisation (the ``:NPLCycles`` note on ``:SYSTem:LSYNc``, p. 3-95): "the integration
  period will not start until the beginning of the next power line cycle",
  i.e. the next positive-going zero crossing;
* repeating filter of N readings (section 3.18, ``:AVERage:TCONtrol``, p. 3-103): N
  conversions per triggered reading; the moving filter takes one;
* trigger delay (``:TRIGger:DELay``).

What the manual does not state as a number is the processing time between
the end of the A/D conversions and the reading being in the output queue;
``processing_time_s`` is that allowance (2 ms by default), an assumption to
replace with a measured value on the lab's instruments.

Examples
--------
>>> timing = ReadingTiming(nplc=1.0, line_frequency_hz=50.0)
>>> round(timing.integration_time_s, 6), round(timing.earliest_delay_s, 6), round(timing.worst_case_delay_s, 6)
(0.02, 0.022, 0.042)
>>> round(ReadingTiming(nplc=1.0, line_frequency_hz=50.0, autozero=False).worst_case_delay_s, 6)
0.022
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

#: Allowance for processing after the last A/D conversion (s); see the module notes.
DEFAULT_PROCESSING_TIME_S = 0.002
#: NORMal autozero refreshes its zero every 200 ms (manual, ``:SYSTem:AZERo:TYPE``).
NORMAL_AUTOZERO_INTERVAL_S = 0.2


@dataclass(frozen=True)
class ReadingTiming:
    """Timing-relevant settings of a 2002 measuring 4-wire resistance.

    The times derived from them are computed once, when first asked (every reading asks several).

    Parameters
    ----------
    nplc : float
        Integration time in power-line cycles.
    line_frequency_hz : float
        Mains frequency of the lab (50 or 60 Hz).
    offset_compensation : bool
        Offset-compensated ohms on.
    autozero : bool
        Autozero on.
    autozero_synchronous : bool
        SYNChronous autozero (a zero with every reading) rather than NORMal.
    line_sync : bool
        Integration starts at the next positive-going zero crossing of the mains.
    conversions_per_reading : int
        A/D conversions per triggered reading (the repeating filter's count, else 1).
    trigger_delay_s : float
        ``:TRIGger:DELay``.
    processing_time_s : float
        Time from the end of the conversions to the reading being available.
    """

    nplc: float
    line_frequency_hz: float
    offset_compensation: bool = False
    autozero: bool = True
    autozero_synchronous: bool = False
    line_sync: bool = False
    conversions_per_reading: int = 1
    trigger_delay_s: float = 0.0
    processing_time_s: float = DEFAULT_PROCESSING_TIME_S

    @cached_property
    def line_period_s(self) -> float:
        return 1.0 / self.line_frequency_hz

    @cached_property
    def integration_time_s(self) -> float:
        """One integration: NPLC / line frequency (s)."""
        return self.nplc / self.line_frequency_hz

    @cached_property
    def conversion_time_s(self) -> float:
        """One A/D conversion with its offset-compensation and synchronous-zero phases (s)."""
        phases = 2 if self.offset_compensation else 1
        if self.autozero and self.autozero_synchronous:
            phases += 1
        return phases * self.integration_time_s

    @cached_property
    def measurement_span_s(self) -> float:
        """From the start of the first conversion to the end of the last (s)."""
        return self.conversions_per_reading * self.conversion_time_s

    @cached_property
    def signal_span_s(self) -> float:
        """From the start of the first signal integration to the end of the last (s).

        Each conversion integrates the signal first, then its zero or
        offset-compensation phase (an assumption: the manual does not give the
        order); the reading stands for the middle of this span.
        """
        return (self.conversions_per_reading - 1) * self.conversion_time_s + self.integration_time_s

    def sample_time_s(self, integration_start_s: float) -> float:
        """The instant a reading whose first integration starts at ``integration_start_s`` stands for (s)."""
        return integration_start_s + 0.5 * self.signal_span_s

    def integration_start_s(self, trigger_time_s: float, needs_zero: bool) -> float:
        """When the first signal integration starts after a trigger at ``trigger_time_s``.

        ``needs_zero``: a NORMal autozero falls due with this reading.
        """
        start = trigger_time_s + self.trigger_delay_s
        if self.autozero and not self.autozero_synchronous and needs_zero:
            start += self.integration_time_s
        if self.line_sync:
            cycles = math.ceil(start * self.line_frequency_hz - 1e-9)
            start = cycles / self.line_frequency_hz
        return start

    def ready_time_s(self, integration_start_s: float) -> float:
        """When the reading whose integration starts at ``integration_start_s`` can be fetched."""
        return integration_start_s + self.measurement_span_s + self.processing_time_s

    @cached_property
    def earliest_delay_s(self) -> float:
        """Shortest time from trigger to an available reading (s): no autozero due, no line-sync wait."""
        return self.trigger_delay_s + self.measurement_span_s + self.processing_time_s

    @cached_property
    def worst_case_delay_s(self) -> float:
        """Longest time from trigger to an available reading (s): what a controller waits."""
        delay = self.trigger_delay_s + self.measurement_span_s + self.processing_time_s
        if self.autozero and not self.autozero_synchronous:
            delay += self.integration_time_s
        if self.line_sync:
            delay += self.line_period_s
        return delay
