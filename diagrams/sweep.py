"""Thin script: one scenario over values of one field, on the Dask sweep
runner (drake_contact.app.sweep), and a table of the main metrics.

    python diagrams/sweep.py nn_styrofoam controller.nn.learning_rate \\
        1e-5 2e-5 5e-5 1e-4 --out out/sweep_lr [--seeds 0 1 2] [--workers 2]

For grids, seeds, maps and clusters, write a sweep file and use
``drake-contact sweep`` (README, "Parameter sweeps").
"""

import argparse
import sys

from drake_contact.app.sweep import Sweep, check_points, run_sweep, summary_lines
from drake_contact.errors import ScenarioError
from drake_contact.scenario import _yaml_load


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario")
    parser.add_argument("field", help="dotted scenario field, e.g. controller.nn.learning_rate")
    parser.add_argument("values", nargs="+", help="values (YAML: 1e-5, 7000.0, true, ...)")
    parser.add_argument("--out", required=True)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--workers", type=int)
    args = parser.parse_args()
    try:
        sweep = Sweep(description=f"{args.scenario}: {args.field}", scenario=args.scenario,
                      overrides=[], grid={args.field: [_yaml_load(v) for v in args.values]},
                      paired={}, seeds=args.seeds, maps=[])
        check_points(sweep)
    except ScenarioError as e:
        print(f"sweep.py: {e}", file=sys.stderr)
        sys.exit(2)
    result = run_sweep(sweep, args.out, workers=args.workers)
    print("\n".join(summary_lines(sweep, result)))
    print(f"{args.field:>28} seed status        contact  final RMSE (N)  stable")
    for row in result.rows:
        print(f"{row[args.field]!s:>28} {row['seed']:4d} {row['status']:<13} "
              f"{row.get('contact_time_s') or float('nan'):7.2f}  "
              f"{row.get('final_force_rmse_n') or float('nan'):14.2f}  {row.get('stable')}")


if __name__ == "__main__":
    main()
