"""The live log's line about a missing outside humidity (gateway/service/humidity_watch.py):
once per outage, however the channel flickers; nothing while rh_out is there or while the
outside temperature is missing too."""

from __future__ import annotations

import math

from gateway.service.humidity_watch import HumidityWatch

T0 = 1_257_055_200.0  # 2009-11-01T06:00Z


def _lines(watch: HumidityWatch, rh: list[float], t_out: float = 10.0) -> list[str]:
    out = []
    for k, v in enumerate(rh):
        said = watch.see(T0 + 60 * k, {"t_out": t_out, "rh_out": v})
        if said:
            out.append(said)
    return out


def test_a_flickering_channel_is_said_once_until_it_is_back_for_good() -> None:
    w = HumidityWatch("north", back_min=30)
    flicker = [80.0 if k % 2 else math.nan for k in range(300)]  # every other minute
    lines = _lines(w, [80.0] * 10 + flicker + [80.0] * 30)
    assert len(lines) == 2, lines
    assert "no outside relative humidity (rh_out) from 2009-11-01T06:10Z" in lines[0]
    assert "back since 2009-11-01T11:09Z" in lines[1]  # minute 309: the flicker's last RH, then 30
    assert not w.missing


def test_nothing_is_said_with_rh_out_or_without_t_out() -> None:
    w = HumidityWatch("north", back_min=30)
    assert _lines(w, [70.0] * 100) == []
    assert _lines(w, [math.nan] * 100, t_out=math.nan) == []  # a dead outside kit: no sky at all
    assert not w.missing
