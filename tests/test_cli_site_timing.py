"""Data whose daylight falls in the site's night (a longitude of the wrong sign, local times
written with Z): the tools warn, since the clear-sky index would sit at 0 by day without any
error (docs/data-format.md, ``time``)."""

from __future__ import annotations

import argparse

import numpy as np

from gateway.cli.common import load_inputs
from gateway.kitcsv import write_kit_csv

LAT, LON = 52.0, 4.5
"""The site of the greenhouse file: solar noon near 11:45 UTC."""


def _args(tmp_path, noon_utc_h: float) -> argparse.Namespace:
    """Two days of 5-minute rows whose radiation peaks at ``noon_utc_h`` (UTC)."""
    t = np.datetime64("2020-03-27T00:00:00", "s") + np.arange(576) * np.timedelta64(300, "s")
    hours = (t - t[0]).astype(float) / 3600.0
    sun = np.maximum(np.cos(2 * np.pi * (hours - noon_utc_h) / 24.0), 0.0) ** 1.5
    n = len(t)
    cols = {"t_in": np.full(n, 18.0), "rh_in": np.full(n, 60.0), "t_out": np.full(n, 10.0),
            "rh_out": np.full(n, 70.0), "i_glob": np.round(600.0 * sun, 1), "wind": np.full(n, 2.0)}
    data = write_kit_csv(tmp_path / f"noon{noon_utc_h:g}.csv", t, cols)
    gh = tmp_path / "gh.toml"
    gh.write_text('name = "g"\n\n[geometry]\nfloor_area = 20.0\nvolume = 50.0\n\n'
                  f"[site]\nlatitude = {LAT}\nlongitude = {LON}\n", encoding="utf-8")
    return argparse.Namespace(greenhouse=str(gh), model="prototype", data=str(data), step=300.0,
                              site=None)


def test_daylight_in_the_sites_night_is_a_warning(capsys, tmp_path):
    load_inputs(_args(tmp_path, noon_utc_h=0.0))  # ~12 h off: a longitude of the wrong sign
    err = capsys.readouterr().err
    assert "warning:" in err and "sun is below the horizon" in err
    assert f"longitude {LON:g}" in err


def test_correctly_timed_daylight_gives_no_warning(capsys, tmp_path):
    load_inputs(_args(tmp_path, noon_utc_h=11.75))
    assert "below the horizon" not in capsys.readouterr().err
