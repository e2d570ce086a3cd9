"""``cryod init DIR``: a new lab's configuration that stands on its own, accepted by ``cryod run --check``."""

import stat

from cryod.cli import main
from cryod.config import load_config
from cryod.web_token import read_token


def test_a_new_labs_folder_is_checked_and_runs_a_dry_run_from_anywhere(tmp_path, capsys, monkeypatch):
    folder = tmp_path / "lab" / "flange-A"
    assert main(["init", str(folder), "--prologix-lan", "192.168.1.40"]) == 0
    printed = capsys.readouterr().out
    assert f"cryod run --check --config {folder / 'cryod.yaml'}" in printed
    assert main(["run", "--check", "--config", str(folder / "cryod.yaml")]) == 0
    assert "configuration and calibration files are valid" in capsys.readouterr().out
    config = load_config(folder / "cryod.yaml")
    assert config.instruments.flange_dmm.prologix_host == "192.168.1.40"
    assert config.instruments.trigger == "prologix"
    assert config.web.address == "127.0.0.1:8336" and not config.web.writable
    token = folder / "web.token"
    assert stat.S_IMODE(token.stat().st_mode) == 0o640 and len(read_token(token)) == 64
    assert config.sensors.flange_calibration == folder / "calibration" / "X186279.340"
    unit = (folder / "cryod.service").read_text()
    assert f"run --config {folder.absolute() / 'cryod.yaml'}" in unit and "/opt/cryod/venv" not in unit
    other = tmp_path / "elsewhere"                  # the folder holds what it names: a dry run from another folder
    other.mkdir()
    monkeypatch.chdir(other)
    assert main(["--simulate", "--config", str(folder / "cryod.yaml"), "--duration", "5", "--speed", "max",
                 "--data-dir", str(other / "data"), "--socket", str(other / "s.sock")]) == 0
    assert list((other / "data").glob("cryod-*.csv"))


def test_init_writes_nothing_over_what_is_there_and_needs_to_be_told_the_connection(tmp_path, capsys):
    folder = tmp_path / "lab"
    folder.mkdir()
    (folder / "cryod.yaml").write_text("the lab's own\n")
    assert main(["init", str(folder), "--gpib"]) == 2
    assert "holds cryod.yaml already; nothing was written" in capsys.readouterr().err
    assert (folder / "cryod.yaml").read_text() == "the lab's own\n" and not (folder / "web.token").exists()
    try:
        main(["init", str(tmp_path / "other")])
    except SystemExit as ended:
        assert ended.code == 2
    assert "one of the arguments --gpib --prologix-usb --prologix-lan is required" in capsys.readouterr().err


def test_a_folder_written_after_gpib_is_the_folder_and_a_card_that_is_not_a_number_is_refused(tmp_path, capsys,
                                                                                             monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["init", "--gpib", "lab"]) == 0                 # read as the folder, on card 0
    assert "resource: GPIB0::" in (tmp_path / "lab" / "cryod.yaml").read_text()
    assert main(["init", "--gpib", "1"]) == 2                   # a card, but no folder
    assert "say where to write the files" in capsys.readouterr().err
    assert main(["init", "other", "--gpib", "x"]) == 2
    assert "--gpib takes a GPIB card's number, not 'x'" in capsys.readouterr().err
    assert not (tmp_path / "other").exists()
    assert main(["init", "second", "--gpib", "2"]) == 0
    assert "resource: GPIB2::" in (tmp_path / "second" / "cryod.yaml").read_text()
