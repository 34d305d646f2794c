"""Study: the diagnosis and the forecasts on a heated house (a thermostat the kit does not see).

Most commercial glasshouses are heated, and the kit reads only the air: a heating pipe that
holds the air at a setpoint is invisible to it. The two-node house (tests/twonode.py, a
development generator) is run with its ``thermostat`` (heating to ``--setpoint`` °C, from the
first sample: nothing changes during the record) and without, on the suite's autumn and winter
windows, written as the suite writes its kit CSVs (5-minute rows, kit columns only). Each is
given to ``gateway.diagnose.diagnose`` (``prototype``, the suite's call) and to ``replay``
(``prototype+vent_control``, the live default) at the suite's 300 s step; printed: the base's
held-out free-run MAE beside persistence, the first finding, and the 15/30/60-min MAE of the
published forecast (``corrected``) beside persistence and the ARX baseline, day 1 left out.

    nice -n 5 .venv/bin/python tests/generality/heated_study.py [--setpoint 12] [--json out.json]
    nice -n 5 .venv/bin/python tests/generality/heated_study.py --no-diagnosis \
        --forecast-models prototype+vent_control,prototype+vent_control+heating   # docs/effects.md
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from tests.generality import generators as gen
from tests.generality.cases import FORECAST_MODEL, MODEL, forecast_report
from tests.generality.windows import load_window

WINDOWS = ("autumn", "winter")


def kit_data(window: str, setpoint: float | None, seed: int = 1) -> gen.KitData:
    """The two-node house on ``window``, heated to ``setpoint`` from the first sample (None:
    unheated, the suite's effect-free case)."""
    w = load_window(window)
    if setpoint is None:
        return gen.generate("twonode", w, "none", seed)
    return gen.generate("twonode", w, "thermostat", seed, change_day=0.0, amount=setpoint)


def run(window: str, setpoint: float | None, forecast_model: str = FORECAST_MODEL,
        diagnosis: bool = True) -> dict:
    from gateway.diagnose import diagnose, to_json
    from gateway.estimate.replay import replay
    from gateway.model import build_model
    from gateway.series import load_series

    data = kit_data(window, setpoint)
    gh = data.greenhouse()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "kit.csv"
        data.write_csv(path)
        j = None
        if diagnosis:
            model = build_model(MODEL, gh)
            series = load_series(str(path), step=gen.ROW_S, required=model.requires)
            j = to_json(diagnose(series, gh, model))
        fmodel = build_model(forecast_model, gh)
        fc = forecast_report(replay(fmodel, load_series(str(path), step=gen.ROW_S,
                                                        required=fmodel.requires), gh))
    t_in = data.columns["t_in"]
    return {
        "window": window, "setpoint": setpoint, "t_in_mean": float(t_in.mean()),
        "t_in_min": float(t_in.min()),
        "base": j["before"]["free_run"]["mae"] if j else None,
        "persistence": j["persistence"]["free_run"]["mae"] if j else None,
        "finding": (j["findings"][0]["effect"] if j["findings"] else None) if j else None,
        "forecast_model": forecast_model,
        "forecast": {h: {k: fc["horizons"][h][k]["mae"] for k in ("corrected", "persistence", "arx",
                                                                 "corrected_outlook", "adaptive")}
                     for h in fc["horizons"]},
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--setpoint", type=float, default=12.0, help="heating setpoint [°C] (12)")
    ap.add_argument("--windows", default=",".join(WINDOWS), help="comma-separated (autumn,winter)")
    ap.add_argument("--forecast-models", default=FORECAST_MODEL,
                    help=f"comma-separated models replayed for the forecasts ({FORECAST_MODEL}; "
                         "e.g. also prototype+vent_control+heating)")
    ap.add_argument("--no-diagnosis", action="store_true", help="the forecasts only")
    ap.add_argument("--json", help="write the rows here too")
    args = ap.parse_args(argv)
    rows = []
    for window in args.windows.split(","):
        for sp in (None, args.setpoint):
            for i, fm in enumerate(args.forecast_models.split(",")):
                r = run(window, sp, fm, diagnosis=not args.no_diagnosis and i == 0)
                rows.append(r)
                _print_row(window, sp, r)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


def _print_row(window: str, sp: float | None, r: dict) -> None:
    f = r["forecast"]
    diag = (f"base {r['base']:.3f} K, persistence {r['persistence']:.3f} | first finding "
            f"{r['finding']} | " if r["base"] is not None else "")
    print(f"{window:7s} {'unheated' if sp is None else f'heated {sp:g} °C':14s} "
          f"T_in mean/min {r['t_in_mean']:.2f}/{r['t_in_min']:.1f} °C | {diag}"
          f"{r['forecast_model']}: corrected / outlook / persistence / ARX at "
          + ", ".join(f"{h}: {f[h]['corrected']:.3f}/{f[h]['corrected_outlook']:.3f}/"
                      f"{f[h]['persistence']:.3f}/{f[h]['arx']:.3f}" for h in f), flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
