"""Virtual ventilation sensor bench: time per step, memory with the model loaded, training time.

(a) onnxruntime, one thread: ``session.run`` of each shipped PCA-NARX on one step (u 1×6×F,
    y_past 1×5), and the whole ``VentSensor.step`` (filters, delays, flags, clamp) around it;
    goal ≤ 50 µs median. Both shipped sensors: ``almeria`` (the summary's top-level figures) and
    the kit's ``prototype`` (``kit_sensor``). Peer, same weights: scikit-learn's own
    ``MLPRegressor.predict`` on the one row (after the same standardisation and PCA in numpy),
    timed interleaved with (a). Side by side in the same rounds: the step's own graph call
    plain (``session.run`` with the sensor's feeds, ``step_call_plain``) against the IOBinding
    bound once to the same arrays (``binding.BoundRun``, ``step_call_bound``), and the whole
    step with ``io_binding=False`` (``vsensor_step_plain``) against the default bound sensor
    (``vsensor_step``); reported as ratios bound / plain (``bound_over_plain``), outputs checked
    bit-identical first.
(b) Resident memory of a gateway process that imports numpy and the gateway, before and after
    loading the sensor (onnxruntime's import dominates).
(c) Training time of ``training.vsensor.train`` on two 2-day simulator files with the small
    estimator budget of the tests (replays and fitting reported apart); the full training on
    the corpus is timed by ``python -m training.vsensor train`` itself (docs/vsensor.md).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # not tests/bench/gateway.py
from _common import no_arguments, one_core, write_result  # noqa: E402

one_core()

import numpy as np  # noqa: E402

from gateway.greenhouse import load_greenhouse  # noqa: E402
from gateway.vsensor.binding import BoundRun  # noqa: E402
from gateway.vsensor.models import shipped_model  # noqa: E402

ROUNDS = 5
CALLS = 2000

_RSS = """
import resource, sys
def rss():
    return int(open('/proc/self/statm').read().split()[1]) * 4096 / 2**20
import numpy, gateway.vsensor.features
from gateway.greenhouse import load_greenhouse
before = rss()
from gateway.vsensor import VentSensor
from gateway.vsensor.models import shipped_model
s = VentSensor(shipped_model('almeria'), load_greenhouse('almeria-palmerillas'), 'almeria')
for _ in range(10):
    s.step({'t_in': 22, 't_out': 18, 'rh_in': 70, 'rh_out': 60, 'wind': 3}, {})
after = rss()
print(before, after, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
"""


def _per_call_us(fn, calls: int = CALLS) -> tuple[float, float]:
    """(wall, CPU) µs per call: on a shared machine the wall time includes waiting for the core."""
    t0, c0 = time.perf_counter_ns(), time.process_time_ns()
    for _ in range(calls):
        fn()
    return (time.perf_counter_ns() - t0) / calls / 1e3, (time.process_time_ns() - c0) / calls / 1e3


def _sklearn_peer(kind: str) -> tuple:
    """MLPRegressors holding the shipped network's weights, read back from the graph (one per
    ensemble member: ``m<j>_w<i>``; a single network: ``w<i>``)."""
    import re
    import warnings

    from onnx import load, numpy_helper
    from sklearn.neural_network import MLPRegressor

    model = load(str(shipped_model(kind)))
    w = {t.name: numpy_helper.to_array(t).astype(np.float64) for t in model.graph.initializer}
    prefixes = sorted({m.group(1) for k in w if (m := re.fullmatch(r"(m\d+_)?w\d+", k))},
                      key=lambda p: p or "")
    mlps = []
    for pre in prefixes:
        pre = pre or ""
        layers = sorted((k for k in w if re.fullmatch(rf"{pre}w\d+", k)),
                        key=lambda k: int(k[len(pre) + 1:]))
        mlp = MLPRegressor(hidden_layer_sizes=tuple(w[k].shape[1] for k in layers[:-1]),
                           activation="tanh", max_iter=1)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mlp.fit(np.zeros((4, w[layers[0]].shape[0])), np.zeros(4))
        mlp.coefs_ = [w[k] for k in layers]
        mlp.intercepts_ = [w[f"{pre}b{k[len(pre) + 1:]}"] for k in layers]
        mlps.append(mlp)
    return mlps, w


def timing(kind: str = "almeria") -> dict:
    from gateway.vsensor.ort import load

    ort = load()

    gh = load_greenhouse("almeria-palmerillas")  # the house both shipped sensors learnt
    from gateway.vsensor import VentSensor

    sensor = VentSensor(shipped_model(kind), gh, kind)
    plain_sensor = VentSensor(shipped_model(kind), gh, kind, io_binding=False)
    sess = sensor.session
    n_f = len(sensor.info.names)
    rng = np.random.default_rng(0)
    u = rng.normal(size=(1, 6, n_f)).astype(np.float32) * 0.1 + sensor.info.mean.astype(np.float32)
    k_h = sensor.histories  # K > 1: every member on its own past outputs
    yp = np.full((1, 5) if k_h == 1 else (1, k_h, 5), sensor.info.y0, dtype=np.float32)
    mlps, w = _sklearn_peer(kind)
    mean, std, pca = w["mean"], w["std"], w.get("pca")
    y_mean, y_std = float(w["y_mean"][0]), float(w["y_std"][0])
    target = sensor.info.meta.get("training_settings", {}).get("target_transform", "identity")
    to_t = {"identity": lambda y: y, "sqrt": lambda y: np.sqrt(np.maximum(y, 0.0)),
            "log1p": lambda y: np.log1p(np.maximum(y, 0.0))}[target]
    from_t = {"identity": lambda v: v, "sqrt": lambda v: np.maximum(v, 0.0) ** 2,
              "log1p": np.expm1}[target]

    def sk_step():
        z = (u[0].astype(np.float64) - mean) / std
        if pca is not None:
            z = z @ pca
        if k_h == 1:
            h = np.concatenate([z.reshape(-1), (to_t(yp[0]) - y_mean) / y_std])[None, :]
            return float(from_t(np.mean([m.predict(h)[0] for m in mlps]) * y_std + y_mean))
        flows = [from_t(m.predict(np.concatenate([z.reshape(-1), (to_t(yp[0, j]) - y_mean) / y_std])
                                  [None, :])[0] * y_std + y_mean) for j, m in enumerate(mlps)]
        return float(np.mean(flows))

    onnx_out = float(np.mean(sess.run(None, {"u": u, "y_past": yp})[0][0]))
    assert abs(onnx_out - sk_step()) < 1e-3 * max(1.0, abs(onnx_out)), "peer differs from the graph"
    bound = BoundRun(sess, k_h)
    call_plain, call_bound = lambda: plain_sensor._plain_run(u, yp), lambda: bound(u, yp)
    assert call_plain().tobytes() == call_bound().tobytes(), "bound run differs from session.run"
    meas = {"t_in": 22.0, "t_out": 18.0, "rh_in": 70.0, "rh_out": 60.0, "wind": 3.0}
    fluxes = {n: 0.0 for n in sensor.info.names[3:] if n.startswith("q_")}  # vpd_in: from meas
    rows = {"onnx_run": [], "step_call_plain": [], "step_call_bound": [], "vsensor_step_plain": [],
            "vsensor_step": [], "sklearn_predict": []}
    for _ in range(ROUNDS):  # interleaved: a busy neighbour hits them all alike
        rows["onnx_run"].append(_per_call_us(lambda: sess.run(None, {"u": u, "y_past": yp})))
        rows["step_call_plain"].append(_per_call_us(call_plain))
        rows["step_call_bound"].append(_per_call_us(call_bound))
        rows["vsensor_step_plain"].append(_per_call_us(lambda: plain_sensor.step(meas, fluxes)))
        rows["vsensor_step"].append(_per_call_us(lambda: sensor.step(meas, fluxes)))
        rows["sklearn_predict"].append(_per_call_us(sk_step, CALLS // 4))
    assert json.dumps(sensor.snapshot()) == json.dumps(plain_sensor.snapshot()), "steps differ"
    med = {k: float(np.median([w for w, _ in v])) for k, v in rows.items()}
    cpu = {k: float(np.median([c for _, c in v])) for k, v in rows.items()}
    ratios = {}  # bound / plain: median over rounds of the ratio within a round (wall, CPU)
    for name, bound_row, plain_row in (("step_call", "step_call_bound", "step_call_plain"),
                                       ("vsensor_step", "vsensor_step", "vsensor_step_plain")):
        for i, tag in ((0, ""), (1, "_cpu")):
            ratios[name + tag] = float(np.median([b[i] / p[i] for b, p in
                                                  zip(rows[bound_row], rows[plain_row], strict=True)]))
    return {"per_call_us_median_of_rounds": med, "cpu_us_median_of_rounds": cpu, "rounds": rows,
            "bound_over_plain": ratios,
            "sklearn_over_onnx_run_cpu": cpu["sklearn_predict"] / cpu["onnx_run"],
            "sklearn_over_onnx_run": med["sklearn_predict"] / med["onnx_run"],
            "sklearn_over_vsensor_step": med["sklearn_predict"] / med["vsensor_step"],
            "goal_us": 50.0, "onnxruntime": ort.__version__, "model": shipped_model(kind).name}


def memory() -> dict:
    out = subprocess.run([sys.executable, "-c", _RSS], capture_output=True, text=True, check=True)
    before, after, peak = (float(v) for v in out.stdout.split())
    return {"rss_gateway_mb": before, "rss_with_sensor_mb": after, "sensor_adds_mb": after - before,
            "peak_rss_mb": peak}


def training_time() -> dict:
    from threadpoolctl import threadpool_limits

    from training.simulate import PRESETS, simulate
    from training.simulate.control import GrowerVents
    from training.vsensor.train import train

    tiny = {"t_in": {"iterations": 2, "bats": 4}, "i_in": {"iterations": 2, "bats": 4}}
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for i, (start, grower) in enumerate((("2020-05-02", True), ("2020-07-20", False))):
            plant = PRESETS["almeria"]
            if grower:
                plant = plant.with_(controller=GrowerVents(seed=i))
            p = Path(tmp) / f"d{i}.csv"
            simulate(plant, "almeria", start, 2.0, seed=i).write(p)
            paths.append(str(p))
        gh = load_greenhouse("almeria-palmerillas")
        with threadpool_limits(1):
            r = train(paths, gh, "almeria", Path(tmp) / "m.onnx", Path(tmp) / "cache", tiny,
                      epochs=60, rounds=2)
    return {"data": "2 files x 2 days, estimator 4 bats x 2 iterations, 30-50-20, 60 epochs, 2 rounds",
            "seconds": {k: round(v, 2) for k, v in r.seconds.items()}}


def run() -> dict:
    t = timing("almeria")
    kit = timing("prototype")
    m = memory()
    tr = training_time()
    summary = {
        "onnx_run_us": t["per_call_us_median_of_rounds"]["onnx_run"],
        "vsensor_step_us": t["per_call_us_median_of_rounds"]["vsensor_step"],
        "sklearn_predict_us": t["per_call_us_median_of_rounds"]["sklearn_predict"],
        "sklearn_over_onnx_run": t["sklearn_over_onnx_run"],
        "sklearn_over_vsensor_step": t["sklearn_over_vsensor_step"],
        "cpu_us": t["cpu_us_median_of_rounds"],
        "sklearn_over_onnx_run_cpu": t["sklearn_over_onnx_run_cpu"],
        "goal_us": 50.0,
        "bound_over_plain": t["bound_over_plain"],
        "kit_sensor": {"model": kit["model"],
                       "bound_over_plain": kit["bound_over_plain"],
                       "onnx_run_us": kit["per_call_us_median_of_rounds"]["onnx_run"],
                       "vsensor_step_us": kit["per_call_us_median_of_rounds"]["vsensor_step"],
                       "sklearn_over_onnx_run": kit["sklearn_over_onnx_run"],
                       "cpu_us": kit["cpu_us_median_of_rounds"]},
        **m,
        "training_seconds": tr["seconds"],
    }
    return {"summary": summary, "timing": t, "timing_kit_sensor": kit, "memory": m, "training": tr}


if __name__ == "__main__":
    no_arguments(__doc__, "vsensor")
    result = run()
    path = write_result("vsensor", result)
    print(json.dumps(result["summary"], indent=2))
    print(f"wrote {path}")
