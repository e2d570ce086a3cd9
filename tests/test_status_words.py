"""Status in the lab's words: the feedforward's values, one spelling of µ, multi-line replies kept off a terminal."""

import logging
import math
import re

from cryod.service.logs import reply_for_log
from cryod.service.readable import readable
from tests.conftest import REPOSITORY


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


def test_no_text_of_cryod_spells_micro_as_u():
    """Reports, figures, replies and docstrings say µK (the micro sign), as the status does: one spelling of one
    unit, so that a reader or a script looking for µK finds every one. Keys of JSON contracts have no unit
    spelled this way (their units are suffixes: ``_K``)."""
    spelled = [f"{path.relative_to(REPOSITORY)}:{number}: {line.strip()}"
               for path in sorted((REPOSITORY / "cryod").rglob("*.py"))
               for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
               if re.search(r"\buK\b", line)]
    assert spelled == []
