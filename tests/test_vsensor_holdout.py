"""``tune --holdout-groups``: leave one site x season out (training/vsensor/holdout_groups.py)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from gateway.greenhouse import load_greenhouse
from tests import vsensor_data as vd
from training.vsensor import holdout_groups as hg


def test_groups_are_site_and_season_of_the_corpus_names():
    from training.vsensor.corpus import TRAIN

    groups = hg.file_groups([r.name for r in TRAIN])
    assert groups == {
        "almeria-winter": ["almeria-winter-controller", "almeria-winter-grower",
                           "almeria-early-winter-grower"],
        "almeria-summer": ["almeria-summer-grower", "almeria-summer-controller",
                           "almeria-late-summer-grower"],
        "almeria-autumn": ["almeria-autumn-grower"],
        "bleiswijk-autumn": ["bleiswijk-autumn-controller", "bleiswijk-autumn-grower",
                             "bleiswijk-late-autumn-grower"],
        "twonode": ["twonode-bleiswijk-autumn"]}
    assert hg.group_of("biskra-spring-grower") == "biskra-spring"
    assert [hg.vents_of(s) for s in ("a-summer-grower", "twonode-bleiswijk-autumn")] == [
        "grower", "controller"]


def test_a_fold_fits_on_the_other_groups_and_scores_the_whole_held_out_files(tmp_path, capsys):
    """Two one-file groups: each fold's figure is the closed loop, over the whole held-out file,
    of the PCA-NARX fitted (standardisation and PCA included) on the other file alone; with
    ``--clamp-inputs`` the same networks also scored with the inputs clamped to the padded
    ranges of that fit's training rows (the ranges its written model would carry); every held-out
    file's mean signed error (sensor − reference) in the log and the printed table."""
    from training.vsensor import fit
    from training.vsensor.cli import main
    from training.vsensor.dataset import build_segment
    from training.vsensor.train import prepare_segments, upper_limits

    gh = load_greenhouse(vd.GREENHOUSE)
    paths = [tmp_path / "almeria-summer-grower.csv", tmp_path / "bleiswijk-autumn-controller.csv"]
    cache, log = tmp_path / "cache", tmp_path / "tune.jsonl"
    cache.mkdir()
    for src, dst in zip(vd.train_files(), paths, strict=True):
        shutil.copy(src, dst)
        # The replays the vsensor tests share (the tiny sensor's, in this worker's cache), under
        # the fold's file names: a cache entry is named <stem>-<key of the CSV's content,
        # greenhouse, kind, settings, seed, code>, so the same content under another name is the
        # same entry; tune reads them instead of replaying both files again.
        build_segment(src, gh, "almeria", vd.workdir() / "cache", vd.TINY, 0)
        for entry in (vd.workdir() / "cache").glob(f"{src.stem}-*.npz"):
            shutil.copy(entry, cache / entry.name.replace(src.stem, dst.stem, 1))
    sets = [a for k, v in vd.TINY.items() for n, x in v.items() for a in ("--set", f"{k}.{n}={x}")]
    assert main(["tune", "--data", *map(str, paths), "--greenhouse", vd.GREENHOUSE, "--model",
                 "almeria", "--cache", str(cache), *sets, "--hidden", "8,8", "--epochs", "6",
                 "--rounds", "1", "--ensemble", "2", "--own-feedback", "--holdout-groups",
                 "--clamp-inputs", "--log", str(log)]) == 0
    printed = capsys.readouterr().out
    got = json.loads(log.read_text())
    folds = {f["group"]: f for f in got["folds"]}
    assert list(folds) == ["almeria-summer", "bleiswijk-autumn"]
    assert folds["almeria-summer"]["trained_on"] == ["bleiswijk-autumn-controller"]
    assert folds["almeria-summer"]["scores"]["controller"] is None
    assert folds["bleiswijk-autumn"]["scores"]["grower"] is None

    segs = [build_segment(p, gh, "almeria", cache, vd.TINY, 0) for p in paths]
    prep = prepare_segments([segs[1]], gh, "almeria", 0, 0.90)
    net, _ = fit.fit_ensemble("pca_narx", prep.split, prep.mean, prep.std, prep.loadings, [0, 1],
                              (8, 8), 6, 1, 6)
    held = fit.Split([segs[0]], upper_limits([segs[0]], gh, "almeria"), [0])
    lo, hi = prep.input_bounds()
    assert np.any((segs[0].inputs < lo) | (segs[0].inputs > hi))  # the clamp acts here
    for key, sims in (("scores", fit.simulate(net, held)),
                      ("own", fit.simulate_own_feedback(net, held)),
                      ("clamped", fit.simulate(net, held, (lo, hi))),
                      ("own_clamped", fit.simulate_own_feedback(net, held, (lo, hi)))):
        ref = segs[0].flow
        ok = np.isfinite(ref)
        assert ok.sum() == len(ref) - 60  # the whole file but its first hour
        mae = float(np.mean(np.abs(sims[0][ok] - ref[ok])))
        s = folds["almeria-summer"][key]["grower"]
        assert s["mae"] == pytest.approx(mae, rel=1e-12)
        assert s["pct_range"] == pytest.approx(100 * mae / np.ptp(ref[ok]), rel=1e-12)
        assert folds["almeria-summer"][key]["all"]["mae"] == s["mae"]
        signed = float(np.mean(sims[0][ok] - ref[ok]))
        assert folds["almeria-summer"]["signed_by_file"][key] == {
            "almeria-summer-grower": pytest.approx(signed, rel=1e-12, abs=1e-12)}
        if key == "own":  # the printed table's figure (--own-feedback: members on their own past)
            assert f"almeria-summer-grower {signed:+.3f} |" in printed
    assert folds["almeria-summer"]["clamped"]["all"]["mae"] != folds["almeria-summer"]["scores"][
        "all"]["mae"]
    clamped = {g: f["clamped"]["all"]["mae"] for g, f in folds.items()}
    assert got["clamped"]["criterion"] == pytest.approx(sum(clamped.values()) / 2)
    assert got["own_feedback_clamped"]["grower_mae"] == pytest.approx(
        folds["almeria-summer"]["own_clamped"]["all"]["mae"])
    pct = {g: f["own"]["all"]["pct_range"] for g, f in folds.items()}
    mae = {g: f["own"]["all"]["mae"] for g, f in folds.items()}
    own = got["own_feedback"]
    assert got["headline"] == "own_feedback"
    assert own["grower_pct"] == pytest.approx(pct["almeria-summer"])
    assert own["controller_mae"] == pytest.approx(mae["bleiswijk-autumn"])
    assert own["criterion"] == pytest.approx((mae["almeria-summer"] + mae["bleiswijk-autumn"]) / 2)
    assert own["criterion_pct"] == pytest.approx(
        (pct["almeria-summer"] + pct["bleiswijk-autumn"]) / 2)
    with pytest.raises(ValueError, match="needs files inside and outside"):
        hg.run_fold("almeria-summer", [segs[0]], gh, "almeria", 0, 0.9, (), lambda *a: None)



def test_score_gives_the_held_out_figures_of_each_sensor(capsys):
    """``score``: written sensors side by side on cached replays, as ``train --test`` scores."""
    from gateway.vsensor.batch import baseline_paths
    from training.vsensor.cli import main
    from training.vsensor.dataset import build_segment
    from training.vsensor.heldout import score_segment

    gh = load_greenhouse(vd.GREENHOUSE)
    model = vd.tiny_model()
    arx = baseline_paths(model)["linear_arx"]
    sets = [a for k, v in vd.TINY.items() for n, x in v.items() for a in ("--set", f"{k}.{n}={x}")]
    assert main(["score", "--sensor", str(model), str(arx), "--data", str(vd.test_file()),
                 "--greenhouse", vd.GREENHOUSE, "--model", "almeria", "--cache",
                 str(vd.workdir() / "cache"), *sets, "--json"]) == 0
    got = json.loads(capsys.readouterr().out)["test-grower"]
    seg = build_segment(vd.test_file(), gh, "almeria", vd.workdir() / "cache", vd.TINY)
    want = score_segment(seg, {"pca_narx": model, "linear_arx": arx}, gh, "almeria")
    assert got[str(model)]["flow"]["mae"] == pytest.approx(want["pca_narx"]["flow"]["mae"])
    assert got[str(arx)]["flow_error_pct"] == pytest.approx(want["linear_arx"]["flow_error_pct"])
    assert got[str(model)]["flow"]["mae"] != got[str(arx)]["flow"]["mae"]
