"""Resampling a logger whose clock jitters (docs/data-format.md): 5-minute rows stamped up to
±20 s off their slot are neighbours, not holes; one missing row still is a hole."""

import numpy as np

from gateway.series import load_series

HEADER = "time,t_in,rh_in,t_out,i_glob,wind\n"
JITTER_S = (0, 20, 0, -20) * 3 + (0,)
"""Offsets [s] of 13 five-minute rows: median spacing 300 s, neighbours up to 5 min 40 s
apart."""


def _rows(keep=lambda i: True) -> str:
    out = []
    for i, j in enumerate(JITTER_S):
        s = 300 * i + j + 60  # from 00:01:00, so a -20 s offset stays within the hour
        if keep(i):
            out.append(f"2020-03-27T{s // 3600:02d}:{s % 3600 // 60:02d}:{s % 60:02d}Z,"
                       f"{20 + 0.1 * i:.1f},50,10,0,1\n")
    return "".join(out)


def test_jittered_five_minute_rows_leave_no_gap_on_the_minute_grid(tmp_path):
    path = tmp_path / "jitter.csv"
    path.write_text(HEADER + _rows(), encoding="utf-8")
    s = load_series(path, step=60)
    assert len(s) > 55
    assert np.isfinite(s["t_in"]).all()
    assert np.all(np.diff(s["t_in"]) >= -1e-9)  # interpolated between the rows, rising


def test_one_missing_jittered_row_is_still_a_gap(tmp_path):
    path = tmp_path / "missing.csv"
    path.write_text(HEADER + _rows(keep=lambda i: i != 6), encoding="utf-8")
    s = load_series(path, step=60)
    hole = np.isnan(s["t_in"])
    assert 8 <= hole.sum() <= 10  # the ~10-minute hole around the dropped row, nothing else
    assert np.all(np.diff(np.flatnonzero(hole)) == 1)


def test_a_kit_that_sends_every_305_s_reads_on_the_minute_grid(tmp_path):
    # sleeps 300 s, takes 5 s to measure and send: 5-minute data, not data for --step 305
    body = "".join(f"2020-03-27T{305 * i // 3600:02d}:{305 * i % 3600 // 60:02d}:"
                   f"{305 * i % 60:02d}Z,{20 + 0.1 * i:.1f},50,10,0,1\n" for i in range(12))
    path = tmp_path / "slow.csv"
    path.write_text(HEADER + body, encoding="utf-8")
    s = load_series(path, step=60)
    assert len(s) > 55
    assert np.isfinite(s["t_in"]).all()
