"""A greenhouse's calibrated parameters (``params = ...``) with a starting value outside its hard
box: ``run --check`` warns (and still accepts the config), and the service logs the same line
once when it builds the estimator, which starts from the value the line names."""

from __future__ import annotations

import logging
from pathlib import Path

from gateway.cli import main
from gateway.greenhouse import load_greenhouse
from gateway.model import build_model
from gateway.service.clock import WallClock
from gateway.service.config import load_config
from gateway.service.resources import prepare
from gateway.service.worker import Worker
from gateway.store.db import open_db
from gateway.store.keys import write_keys
from tests.gateway_harness import KEY

GH = load_greenhouse("biskra-prototype")
MODEL = build_model("prototype", GH)
LO, HI = MODEL.bounds(GH)
J = MODEL.names.index("c_solar")


def _files(tmp_path: Path, c_solar: float) -> tuple[Path, Path]:
    """A gateway.toml naming a params file (c_solar as given, the others mid-box) and its keys."""
    write_keys(tmp_path / "keys.txt", {7: KEY})
    values = {n: float(0.5 * (a + b)) for n, a, b in zip(MODEL.names, LO, HI, strict=True)}
    values["c_solar"] = c_solar
    params = tmp_path / "north-params.toml"
    params.write_text('model = "prototype"\n[params]\n'
                      + "".join(f"{n} = {v!r}\n" for n, v in values.items()))
    cfg = tmp_path / "gw.toml"
    cfg.write_text('[gateway]\nfarm = "f1"\ndb = "gw.db"\nkeys = "keys.txt"\n[[greenhouse]]\n'
                   'name = "north"\ngreenhouse = "biskra-prototype"\nmodel = "prototype"\n'
                   'inside = 7\nparams = "north-params.toml"\n')
    return cfg, params


def _line(cfg: Path, params: Path, value: str) -> str:
    return (f"{cfg}: greenhouse[1].params (north): {params}: params.c_solar = {value} is outside "
            f"its hard box [{LO[J]:g}, {HI[J]:g}] (the model's, or the greenhouse's [parameters] "
            f"bounds): the estimator uses {HI[J]:g}")


def test_check_warns_naming_greenhouse_file_key_box_and_value_and_accepts(tmp_path, capsys):
    cfg, params = _files(tmp_path, 1e9)  # a hand edit: calibrate never writes this
    assert main(["run", "--config", str(cfg), "--check"]) == 0
    out, err = capsys.readouterr()
    assert err.splitlines() == [f"warning: {_line(cfg, params, '1e+09')}"]
    assert f"{cfg}: ok: farm f1, 1 greenhouse(s)" in out
    assert not (tmp_path / "gw.db").exists()


def test_check_says_nothing_of_values_inside_the_box(tmp_path, capsys):
    cfg, _ = _files(tmp_path, float(HI[J]))  # on the edge is inside
    assert main(["run", "--config", str(cfg), "--check"]) == 0
    assert capsys.readouterr().err == ""


def test_the_service_logs_it_once_and_starts_from_the_value_named(tmp_path, caplog):
    cfg, params = _files(tmp_path, -3.0)
    resources = prepare(load_config(cfg))
    assert resources[0].warnings == (_line(cfg, params, "-3").replace(f"uses {HI[J]:g}",
                                                                      f"uses {LO[J]:g}"),)
    worker = Worker(load_config(cfg), resources, WallClock(), lambda s: None, publish=False)
    conn = open_db(tmp_path / "gw.db")
    try:
        with caplog.at_level(logging.INFO, logger="serra.gateway"):
            worker._setup(conn)
    finally:
        conn.close()
    said = [r for r in caplog.records if "outside its hard box" in r.getMessage()]
    assert [(r.levelname, r.getMessage()) for r in said] == [("WARNING", resources[0].warnings[0])]
    assert worker.pipelines[0].est.theta0[J] == LO[J]  # what the line says is used
