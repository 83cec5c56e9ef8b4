"""Benchmark: µs per simulated plant step and real-time factor of a scenario.

    python diagrams/benchmark.py [SCENARIO] [--duration S] [--repeat N] [--set k=v ...]

Builds the diagram once per repeat, simulates ``duration`` seconds without
figures, and prints the best wall time, µs/step, real-time factor and the
process's peak resident memory. Not a test: timings depend on the machine.
"""

import argparse
import resource
import tempfile

from drake_contact.runner import run
from drake_contact.scenario import load_scenario


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="?", default="push_constant")
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--set", action="append", default=[])
    args = parser.parse_args()
    scenario = load_scenario(args.scenario, args.set, duration=args.duration)
    best = None
    for _ in range(args.repeat):
        with tempfile.TemporaryDirectory() as out:
            metrics = run(scenario, out, figures=False).metrics
        if best is None or metrics["wall_time_s"] < best["wall_time_s"]:
            best = metrics
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"{args.scenario}: {best['simulated_time_s']:.1f} s simulated, "
          f"plant step {scenario.arm.time_step * 1e3:g} ms: "
          f"{best['us_per_step']:.1f} us/step, real-time factor {best['realtime_factor']:.2f}, "
          f"wall {best['wall_time_s']:.2f} s (best of {args.repeat}), "
          f"peak RSS {peak_mib:.0f} MiB")


if __name__ == "__main__":
    main()
