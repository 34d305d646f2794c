import pytest

from gateway.greenhouse import GreenhouseError, list_presets, load_greenhouse
from gateway.model import build_model


def test_presets_load_with_thesis_geometry():
    assert {"biskra-prototype", "almeria-palmerillas"} <= set(list_presets())
    proto = load_greenhouse("biskra-prototype")
    assert (proto.floor_area, proto.volume, proto.air_density, proto.pressure) == (0.68, 0.76, 1.205, 101.0)
    alm = load_greenhouse("almeria-palmerillas")
    assert alm.floor_area == pytest.approx(37.80 * 23.20, rel=1e-3)
    assert (alm.vents.roof_count, alm.vents.side_count) == (5, 2)


def test_user_file_works_like_a_preset_and_overrides_parameters(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text(
        'name = "mine"\n[geometry]\nfloor_area = 100.0\nvolume = 300.0\n'
        "[parameters.c_cnd_cnv]\nvalue = 7.5\nbounds = [2.0, 50.0]\n",
        encoding="utf-8",
    )
    gh = load_greenhouse(path)
    model = build_model("almeria", gh)
    lo, hi = model.bounds(gh)
    j = model.index("c_cnd_cnv")
    assert (lo[j], hi[j], model.defaults(gh)[j]) == (2.0, 50.0, 7.5)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[geometry]\nfloor_area = 1.0\nvolume = 1.0\nroof = 3\n", "unknown key 'geometry.roof'"),
        ("colour = 'red'\n[geometry]\nfloor_area = 1.0\nvolume = 1.0\n", "unknown key 'colour'"),
        ("[geometry]\nfloor_area = -2.0\nvolume = 1.0\n", "'geometry.floor_area' = -2.0 is impossible"),
        ("[geometry]\nfloor_area = 1.0\n", "missing 'geometry.volume'"),
        ("[geometry]\nfloor_area = 1.0\nvolume = 1.0\n[cover]\ntransmission = 1.5\n",
         "'cover.transmission' = 1.5 is impossible"),
        ("[geometry]\nfloor_area = 1.0\nvolume = 1.0\n[vents]\nroof_count = 2.5\n",
         "'vents.roof_count' must be a whole number"),
        ("[geometry]\nfloor_area = 1.0\nvolume = 1.0\n[parameters.c_loss]\nbounds = [2, 1]\n",
         "'parameters.c_loss.bounds' must be"),
        ("sensors = ['t_in', 'moon']\n[geometry]\nfloor_area = 1.0\nvolume = 1.0\n", "unknown column 'moon'"),
    ],
)
def test_bad_descriptions_name_the_key(tmp_path, text, match):
    path = tmp_path / "bad.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(GreenhouseError, match=match):
        load_greenhouse(path)


def test_unknown_preset_lists_the_presets():
    with pytest.raises(GreenhouseError, match="biskra-prototype"):
        load_greenhouse("atlantis")


@pytest.mark.parametrize(
    ("table", "match"),
    [
        ("[parameters.c_sollar]\nvalue = 1e-4\n", "unknown parameter 'parameters.c_sollar'"),
        ("[parameters.c_solar]\nvalue = 5e-4\nbounds = [0.0, 2e-4]\n",
         r"'parameters.c_solar.value' = 0.0005 is outside its bounds \[0, 0.0002\]"),
    ],
)
def test_parameter_typo_or_value_outside_bounds_is_an_error(tmp_path, table, match):
    from gateway.model import check_parameters

    path = tmp_path / "mine.toml"
    path.write_text("[geometry]\nfloor_area = 1.0\nvolume = 1.0\n" + table, encoding="utf-8")
    gh = load_greenhouse(path)
    with pytest.raises(GreenhouseError, match=match):
        check_parameters(build_model("prototype", gh), gh)
    # A parameter of the other model is no typo: one file may serve both models.
    path.write_text("[geometry]\nfloor_area = 1.0\nvolume = 1.0\n[parameters.c_asw]\nvalue = 0.5\n")
    gh = load_greenhouse(path)
    check_parameters(build_model("prototype", gh), gh)
