"""Study: the sky the live gateway's forecasts see, against replay's (issue 10, noticed by fs).

Before commit 490fabd the estimator read the cloud fraction from a tracker carried sample to
sample (gateway/model/sky.py ``CloudTracker``) and replay's outlook blocks derived it per lead
time from the series of outlooks, while the live pipeline (gateway/service/pipeline.py
``_forecasts``) ran ``prepare_drivers`` on the one-hour block it forecast with, so its cloud was
read from that block alone: ``DEFAULT_CLOUD`` at night and until the block held 30 min of strong
sun. Both now hold the estimator's cloud at the start (gateway/estimate/horizon.py). This
rescores replays kept by ``tests/generality/forecasts.py --keep DIR`` (made before that commit)
with the outlook blocks' cloud (and the sky temperature made from it) replaced:

- ``block``: derived from each block alone, as the live pipeline did;
- ``held``: the estimator's cloud at the start, held over the horizon.

Never reads the held-out generator's replays. Writes a results file like ``forecasts.py``'s
(compare with ``--rescore`` of the same DIR: tests/generality/compare_forecasts.py).

    .venv/bin/python tests/generality/live_cloud.py out/fs/main-replays --cloud block \\
        --json out/fs/cloud-block.json
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from gateway.estimate.replay import HORIZONS, score_forecasts, steps_of  # noqa: E402
from gateway.model import sky  # noqa: E402
from gateway.model.drivers import site_of  # noqa: E402
from tests.generality.cases import Case, forecast_report  # noqa: E402
from tests.generality.generators import HELD_OUT  # noqa: E402


def recloud(res, how: str) -> None:
    """Replace the cloud (and T_sky) of ``res.ahead``'s blocks: ``block`` or ``held``."""
    a = res.ahead
    width = a.horizon + 1
    cloud = a.x["cloud"].reshape(-1, width).copy()
    if how == "block":
        i_glob = a.x["i_glob"].reshape(-1, width)
        step = np.timedelta64(int(round(res.dt)), "s")
        for b, s in enumerate(a.starts):
            t = res.time[s] + np.arange(width) * step
            cloud[b] = sky.cloud_fraction(t, i_glob[b], site_of(res.gh), res.dt)
    else:
        cloud[:, 1:] = cloud[:, :1]
    a.x["cloud"] = cloud.ravel()
    a.x["t_sky"] = sky.sky_temperature(a.x["t_out"], a.x.get("rh_out"), a.x["cloud"])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("keep", help="replays kept by forecasts.py --keep")
    ap.add_argument("--cloud", choices=("block", "held"), default="block")
    ap.add_argument("--json", required=True)
    a = ap.parse_args(argv)
    results = []
    for f in sorted(Path(a.keep).glob("*.pkl")):
        generator, window = f.stem.split("-", 1)
        if generator in HELD_OUT:
            continue
        res = pickle.loads(f.read_bytes())
        recloud(res, a.cloud)
        score_forecasts(res, steps_of(HORIZONS, res.dt))
        vented = any(t.name == "q_vent_control" for t in res.model.terms)
        case = Case("forecast", generator, window, model="prototype+vent_control" if vented else "prototype")
        results.append({"case": asdict(case), **forecast_report(res)})
    out = Path(a.json)
    out.write_text(json.dumps({"meta": {"cloud": a.cloud}, "results": results}, indent=1) + "\n",
                   encoding="utf-8")
    print(f"wrote {out} ({len(results)} replays)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
