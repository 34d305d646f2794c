import numpy as np
import pytest

from gateway.kitcsv import KitCsvError, read_kit_csv, write_kit_csv
from gateway.series import load_series, resample

HEADER = "time,t_in,rh_in,t_out,i_glob,wind\n"


def write(tmp_path, body, header=HEADER, name="d.csv"):
    path = tmp_path / name
    path.write_text(header + body, encoding="utf-8")
    return path


def test_round_trip_keeps_values_and_gaps(tmp_path):
    t = np.datetime64("2020-03-27T00:00:00", "s") + np.arange(5) * np.timedelta64(60, "s")
    cols = {"t_in": np.array([20.0, 20.5, np.nan, 21.25, 21.5]), "wind": np.array([0, 1, 2, 3, 4.0])}
    path = write_kit_csv(tmp_path / "x.csv", t, cols)
    back = read_kit_csv(path)
    assert np.array_equal(back.time, t)
    assert np.allclose(back.columns["t_in"], cols["t_in"], equal_nan=True)
    assert "2020-03-27T00:00:00Z" in path.read_text()


def test_kelvin_temperature_is_an_error_naming_line_and_column(tmp_path):
    path = write(tmp_path, "2020-03-27T00:00:00Z,20,50,10,0,1\n2020-03-27T00:01:00Z,293.2,50,10,0,1\n")
    with pytest.raises(KitCsvError, match=r"d\.csv:3: column t_in: .*kelvin"):
        read_kit_csv(path)


def test_rh_above_100_is_an_error(tmp_path):
    path = write(tmp_path, "2020-03-27T00:00:00Z,20,100.4,10,0,1\n")
    with pytest.raises(KitCsvError, match=r"d\.csv:2: column rh_in: .*cannot exceed 100"):
        read_kit_csv(path)


def test_time_going_backwards_is_an_error(tmp_path):
    body = "2020-03-27T00:01:00Z,20,50,10,0,1\n2020-03-27T00:00:00Z,20,50,10,0,1\n"
    with pytest.raises(KitCsvError, match=r"d\.csv:3: column time: .*not after"):
        read_kit_csv(write(tmp_path, body))


def test_exact_repeated_rows_are_skipped_with_a_notice(tmp_path):
    row = "2020-03-27T00:01:00Z,20,50,10,0,1\n"
    body = "2020-03-27T00:00:00Z,19,50,10,0,1\n" + row + row + "2020-03-27T00:02:00Z,21,50,10,0,1\n"
    data = read_kit_csv(write(tmp_path, body))
    np.testing.assert_array_equal(data.columns["t_in"], [19, 20, 21])
    assert any("skipped 1 exact repeat" in n and "line(s) 4" in n for n in data.notices)


def test_repeated_time_with_other_values_is_an_error(tmp_path):
    body = "2020-03-27T00:00:00Z,20,50,10,0,1\n2020-03-27T00:00:00Z,20.5,50,10,0,1\n"
    with pytest.raises(KitCsvError, match=r"d\.csv:3: column time: .*repeats .* other values"):
        read_kit_csv(write(tmp_path, body))


def test_time_without_offset_is_an_error(tmp_path):
    with pytest.raises(KitCsvError, match=r":2: column time: .*UTC offset"):
        read_kit_csv(write(tmp_path, "2020-03-27T00:00:00,20,50,10,0,1\n"))


def test_offsets_are_converted_to_utc(tmp_path):
    data = read_kit_csv(write(tmp_path, "2020-03-27T02:00:00+02:00,20,50,10,0,1\n"))
    assert data.time[0] == np.datetime64("2020-03-27T00:00:00")


def test_bad_number_and_missing_column(tmp_path):
    with pytest.raises(KitCsvError, match=r":2: column wind: not a number: 'calm'"):
        read_kit_csv(write(tmp_path, "2020-03-27T00:00:00Z,20,50,10,0,calm\n"))
    with pytest.raises(KitCsvError, match=r"missing required column\(s\) t_soil"):
        read_kit_csv(write(tmp_path, "2020-03-27T00:00:00Z,20,50,10,0,1\n"), required=["t_soil"])


def test_unknown_columns_are_ignored_with_a_notice(tmp_path):
    path = write(tmp_path, "2020-03-27T00:00:00Z,20,7\n", header="time,t_in,leaf_wetness\n")
    data = read_kit_csv(path)
    assert "leaf_wetness" not in data.columns
    assert any("leaf_wetness" in n for n in data.notices)


def test_resample_keeps_long_gaps_as_gaps(tmp_path):
    # 1-minute samples with a 10-minute hole: no value is invented inside the hole.
    minutes = [0, 1, 2, 12, 13]
    body = "".join(f"2020-03-27T00:{m:02d}:00Z,{20 + m},50,10,0,1\n" for m in minutes)
    s = load_series(write(tmp_path, body), step=60)
    assert len(s) == 14
    assert np.isnan(s["t_in"][3:12]).all()
    assert s["t_in"][12] == 32.0


def test_resample_interpolates_short_gaps_and_averages_fast_samples(tmp_path):
    # 5-minute data onto 1 minute: interpolated linearly (gap = 300 s is allowed).
    body = "2020-03-27T00:00:00Z,20,50,10,0,1\n2020-03-27T00:05:00Z,25,50,10,0,1\n"
    s = load_series(write(tmp_path, body), step=60)
    assert np.allclose(s["t_in"], [20, 21, 22, 23, 24, 25])
    # 30 s samples onto 1 minute: block means, no aliasing of alternate samples.
    rows = "".join(
        f"2020-03-27T00:{i // 2:02d}:{30 * (i % 2):02d}Z,{20 + (i % 2)},50,10,0,1\n" for i in range(12)
    )
    data = read_kit_csv(write(tmp_path, rows, name="fast.csv"))
    s = resample(data, 60)
    assert np.allclose(s["t_in"][1:-1], 20.5)


def test_data_coarser_than_the_gap_limit_is_an_error_not_an_empty_series(tmp_path):
    # 10-minute data on the default 1-minute grid would be all gaps: say so and name the step.
    rows = [(h, m) for h in range(3) for m in range(0, 60, 10)]
    body = "".join(f"2020-03-27T{h:02d}:{m:02d}:00Z,20,50,10,0,1\n" for h, m in rows)
    with pytest.raises(KitCsvError, match=r"d\.csv: samples are 600 s apart.*--step 600"):
        load_series(write(tmp_path, body), step=60)
    # At its own step it reads, also when the clock is not aligned to the grid.
    body = "".join(f"2020-03-27T{h:02d}:{m + 5:02d}:07Z,{20 + h},50,10,0,1\n" for h, m in rows)
    s = load_series(write(tmp_path, body, name="u.csv"), step=600)
    assert len(s) == 17 and np.isfinite(s["t_in"]).all()


def test_byte_order_mark_is_accepted(tmp_path):
    path = tmp_path / "excel.csv"
    path.write_text("\ufeff" + HEADER + "2020-03-27T00:00:00Z,20,50,10,0,1\n", encoding="utf-8")
    assert read_kit_csv(path).columns["t_in"][0] == 20.0


def test_semicolon_separator_is_named(tmp_path):
    path = write(tmp_path, "2020-03-27T00:00:00Z;20;50;10;0;1\n", header=HEADER.replace(",", ";"))
    with pytest.raises(KitCsvError, match=r"d\.csv:1: .*separator must be a comma, not ';'"):
        read_kit_csv(path)


def test_relative_humidity_as_a_fraction_is_an_error(tmp_path):
    body = "".join(f"2020-03-27T00:{m:02d}:00Z,20,0.{50 + m},10,0,1\n" for m in range(12))
    with pytest.raises(KitCsvError, match=r"d\.csv: column rh_in: .*fraction"):
        read_kit_csv(write(tmp_path, body))
    dry = "".join(f"2020-03-27T00:{m:02d}:00Z,20,{0.5 + m},10,0,1\n" for m in range(12))
    assert read_kit_csv(write(tmp_path, dry, name="dry.csv")).columns["rh_in"][0] == 0.5
