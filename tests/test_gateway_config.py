"""The gateway config: validated at start, every error one line naming the file and the key; the
shipped example parses and every key it uses is documented."""

from __future__ import annotations

import os
import re
import tomllib
from pathlib import Path

import pytest

from gateway.cli import main
from gateway.service.config import ConfigError, load_config, parse_config
from gateway.service.resources import prepare
from gateway.store.keys import write_keys
from tests.gateway_harness import KEY

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "images" / "gateway" / "gateway.toml"
GOOD = {
    "gateway": {"farm": "f1", "db": "gw.db", "keys": "keys.txt"},
    "greenhouse": [{"name": "north", "greenhouse": "biskra-prototype", "model": "prototype",
                    "inside": 7}],
}


def with_(path: str, value, base: dict | None = None) -> dict:
    import copy

    cfg = copy.deepcopy(base or GOOD)
    node = cfg
    keys = path.split(".")
    for k in keys[:-1]:
        node = node[int(k)] if isinstance(node, list) else node.setdefault(k, {})
    if value is KeyError:
        del node[keys[-1]]
    else:
        node[keys[-1]] = value
    return cfg


@pytest.mark.parametrize("path, value, message", [
    ("zenoh.mdoe", "peer", "gw.toml: zenoh.mdoe: unknown key (allowed here: "),
    ("gateway.farm", "my/farm", "gateway.farm: 'my/farm' is not usable in a Zenoh key"),
    ("gateway.farm", KeyError, "gateway.farm: missing (required)"),
    ("ingest.listen", "5683", "ingest.listen: expected HOST:PORT"),
    ("ingest.retention_days", "a year", "ingest.retention_days: must be a number, got 'a year'"),
    ("zenoh.mode", "router", "zenoh.mode: 'router' is not one of peer, client"),
    ("zenoh.mode", "client", "zenoh.connect: client mode needs at least one router"),
    ("zenoh.connect", ["192.168.1.2:7447"], "zenoh.connect[0]: expected a Zenoh endpoint"),
    ("estimator.horizons_min", [15, 0], "estimator.horizons_min: must be whole minutes"),
    ("estimator.forecast", "best", "estimator.forecast: 'best' is not one of adaptive, adaptive_kf, "),
    ("estimator.snapshot_every_min", 61, "estimator.snapshot_every_min: 61 is outside 1..60"),
    ("clock.scale", 300, "clock.epoch: a scaled clock needs the time it starts from"),
    ("clock.epoch", "yesterday", "clock.epoch: expected an ISO UTC time"),
    ("greenhouse.0.inside", KeyError, "greenhouse[1].inside: missing (required)"),
    ("greenhouse.0.inside", "7", "greenhouse[1].inside: must be a whole number, got '7'"),
    ("greenhouse.0.name", "history", "greenhouse[1].name: 'history' is not usable"),
    ("greenhouse.0.model", "tomato",
     "greenhouse[1].model: 'tomato' is not one of prototype, prototype+vent_control, "
     "prototype+vent_control+heating, almeria"),
    ("greenhouse.0.outlook", "crystal-ball", "greenhouse[1].outlook: unknown weather outlook"),
    ("greenhouse.0.greenhouse", "nowhere.toml", "greenhouse[1].greenhouse: "),
    ("greenhouse.0.vents", 3, "greenhouse[1].vents: unknown key"),
    ("greenhouse", [], "greenhouse: at least one [[greenhouse]] table is required"),
])
def test_errors_name_the_key(path: str, value, message: str, tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as e:
        parse_config(with_(path, value), "gw.toml", tmp_path)
    assert message in str(e.value)
    assert "\n" not in str(e.value)


def test_twice_the_same_greenhouse_and_no_location(tmp_path: Path) -> None:
    two = with_("greenhouse", GOOD["greenhouse"] * 2)
    with pytest.raises(ConfigError, match=r"greenhouse\[2\].name: 'north' is used twice"):
        parse_config(two, "gw.toml")
    own = tmp_path / "no_site.toml"  # a greenhouse file without [site]
    own.write_text("[geometry]\nfloor_area = 1.0\nvolume = 1.0\n")
    with pytest.raises(ConfigError, match=r"greenhouse\[1\].greenhouse: .* no \[site\]"):
        parse_config(with_("greenhouse.0.greenhouse", str(own)), "gw.toml")
    located = with_("location", {"latitude": 52.0, "longitude": 4.5},
                    with_("greenhouse.0.greenhouse", str(own)))
    cfg = parse_config(located, "gw.toml")
    assert (cfg.greenhouses[0].latitude, cfg.greenhouses[0].longitude) == (52.0, 4.5)
    # no [site]: the clear sky cannot be placed, so the default outlook holds the latest values
    assert cfg.greenhouses[0].outlook == "hold-latest"
    with pytest.raises(ConfigError, match=r"greenhouse\[1\].outlook: clear-sky-trend needs"):
        parse_config(with_("greenhouse.0.outlook", "clear-sky-trend", located), "gw.toml")


def test_the_default_outlook_is_the_clear_sky_one_and_can_be_named(tmp_path: Path) -> None:
    """A greenhouse with a [site] forecasts with clear-sky-trend unless the config names
    another outlook ([estimator] for all, or per greenhouse)."""
    assert parse_config(GOOD, "gw.toml").greenhouses[0].outlook == "clear-sky-trend"
    held = parse_config(with_("estimator.outlook", "hold-latest"), "gw.toml")
    assert held.greenhouses[0].outlook == "hold-latest"
    own = parse_config(with_("greenhouse.0.outlook", "hold-latest"), "gw.toml")
    assert own.greenhouses[0].outlook == "hold-latest"


def test_what_the_config_names_is_checked_before_start(tmp_path: Path) -> None:
    write_keys(tmp_path / "keys.txt", {7: KEY})
    (tmp_path / "params.toml").write_text('model = "almeria"\n[params]\nc_asw = 0.2\n')

    def check(cfg: dict, message: str) -> None:
        with pytest.raises(ConfigError) as e:
            prepare(parse_config(cfg, "gw.toml", tmp_path))
        assert message in str(e.value), str(e.value)

    check(with_("greenhouse.0.outside", 9),
          "greenhouse[1].outside: device 9 has no key in")
    check(with_("greenhouse.0.params", "params.toml"),
          "greenhouse[1].params: ")
    check(with_("greenhouse.0.model", "almeria"),
          "greenhouse[1].model: the 'almeria' model needs t_soil")
    check(with_("greenhouse.0.vsensor", "vent.onnx"), "greenhouse[1].vsensor: ")
    check(with_("gateway.keys", "missing.txt"), "gateway.keys: cannot read")
    (res,) = prepare(parse_config(GOOD, "gw.toml", tmp_path))
    assert res.model.name == "prototype" and res.theta0 is None


def test_the_vented_prototype_is_a_model_a_greenhouse_can_name(tmp_path: Path) -> None:
    """``prototype+vent_control``: six parameters; a virtual sensor of a model kind the kit cannot
    feed (almeria: t_soil) is refused, naming the key and the column."""
    from gateway.vsensor.models import __file__ as models_init

    write_keys(tmp_path / "keys.txt", {7: KEY})
    vented = with_("greenhouse.0.model", "prototype+vent_control")
    (res,) = prepare(parse_config(vented, "gw.toml", tmp_path))
    assert res.model.name == "prototype+vent_control"
    assert res.model.names[-2:] == ["c_vc", "t_vc"] and len(res.model.names) == 6
    shipped = Path(models_init).with_name("almeria.onnx")
    with pytest.raises(ConfigError, match=r"greenhouse\[1\]\.vsensor: .*'almeria' model, which needs t_soil"):
        prepare(parse_config(with_("greenhouse.0.vsensor", str(shipped), vented), "gw.toml", tmp_path))


def test_cli_says_one_line_and_check_validates(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('[gateway]\nfarm = "f1"\ndb = "x.db"\nkeys = "k"\n[zenoh]\nmode = "router"\n')
    assert main(["run", "--config", str(bad)]) == os.EX_CONFIG  # 78: systemd does not restart
    err = capsys.readouterr().err
    assert err.startswith(f"error: {bad}: zenoh.mode:") and err.count("\n") == 1
    write_keys(tmp_path / "keys.txt", {7: KEY})
    good = tmp_path / "good.toml"
    good.write_text('[gateway]\nfarm = "f1"\ndb = "gw.db"\nkeys = "keys.txt"\n[[greenhouse]]\n'
                    'name = "north"\ngreenhouse = "biskra-prototype"\nmodel = "prototype"\ninside = 7\n')
    assert main(["run", "--config", str(good), "--check"]) == 0
    assert "ok: farm f1, 1 greenhouse(s), devices 7" in capsys.readouterr().out
    assert not (tmp_path / "gw.db").exists()  # a check changes nothing


def test_the_shipped_example_parses_and_every_key_is_documented() -> None:
    cfg = load_config(EXAMPLE)
    assert cfg.farm == "demo-farm" and cfg.greenhouses[0].inside == 7
    doc = (ROOT / "docs" / "gateway.md").read_text()
    text = EXAMPLE.read_text()
    raw = tomllib.loads(text)
    keys = {k for sec in raw.values() if isinstance(sec, dict) for k in sec}
    keys |= {k for g in raw["greenhouse"] for k in g}
    keys |= set(re.findall(r"^# (\w+) = ", text, re.M))  # the commented-out ones
    missing = sorted(k for k in keys if f"`{k}`" not in doc)
    assert not missing, f"keys of the example not in docs/gateway.md: {missing}"


def test_log_lines_fit_journald(monkeypatch) -> None:
    import logging

    from gateway.cli.run import JournalFormatter

    rec = logging.LogRecord("serra.gateway", logging.WARNING, "x", 1, "outbox alarm\nsecond", (), None)
    monkeypatch.setenv("JOURNAL_STREAM", "8:1234")
    assert JournalFormatter().format(rec) == "<4>WARNING serra.gateway: outbox alarm | second"
    monkeypatch.delenv("JOURNAL_STREAM")
    assert JournalFormatter().format(rec).endswith(" WARNING serra.gateway: outbox alarm | second")


def test_subscribe_cli_exports_a_kit_csv_per_greenhouse(tmp_path: Path, capsys) -> None:
    from gateway.cloud.store import SqliteCloudStore, parse
    from gateway.kitcsv import read_kit_csv
    from gateway.publish import payloads as P

    place = P.Place("f1", "north", 34.85, 5.73)
    store = SqliteCloudStore(tmp_path / "cloud.db")
    msgs = []
    for seq in range(3):
        r = P.Reading(7, 0, seq, 1_257_055_230.0 + 60 * seq,
                      {"t_in": (20.0 + seq, 0), "rh_in": (60.0, 0), "t_out": (10.0, 0),
                       "rh_out": (80.0, 0), "i_glob": (100.0, 0), "wind": (2.0, 0), "rain": (0.0, 0)})
        for side in ("inside", "outside"):
            idem = f"f1/north/{side}/{seq}"
            msgs.append(parse(f"serra/f1/north/measurement/{side}",
                              P.dumps(P.weather_observed(place, side, r, idem))))
    assert store.add(msgs) == 6 and store.add(msgs) == 0  # repeats dropped
    store.close()
    assert main(["subscribe", "--db", str(tmp_path / "cloud.db"), "--export", str(tmp_path / "csv")]) == 0
    data = read_kit_csv(tmp_path / "csv" / "f1-north.csv")
    assert list(data.columns["t_in"]) == [20.0, 21.0, 22.0] and list(data.columns["rh_in"]) == [60.0] * 3
    assert main(["subscribe", "--db", str(tmp_path / "cloud.db")]) == 78  # EX_CONFIG
    assert "give --connect" in capsys.readouterr().err


def test_a_port_in_use_is_one_line_naming_it(tmp_path: Path) -> None:
    import socket
    import subprocess
    import sys

    from tests.gateway_harness import write_config

    busy = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    busy.bind(("127.0.0.1", 0))
    try:
        cfg = write_config(tmp_path, anchor=0.0)
        port = busy.getsockname()[1]
        cfg.write_text(cfg.read_text().replace('listen = "127.0.0.1:0"', f'listen = "127.0.0.1:{port}"'))
        r = subprocess.run([sys.executable, "-m", "gateway", "run", "--config", str(cfg)],
                           capture_output=True, text=True, timeout=120, cwd=tmp_path,
                           env={**os.environ, "TMPDIR": str(tmp_path)})
    finally:
        busy.close()
    assert r.returncode == 2 != os.EX_CONFIG  # a held port may free up: the units restart on 2
    last = r.stderr.strip().splitlines()[-1]
    assert f"ERROR serra.gateway: cannot listen on 127.0.0.1:{port}: address already in use" in last
    assert "Traceback" not in r.stderr


def test_zenoh_off_stores_and_estimates_but_makes_no_message(tmp_path: Path) -> None:
    import sqlite3
    import time

    from tests.gateway_harness import EPOCH, GatewayProcess, PyKit, sim_trace, wait_for, write_config
    from training.kitsim import KitClock

    clock = KitClock(300.0, EPOCH)
    cfg = write_config(tmp_path, anchor=clock.anchor)
    cfg.write_text(cfg.read_text().replace("[zenoh]", "[zenoh]\nenabled = false"))
    gw = GatewayProcess(cfg)
    kit = PyKit(7, sim_trace(), clock.now)

    def count(sql: str) -> int:
        with sqlite3.connect(tmp_path / "gw.db") as c:
            return c.execute(sql).fetchone()[0]

    try:
        gw.start()
        assert gw.zenoh == "off"
        wait_for(lambda: kit.pump(gw.udp) or count("SELECT count(*) FROM estimates "
                                                    "WHERE source='forecast'") >= 6,
                 90, "forecasts stored")
        assert gw.stop() == 0
    finally:
        gw.kill()
        kit.close()
    assert count("SELECT count(*) FROM samples") >= 3 and count("SELECT count(*) FROM outbox") == 0
    assert time.time() - clock.anchor < 300
