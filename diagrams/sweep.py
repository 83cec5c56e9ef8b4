"""Thin script: run one scenario over values of one field, in parallel
processes, and print a table of metrics.

    python diagrams/sweep.py nn_styrofoam controller.nn.learning_rate \\
        1e-5 2e-5 5e-5 1e-4 2e-4 5e-4 1e-3 --out out/sweep_lr

Each value runs into OUT/<field>=<value>/ (logs, metrics, no figures).
Columns: the run's status, contact time, force RMSE per 5 s window from
contact, adaptation time and, when present, the 10-20 s window RMSE.
"""

import argparse
import json
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from drake_contact.runner import run
from drake_contact.scenario import load_scenario


def _one(args):
    name, field, value, out, duration, seed = args
    scenario = load_scenario(name, [f"{field}={value}"], duration=duration, seed=seed)
    metrics = run(scenario, Path(out) / f"{field}={value}", figures=False).metrics
    return value, metrics


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario")
    parser.add_argument("field", help="dotted scenario field, e.g. controller.nn.learning_rate")
    parser.add_argument("values", nargs="+")
    parser.add_argument("--out", required=True)
    parser.add_argument("--duration", type=float)
    parser.add_argument("--seed", type=int)
    parser.add_argument("--jobs", type=int, default=os.cpu_count())
    args = parser.parse_args()
    jobs = [(args.scenario, args.field, v, args.out, args.duration, args.seed)
            for v in args.values]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        results = list(pool.map(_one, jobs))
    table = {}
    print(f"{args.field:>12} status      contact  windows RMSE (N)                 "
          "adapt (s)  RMSE window (N)")
    for value, m in results:
        windows = " ".join(f"{x:5.2f}" for x in m.get("force_rmse_windows_n", []))
        print(f"{value:>12} {m['status']:<10} {m.get('contact_time_s') or float('nan'):7.2f}  "
              f"{windows:<32} {m.get('adaptation_time_s') or float('nan'):8.1f}  "
              f"{m.get('force_rmse_n', float('nan')):6.2f}   {m.get('message', '')}")
        table[value] = m
    (Path(args.out) / "sweep.json").write_text(json.dumps(table, indent=2, sort_keys=True))


if __name__ == "__main__":
    main()
