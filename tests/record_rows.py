"""Rows of a record as the loop hands them to the data log, made up for a test."""

from cryod.records.columns import REQUIRED, STATE, Row, RowSchema

SCHEMA = RowSchema(REQUIRED + (STATE,))


def rows(start, count, period=0.08):
    return [Row(time_s=start + k * period, lateness_ms=0.0, T2_K=4.23 + 1e-6 * k, T5_K=3.34, heater_W=0.01,
                setpoint_K=5.0 if k % 2 else float("nan"), state="closed") for k in range(count)]
