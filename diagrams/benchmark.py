"""Benchmark: µs per plant step of a scenario against the plant floor and the physics.

    python diagrams/benchmark.py [SCENARIO] [--duration S] [--repeat N] [--set k=v ...] [--profile]

The same measurement as ``drake-contact bench`` (see
:mod:`drake_contact.app.bench`), with scenario overrides, a repeat count and
the process's peak resident memory. Not a test: timings depend on the machine.
"""

import argparse
import resource

from drake_contact.app.bench import bench, load_bench_scenario, profile_scenario
from drake_contact.errors import ScenarioError


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="?", default="push_constant")
    parser.add_argument("--duration", type=float,
                        help="simulated time (s; default the scenario's, at most 20)")
    parser.add_argument("--repeat", type=int, default=2, help="runs per diagram (best is kept)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--profile", action="store_true",
                        help="also profile one run: us/step per Python system")
    args = parser.parse_args()
    try:
        scenario = load_bench_scenario(args.scenario, args.duration, args.set)
    except ScenarioError as e:
        parser.exit(2, f"{parser.prog}: {e}\n")
    print(bench(scenario, runs=args.repeat, scenario_runs=args.repeat, name=args.scenario).format())
    if args.profile:
        print()
        print(profile_scenario(scenario, name=args.scenario).format())
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak RSS {peak_mib:.0f} MiB")


if __name__ == "__main__":
    main()
