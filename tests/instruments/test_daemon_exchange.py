"""The drivers send the simulated instruments the same bytes and get the same replies as before the tick was made cheaper.

``tests/data/daemon_exchange.txt`` was recorded by :mod:`daemon_exchange` on the tree before the
simulated instruments and the drivers took their shortcuts (answering from state, whole messages
looked up once, calibration tables): every command, every reply and every group trigger of 80
simulated seconds must be the same, so the simulation still proves what the drivers would say to a
real 2002 or 6221 and that they parse what one answers.
"""

from pathlib import Path

from daemon_exchange import digest, recorded_exchange

RECORDED = Path(__file__).resolve().parent.parent / "data" / "daemon_exchange.txt"


def recorded_file():
    text = RECORDED.read_text().splitlines()
    header = {key.strip(): value.strip() for line in text if line.startswith("# ") and ": " in line[2:]
              for key, _, value in [line[2:].partition(": ")]}
    return int(header["exchanges"]), header["sha256"], [line for line in text if not line.startswith("#")]


def test_the_drivers_exchange_with_the_simulated_instruments_is_unchanged():
    count, sha256, first = recorded_file()
    exchange = recorded_exchange()
    for index, (now, then) in enumerate(zip(exchange, first)):
        assert now == then, f"exchange {index}: now {now!r}, recorded {then!r}"
    assert len(exchange) == count
    assert digest(exchange) == sha256, ("the exchange differs after the recorded head: compare two trees with "
                                        "tests/instruments/daemon_exchange.py")
