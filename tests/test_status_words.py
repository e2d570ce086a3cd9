"""Status in the lab's words: the feedforward's values, one spelling of µ, multi-line replies kept off a terminal."""

import logging
import math

from cryod.service.logs import reply_for_log
from cryod.service.readable import readable


def test_the_feedforward_status_reads_in_words():
    assert readable("ff_phase_rad", 5082.042).startswith(f"{5082.042 % (2 * math.pi):.3f} rad (the cooler's phase "
                                                         f"within its cycle")
    assert readable("ff_locked", 1) == "yes" and readable("ff_locked", 0).startswith("no")
    assert readable("ff_W", -0.101548) == "-101.548 mW (the waveform's part, added to PI's: negative is normal)"
    assert readable("ff_scale", 0.5).startswith("50 %")
    assert readable("ff_line_K", 2.536e-4) == "253.6 µK"


def test_a_multi_line_reply_is_one_line_in_a_terminals_log_and_whole_in_the_journal(monkeypatch):
    reply = "feedforward on\ncooler phase locked\nT2's part: 209.5 µK"
    monkeypatch.delenv("JOURNAL_STREAM", raising=False)
    assert reply_for_log(reply) == "feedforward on (and 2 more lines, in the reply)"
    assert reply_for_log("setpoint 5 K") == "setpoint 5 K"
    monkeypatch.setenv("JOURNAL_STREAM", "8:1")
    assert reply_for_log(reply) == reply
