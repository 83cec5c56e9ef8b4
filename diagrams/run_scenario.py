"""Thin script: simulate one scenario and write its logs and figures.

    python diagrams/run_scenario.py push_constant --out out/push_constant [--set k=v ...]

Same as ``drake-contact run``; kept as the example of driving the library from
a script (load a scenario, build the diagram, simulate, save).
"""

import argparse

from drake_contact.app.runner import run, terminal_progress
from drake_contact.scenario import load_scenario


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario")
    parser.add_argument("--out", required=True)
    parser.add_argument("--set", action="append", default=[])
    args = parser.parse_args()
    scenario = load_scenario(args.scenario, args.set)
    result = run(scenario, args.out, progress=terminal_progress())
    print(result.status, {k: v for k, v in result.metrics.items() if not isinstance(v, dict)})


if __name__ == "__main__":
    main()
