"""Live gateway bench (issue 9): packet → publish latency with one kit, beside bare Zenoh
put → callback and the kit's own send → ack on the same run; the gateway's RSS with the
estimator, zenoh and onnxruntime loaded, beside a bare interpreter importing the same libraries;
CPU with 1 kit and with 100 kits (100 greenhouses, one estimator each) as a fraction of one core
at real time.

    python tests/bench/gateway.py          # writes bench/results/gateway.json

The gateway runs as a real subprocess on a scaled clock (docs/gateway.md): the latency run at
300× puts its estimator through 300 minutes per wall minute, a harder load than one kit in
service. CPU at real time = CPU seconds / (wall seconds × scale).
"""

from __future__ import annotations

import json
import os
import select
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))
import zenoh  # noqa: E402
from _common import no_arguments, write_result  # noqa: E402

from gateway.publish import zconfig  # noqa: E402
from gateway.vsensor.ort import telemetry_off  # noqa: E402
from tests.gateway_harness import EPOCH, GatewayProcess, PyKit, sim_trace, write_config  # noqa: E402
from training.kitsim import KitClock  # noqa: E402

telemetry_off()  # the gateway and bare interpreters this bench starts import onnxruntime

LAUNCH_WITH_ONNX = """
import sys, numpy as np
import onnxruntime as ort
sys.argv = ["gateway", "run", "--config", sys.argv[1]]
model = {model!r}
if model:
    sess = ort.InferenceSession(model, providers=["CPUExecutionProvider"])
    feeds = {{i.name: np.zeros([d if isinstance(d, int) else 1 for d in i.shape], np.float32)
              for i in sess.get_inputs()}}
    sess.run(None, feeds)
from gateway.cli import main
raise SystemExit(main(sys.argv[1:]))
"""

BARE = """
import sys, time, numpy, zenoh, onnxruntime as ort
s = zenoh.open(zenoh.Config())
model = {model!r}
if model:
    sess = ort.InferenceSession(model, providers=["CPUExecutionProvider"])
print("ready", flush=True)
sys.stdin.readline()
s.close()
"""


def onnx_model(folder: Path) -> tuple[str, str]:
    """A model for onnxruntime to load: the shipped virtual sensor if there is one, else a small
    MLP (16-30-20-1) built with onnx.helper, else none (onnxruntime imported only)."""
    shipped = sorted(p for d in ("gateway", "training") for p in (ROOT / d).glob("**/*.onnx"))
    if shipped:
        return str(shipped[0]), f"shipped {shipped[0].relative_to(ROOT)}"
    try:
        import numpy as np
        import onnx
        from onnx import TensorProto, helper, numpy_helper
    except ImportError:
        return "", "onnxruntime imported, no model (onnx not installed)"
    rng = np.random.default_rng(0)
    nodes, inits, prev = [], [], "x"
    for i, (a, b) in enumerate(((16, 30), (30, 20), (20, 1))):
        inits += [numpy_helper.from_array(rng.normal(size=(a, b)).astype(np.float32), f"w{i}"),
                  numpy_helper.from_array(np.zeros(b, np.float32), f"b{i}")]
        nodes += [helper.make_node("Gemm", [prev, f"w{i}", f"b{i}"], [f"h{i}"])]
        prev = f"h{i}"
        if i < 2:
            nodes.append(helper.make_node("Tanh", [prev], [f"t{i}"]))
            prev = f"t{i}"
    graph = helper.make_graph(nodes, "mlp", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 16])],
                              [helper.make_tensor_value_info(prev, TensorProto.FLOAT, [1, 1])], inits)
    path = folder / "mlp.onnx"
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), path)
    return str(path), "a 16-30-20-1 MLP built with onnx.helper (no shipped model yet)"


def proc_stats(pid: int) -> dict[str, float]:
    status = Path(f"/proc/{pid}/status").read_text()
    rss = {k: int(v.split()[0]) / 1024 for k, v in (line.split(":", 1) for line in status.splitlines())
           if k in ("VmRSS", "VmHWM")}
    f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    tick = os.sysconf("SC_CLK_TCK")
    return {"rss_mb": rss["VmRSS"], "peak_rss_mb": rss["VmHWM"],
            "cpu_s": (int(f[11]) + int(f[12])) / tick}


def pct(values: list[float], q: float) -> float:
    v = sorted(values)
    return v[min(len(v) - 1, int(round(q / 100 * (len(v) - 1))))]


def zenoh_floor(n: int = 300) -> dict[str, float]:
    """Bare put → callback latency between two sessions over TCP loopback [ms]."""
    before = zconfig.listening_ports()
    a = zenoh.open(zconfig.build(listen=["tcp/127.0.0.1:0"]))
    (ep,) = zconfig.resolve_listen(["tcp/127.0.0.1:0"], before)
    b = zenoh.open(zconfig.build(connect=[ep]))
    got: dict[int, float] = {}
    ev = threading.Event()

    def cb(s) -> None:
        got[int(s.payload.to_string())] = time.monotonic()
        ev.set()

    sub = b.declare_subscriber("bench/x", cb)
    pub = a.declare_publisher("bench/x", congestion_control=zenoh.CongestionControl.BLOCK)
    while not pub.matching_status.matching:
        time.sleep(0.01)
    lat = []
    for i in range(n):
        ev.clear()
        t0 = time.monotonic()
        pub.put(str(i))
        ev.wait(5)
        lat.append((got.get(i, t0 + 5) - t0) * 1000)
        time.sleep(0.005)
    sub.undeclare()
    b.close()
    a.close()
    return {"p50_ms": statistics.median(lat), "p99_ms": pct(lat, 99), "n": n}


class TimedKit(PyKit):
    def __init__(self, *a: Any, **k: Any) -> None:
        super().__init__(*a, **k)
        self.first_sent: dict[int, float] = {}
        self.ack_at: dict[int, float] = {}

    def send_due(self, addr):  # type: ignore[override]
        before = set(self.unacked)
        n = super().send_due(addr)
        now = time.monotonic()
        for seq in set(self.unacked) - before:
            self.first_sent[seq] = now
        return n

    def read_acks(self) -> None:
        before = set(self.acked)
        super().read_acks()
        now = time.monotonic()
        for seq in self.acked - before:
            self.ack_at.setdefault(seq, now)


def latency_run(folder: Path, model: str, seconds: float = 60.0, scale: float = 300.0) -> dict:
    """One kit at ``scale``: packet sent → its measurement/inside received by a subscriber."""
    clock = KitClock(scale, EPOCH)
    cfg = write_config(folder, anchor=clock.anchor, scale=scale, status_every_s=300)
    launcher = folder / "launch.py"
    launcher.write_text(LAUNCH_WITH_ONNX.format(model=model))
    gw = GatewayProcess(cfg)
    gw.argv = [sys.executable, str(launcher), str(cfg)]  # onnxruntime loaded, as with a vsensor
    gw.start()
    got: dict[int, float] = {}
    s = zenoh.open(zconfig.build(connect=[gw.zenoh]))
    sub = s.declare_subscriber(
        "serra/f1/north/measurement/inside",
        lambda smp: got.setdefault(json.loads(smp.payload.to_string())["kitRecord"]["value"]["seq"],
                                   time.monotonic()))
    kit = TimedKit(7, sim_trace(), clock.now)
    try:
        t_end = time.monotonic() + seconds
        stats0 = proc_stats(gw.proc.pid)
        while time.monotonic() < t_end:
            kit.send_due(gw.udp)
            select.select([kit.sock], [], [], 0.002)
            kit.read_acks()
        stats1 = proc_stats(gw.proc.pid)
        deadline = time.monotonic() + 30
        while len(got) < kit.next - 1 and time.monotonic() < deadline:
            kit.pump(gw.udp)
    finally:
        sub.undeclare()
        s.close()
        gw.stop()
        kit.close()
    lat = [(got[q] - kit.first_sent[q]) * 1000 for q in got if q in kit.first_sent]
    ack = [(kit.ack_at[q] - kit.first_sent[q]) * 1000 for q in kit.ack_at if q in kit.first_sent]
    wall = seconds
    return {"records": len(lat), "scale": scale,
            "packet_to_publish_ms": {"p50": statistics.median(lat), "p99": pct(lat, 99),
                                     "max": max(lat)},
            "packet_to_ack_ms": {"p50": statistics.median(ack), "p99": pct(ack, 99)},
            "rss_mb": stats1["rss_mb"], "peak_rss_mb": stats1["peak_rss_mb"],
            "cpu_real_time_pct": 100 * (stats1["cpu_s"] - stats0["cpu_s"]) / (wall * scale)}


def bare_rss(model: str) -> float:
    p = subprocess.Popen([sys.executable, "-c", BARE.format(model=model)], stdin=subprocess.PIPE,
                         stdout=subprocess.PIPE, text=True)
    assert p.stdout is not None and p.stdin is not None
    p.stdout.readline()
    rss = proc_stats(p.pid)["rss_mb"]
    p.stdin.write("\n")
    p.stdin.close()
    p.wait(30)
    return rss


def drive(fleet: list[PyKit], addr: tuple[str, int], seconds: float) -> None:
    """Every kit sends what is due and reads its acks, for ``seconds``."""
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        for k in fleet:
            k.send_due(addr)
        select.select([k.sock for k in fleet], [], [], 0.01)
        for k in fleet:
            k.read_acks()


def fleet_run(folder: Path, kits: int, scale: float, seconds: float) -> dict:
    """``kits`` kits, one greenhouse each: the gateway's CPU as a fraction of one core at real time."""
    clock = KitClock(scale, EPOCH)
    ghs = "\n".join(f'[[greenhouse]]\nname = "g{d}"\ngreenhouse = "biskra-prototype"\n'
                    f'model = "prototype"\ninside = {d}\n' for d in range(1, kits + 1))
    cfg = write_config(folder, anchor=clock.anchor, scale=scale, devices=tuple(range(1, kits + 1)),
                       greenhouses=ghs, status_every_s=300)
    gw = GatewayProcess(cfg)
    gw.start(timeout=300)
    trace = sim_trace()
    fleet = [PyKit(d, trace, clock.now) for d in range(1, kits + 1)]
    s = zenoh.open(zconfig.build(connect=[gw.zenoh]))
    n = [0]
    sub = s.declare_subscriber("serra/**", lambda smp: n.__setitem__(0, n[0] + 1))
    try:
        drive(fleet, gw.udp, min(20.0, seconds / 3))  # estimators start, the backlog settles
        s0, m0 = proc_stats(gw.proc.pid), n[0]
        drive(fleet, gw.udp, seconds)
        s1, m1 = proc_stats(gw.proc.pid), n[0]
        behind = sum(len(k.unacked) for k in fleet)
    finally:
        sub.undeclare()
        s.close()
        gw.stop(timeout=120)
        for k in fleet:
            k.close()
    return {"kits": kits, "scale": scale, "wall_s": seconds,
            "cpu_real_time_pct": 100 * (s1["cpu_s"] - s0["cpu_s"]) / (seconds * scale),
            "messages_per_s_wall": (m1 - m0) / seconds, "rss_mb": s1["rss_mb"],
            "unacked_at_end": behind}


def run() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        model, model_note = onnx_model(tmp)
        floor = zenoh_floor()
        (tmp / "one").mkdir()
        one = latency_run(tmp / "one", model)
        bare = bare_rss(model)
        (tmp / "hundred").mkdir()
        hundred = fleet_run(tmp / "hundred", 100, scale=10.0, seconds=60.0)
    lat = one["packet_to_publish_ms"]
    summary = {
        "packet_to_publish_p50_ms": round(lat["p50"], 1),
        "packet_to_publish_p99_ms": round(lat["p99"], 1),
        "goal_p99_ms": 100, "p99_goal_met": lat["p99"] <= 100,
        "of_which_commit_and_ack_p50_ms": round(one["packet_to_ack_ms"]["p50"], 1),
        "bare_zenoh_put_to_callback_p50_ms": round(floor["p50_ms"], 2),
        "gateway_rss_mb": round(one["rss_mb"], 1),
        "bare_python_numpy_zenoh_onnxruntime_rss_mb": round(bare, 1),
        "goal_rss_mb": 120, "rss_goal_met": one["rss_mb"] <= 120,
        "onnx_model": model_note,
        "cpu_1_kit_pct_of_a_core": round(one["cpu_real_time_pct"], 2),
        "cpu_100_kits_pct_of_a_core": round(hundred["cpu_real_time_pct"], 1),
        "cpu_100_vs_1_kit": round(hundred["cpu_real_time_pct"] / max(one["cpu_real_time_pct"], 1e-9), 1),
    }
    return {"summary": summary, "one_kit": one, "hundred_kits": hundred, "zenoh_floor": floor}


if __name__ == "__main__":
    no_arguments(__doc__, "gateway")
    result = run()
    path = write_result("gateway", result)
    print(f"wrote {path}")
    print(json.dumps(result["summary"], indent=2))
