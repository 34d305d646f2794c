"""``python -m training demo`` (``make demo``): the offline loop on shipped data.

1. The reference simulator (training/simulate) grows 6 days of an Almería-type greenhouse on
   the shipped Bleiswijk weather, with an effect nobody declares: the cover is whitened
   (transmission × 0.5) on day 4.
2. ``calibrate`` fits the almeria model on the first 2 days (RSBA, thesis settings).
3. ``replay`` runs the online estimator over the 6 days as the live gateway would, beside the
   constant-parameter model and persistence, and plots it.
4. ``diagnose`` looks for what the model lacks and reports it with the error before and after.

Everything lands in ``--out`` (default ``out/demo``): the CSV and its truth, params.toml,
replay.png, predictions.csv, and the diagnosis report. It lives in training/ because it needs
the simulator, which the gateway wheel does not carry; steps 2–4 are the gateway's own commands.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

EFFECT = "cover_transmission@2009-10-29T10:00:factor=0.5"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="end-to-end offline run on shipped data: simulate → calibrate → replay → diagnose",
        description=__doc__.split("\n\n")[0].replace("``", "")
        + " Steps: simulate, calibrate, replay, diagnose.",
    )
    p.add_argument("--out", default="out/demo", metavar="DIR", help="output folder (out/demo)")
    p.add_argument("--days", type=float, default=6.0, help="days to simulate (6)")
    p.add_argument("--seed", type=int, default=1, help="simulator and swarm seed (1)")
    p.set_defaults(func=run)


def _step(title: str) -> float:
    print(f"\n== {title}", flush=True)
    return time.perf_counter()


def run(args: argparse.Namespace) -> int:
    from gateway.cli import main as gateway_main
    from training.simulate import simulate
    from training.simulate.weather import BLEISWIJK_LATITUDE, BLEISWIJK_LONGITUDE

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    data = out / "almeria.csv"
    t0 = _step(f"1/4 simulate {args.days:g} days of an Almería-type greenhouse on Bleiswijk weather")
    result = simulate("almeria", "bleiswijk", start="2009-10-26", days=args.days,
                      effects=[EFFECT], seed=args.seed)
    result.write(data)
    print(f"wrote {data} (+ truth) in {time.perf_counter() - t0:.1f} s; undeclared effect: {EFFECT}")
    # the weather is Bleiswijk's: the sun (and with it the cloudiness the sky temperature is read
    # from) is computed there, not at the preset's Almería site
    common = ["--data", str(data), "--greenhouse", "almeria-palmerillas", "--model", "almeria",
              "--site", f"{BLEISWIJK_LATITUDE},{BLEISWIJK_LONGITUDE}"]
    params = out / "params.toml"
    _step("2/4 calibrate the almeria model on the first 2 days (RSBA), validate on the rest")
    code = gateway_main(["calibrate", *common, "--algorithm", "rsba", "--seed", str(args.seed),
                         "--calibrate-on", "2009-10-26/2009-10-28", "--out", str(params)])
    if code:
        return code
    _step("3/4 replay: the online estimator sample by sample, vs constant parameters and persistence")
    code = gateway_main(["replay", *common, "--params", str(params), "--seed", str(args.seed),
                         "--out", str(out / "predictions.csv"), "--plot", str(out / "replay.png")])
    if code:
        return code
    _step("4/4 diagnose: residual → effect → error before and after, on held-out data")
    code = gateway_main(["diagnose", *common, "--seed", str(args.seed), "--report",
                         str(out / "diagnosis")])
    if code:
        return code
    print(f"\nall outputs in {out}/ (replay.png, diagnosis/report.md)", file=sys.stderr)
    return 0
