"""The feedforward's record columns: every row has them (``ff_*``), in this order.

What each says is in its declaration; docs/how-to/feedforward.md ("Using it") says it for a reader of the
record. :meth:`cryod.control.feedforward.FeedforwardTerm.column_values` fills them.
"""

from __future__ import annotations

from cryod.records.columns import Column

#: The columns, in the order of the term's values.
COLUMNS = (
    Column("ff_W", "W", "feedforward heater part (locked to the cooler)", "{:.6e}"),
    Column("ff_phase_rad", "rad", "cooler phase at the T2 reading (T5's fundamental is A cos(phase))",
           "{:.4f}"),
    Column("ff_frequency_rad_s", "rad/s", "cooler angular frequency tracked from T5", "{:.5f}"),
    Column("ff_locked", "", "1 when the phase tracker is locked to the cooler", "{:.0f}"),
    Column("ff_line_K", "K", "amplitude of T2's part synchronous with the cooler as estimated at the last "
                             "learning step (sqrt of the sum of the harmonics' squared amplitudes)", "{:.4e}"),
    Column("ff_scale", "", "fade of the waveform, 0 (off) to 1 (on)", "{:.3f}"),
    Column("ff_limit_K", "K", "the physical limit at this setpoint: the least synchronous T2 any heater "
                              "waveform can leave (feedforward-limit; empty until computed)", "{:.3e}"),
    Column("ff_authority", "", "largest fundamental the heater can give over the one the line needs "
                               "(below 1: authority-limited)", "{:.3f}"),
    Column("ff_limit_from", "", "what ff_limit_K and ff_authority were computed from: model (the controller's "
                                "model) or learned (the plant and line learned, the mean power PI found)"),
    Column("ff_probe_K", "K", "T2's answer to the probe (harmonics together), empty when it is off; the "
                              "learned plant itself is in the record's feedforward events", "{:.2e}"),
)

__all__ = ["COLUMNS"]
