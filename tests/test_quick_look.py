"""``cryod plot RECORD``: the quick look at a record, on a record the daemon wrote and on a known signal."""

import io

import matplotlib.image
import numpy as np
import pytest

import cryod
from cryod.cli import main, running_record
from cryod.cli.plot import cooler_frequency, periodic_line_amplitudes
from cryod.records.record import write_record


def known_record(path, line_K=1e-3, rad_s=10.9):
    t = np.arange(0.0, 900.0, 0.08)
    rng = np.random.default_rng(1)
    columns = {"time_s": t, "T2_K": 5.0 + line_K * np.sin(rad_s * t + 0.4) + 2e-5 * rng.standard_normal(t.size),
               "T5_K": 3.6 + 0.12 * np.sin(rad_s * t + 1.5), "heater_W": np.full(t.size, 0.2),
               "setpoint_K": np.full(t.size, 5.0)}
    return write_record(path, columns, {"site": "test"})


def test_the_line_is_found_on_T5_and_measured_on_T2_block_by_block(tmp_path):
    record = cryod.read_record(known_record(tmp_path / "known.csv"))
    rad_s = cooler_frequency(record.time_s, record.ptc_stage_K, 10.83)
    assert rad_s == pytest.approx(10.9, abs=1e-4)
    centres, amplitudes, noises = periodic_line_amplitudes(record.time_s, record.flange_K, rad_s)
    assert centres.size == 30 and np.allclose(amplitudes, 1e-3, rtol=0.01)
    assert np.allclose(noises, 2 * 2e-5 * np.sqrt(6 / 375), rtol=0.15)      # 20 µK readings, 375 a block


def test_cryod_plot_draws_a_daemon_record_beside_it_and_keeps_an_existing_figure(tmp_path, capsys, monkeypatch):
    """A record named on the command line: its figure is kept unless --force. Without a path, the record the
    daemon is writing grows between looks: its own quick look is drawn again in place, anything else there is
    still kept unless --force."""
    run = cryod.simulate(300.0, data_dir=tmp_path / "data", socket=tmp_path / "c.sock", log_stream=io.StringIO())
    record_path = run.log_paths[0]
    record = cryod.read_record(record_path)                  # one cooler frequency: the daemon's, the plot's, --json's
    locked = record.columns["ff_locked"] == 1
    daemon_rad_s = float(np.median(record.columns["ff_frequency_rad_s"][locked][-2500:]))
    assert cooler_frequency(record.time_s, record.ptc_stage_K, 10.83) == pytest.approx(daemon_rad_s, abs=2e-3)
    assert run.summary["ptc_line_rad_s"] == pytest.approx(daemon_rad_s, abs=2e-3)
    assert run.summary["feedforward_limit_bound"] == "floor"            # 113 mW of 500 mW at 5 K
    assert "a bigger heater does not help" in run.summary["feedforward_limit_explained"].lower()
    # the heater panel's line is the heater's level, not the middle of the waveform's band: over the settled last
    # two minutes its mean over cooler cycles is the record's mean power, the band's middle is far from it
    from cryod.cli.plot import cycle_mean
    late = record.time_s > record.time_s[-1] - 120.0
    level = cycle_mean(record.time_s, record.heater_w, daemon_rad_s)[late]
    mean_w = float(np.mean(record.heater_w[late]))
    assert float(np.nanmean(level)) == pytest.approx(mean_w, rel=0.01)
    assert float(np.nanmax(np.abs(level - mean_w))) < 0.1 * mean_w
    middle = (np.min(record.heater_w[late]) + np.max(record.heater_w[late])) / 2
    assert abs(middle - mean_w) > 0.2 * mean_w
    assert main(["plot", str(record_path)]) == 0
    figure = record_path.with_suffix(".png")
    assert capsys.readouterr().out.strip() == str(figure)
    image = matplotlib.image.imread(figure)
    assert image.shape[0] > 1000 and image.shape[1] > 1000          # six panels
    before = figure.stat().st_mtime_ns
    assert main(["plot", str(record_path)]) == 2
    assert "exists; give --force" in capsys.readouterr().err and figure.stat().st_mtime_ns == before
    assert main(["plot", str(record_path), "--force"]) == 0
    capsys.readouterr()
    monkeypatch.setattr(running_record, "running_record_path", lambda socket: record_path)
    drawn = figure.stat().st_mtime_ns
    assert main(["plot"]) == 0 and capsys.readouterr().out.strip() == str(figure)
    assert figure.stat().st_mtime_ns > drawn
    figure.write_bytes(b"a figure of my own")
    assert main(["plot"]) == 2
    assert "exists; give --force" in capsys.readouterr().err and figure.read_bytes() == b"a figure of my own"


@pytest.mark.parametrize("text, message", [
    ("# cryod-log v1\ntime_s,T2_K,heater_W,setpoint_K\n0.0,4.23,0.0,\n", "T5_K"),
    ("# cryod-log v1\ntime_s,T2_K,T5_K,heater_W,setpoint_K\n0.08,4.23,3.3,0,\n", "1 row(s), nothing to plot"),
])
def test_records_that_cannot_be_plotted_say_why(tmp_path, capsys, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    assert main(["plot", str(path)]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "bad.png").exists()


def test_spectral_lines_are_named_where_sampling_puts_them():
    from cryod.analysis.figures import heater_modulation_hz
    from cryod.figure_files import folded_frequency

    assert folded_frequency(1.7237, 12.5) == pytest.approx(1.7237)
    assert folded_frequency(6 * 1.7237, 12.5) == pytest.approx(12.5 - 6 * 1.7237)   # 10.34 Hz shows at 2.16 Hz
    t = np.arange(0.0, 1200.0, 0.08)
    steps = np.where(t > 300.0, 0.03, 0.0) + np.where(t > 800.0, 0.05, 0.0)
    modulated = steps + np.where((t > 400) & (t < 600), 0.01 * np.sign(np.sin(2 * np.pi * 0.4 * t)), 0.0)
    feedforward = steps + 0.1 * (1 + np.cos(2 * np.pi * 1.7237 * t))          # the cooler's line: not a modulation
    assert heater_modulation_hz(modulated, 12.5, 1.7237) == pytest.approx(0.4, abs=0.01)
    assert heater_modulation_hz(steps, 12.5, 1.7237) is None
    assert heater_modulation_hz(feedforward, 12.5, 1.7237) is None


def test_a_heater_modulation_is_looked_for_only_where_the_loop_was_open():
    from cryod.analysis.figures import record_heater_modulation_hz
    from cryod.analysis.record_data import RecordData

    t = np.arange(0.0, 1200.0, 0.08)
    square = 0.01 * np.sign(np.sin(2 * np.pi * 0.4 * t))
    # regulating throughout: a peak in the heater's spectrum is the controller's, not a modulation
    regulated = RecordData(time_s=t, flange_K=np.full(t.size, 5.0), ptc_stage_K=np.full(t.size, 3.4),
                           heater_w=0.11 + square, setpoint_K=np.full(t.size, 5.0))
    assert record_heater_modulation_hz(regulated, 1.7237) is None
    # open loop from 400 s to 800 s, modulated there
    setpoint = np.where((t > 400) & (t < 800), np.nan, 5.0)
    opened = RecordData(time_s=t, flange_K=np.full(t.size, 5.0), ptc_stage_K=np.full(t.size, 3.4),
                        heater_w=np.where(np.isnan(setpoint), 0.05 + square, 0.11), setpoint_K=setpoint)
    assert record_heater_modulation_hz(opened, 1.7237) == pytest.approx(0.4, abs=0.01)


def test_the_start_up_and_overruns_are_marked_and_left_out_of_the_spectrum(tmp_path):
    from scipy import signal

    from cryod.cli.plot import event_instants, plot_record, stretch_spectrum
    from cryod.records.record import Record
    from cryod.records.stretches import settled_stretches, startup_end_s

    t = np.arange(0.0, 1800.0, 0.08)
    rng = np.random.default_rng(3)
    flange = 5.0 - 0.77 * np.exp(-t / 100.0) + 1e-3 * np.sin(10.83 * t) + 2e-5 * rng.standard_normal(t.size)
    late = np.flatnonzero(t > 1000.0)[::400][:6]           # six overruns: a deadline skipped, a 5 mK spike
    flange[late] += 5e-3
    keep = np.ones(t.size, dtype=bool)
    keep[late - 1] = False
    rows = np.flatnonzero(keep)
    columns = {"time_s": t[keep], "T2_K": flange[keep], "T5_K": 3.6 + 0.12 * np.sin(10.83 * t[keep]),
               "heater_W": np.full(rows.size, 0.1), "setpoint_K": np.full(rows.size, 5.0)}
    events = [(int(np.searchsorted(rows, index)), "event: overrun: cycle ended 95.0 ms after its deadline")
              for index in late]
    record = Record({}, columns, events, source="overruns.csv")
    marks = event_instants(record)
    assert marks["overrun"] == pytest.approx(list(t[late]))
    end = startup_end_s(record.time_s, record.flange_K, record.setpoint_K)
    assert 800.0 < end < 1000.0                           # 0.77 K e^(-t/100 s) is within 0.1 mK after 894 s
    stretches = settled_stretches(record.time_s, record.flange_K, record.setpoint_K, marks["overrun"], 0.08)
    for start, stop in stretches:
        assert record.time_s[start] >= end
        assert not any(record.time_s[start] < instant <= record.time_s[stop - 1] for instant in marks["overrun"])
    frequency, amplitude, _, used_s = stretch_spectrum(record.flange_K, stretches, 12.5)
    assert 400.0 < used_s < 800.0
    whole_frequency, whole_density = signal.welch(record.flange_K, fs=12.5, nperseg=4096, scaling="spectrum")
    assert np.sqrt(2 * whole_density[1]) > 1e-3                     # the start-up's transient, tens of mK
    assert amplitude[1] < 3e-5                                      # left out: noise and the line's skirt
    assert amplitude[np.argmin(np.abs(frequency - 10.83 / (2 * np.pi)))] == pytest.approx(1e-3, rel=0.2)
    assert plot_record(record, tmp_path / "overruns.png").stat().st_size > 50_000
