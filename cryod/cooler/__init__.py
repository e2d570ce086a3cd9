"""The pulse-tube cooler's line: its phase, its fit in a record, its periodic amplitude.

The cooler makes T5 (its second stage) oscillate by about 0.12 K at 10.8 rad/s
and T2 (the flange) by a few mK. Everything that follows that oscillation uses
this package: the feedforward (its phase-locked loop), the records' metrics and
the live view (the line's amplitude), the analysis and the identification (the
line's frequency, harmonics, phase and drift in a whole record).

* :mod:`cryod.cooler.phase`: the phase and frequency tracked sample by sample from T5, and the
  cooler's frequency over a stretch as the daemon follows it (every tool names that one);
* :mod:`cryod.cooler.line_fit`: amplitude and phase of the line at a known frequency;
* :mod:`cryod.cooler.periodic`: T2's whole part synchronous with the cooler (harmonics
  against the tracked phase);
* :mod:`cryod.cooler.line`: the line in a whole record (frequency, harmonics, phase
  track, drift, the measured cycle the replay follows).
"""
