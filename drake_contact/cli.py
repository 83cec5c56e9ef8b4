"""The ``drake-contact`` command (also ``python -m drake_contact``).

    drake-contact run SCENARIO --out DIR [--duration S] [--seed N] [--set k=v ...]
                      [--meshcat [--realtime-rate R]] [--record FILE.html]
    drake-contact reproduce [--quick] --out DIR [--jobs N]
    drake-contact list
    drake-contact bench [SCENARIO] [--duration S]

Bad input exits with status 2 and one line naming the field and its allowed
range; a diverged run exits with status 3 after writing its logs; Ctrl-C
exits with 130 after writing the logs (and, for reproduce, a partial report);
reproduce exits with 1 when a thesis result fails its tolerance.
"""

import argparse
import sys

from drake_contact.errors import ScenarioError

EXIT_BAD_INPUT = 2
EXIT_DIVERGED = 3
EXIT_FAILED = 1  # reproduce: a thesis result not reproduced
EXIT_INTERRUPTED = 130


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        # One line, status 2, like every other bad input.
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


def _build_parser():
    parser = _Parser(prog="drake-contact", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    run = commands.add_parser("run", help="simulate one scenario and write its logs")
    run.add_argument("scenario", help="a scenario file, or a bundled scenario's name")
    run.add_argument("--out", required=True, help="output folder")
    run.add_argument("--duration", type=float, help="simulated time (s)")
    run.add_argument("--seed", type=int, help="seed of every random source")
    run.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                     help="override a scenario field, e.g. environment.stiffness=6.2e4")
    run.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    run.add_argument("--no-baseline", action="store_true",
                     help="neural controller: skip the hybrid-only baseline run")
    run.add_argument("--meshcat", action="store_true",
                     help="show the arm, wall and contact force live in Meshcat (prints the URL)")
    run.add_argument("--realtime-rate", type=float, default=1.0, metavar="R",
                     help="with --meshcat: simulated s per wall s (default 1; 0 = unpaced)")
    run.add_argument("--record", metavar="FILE",
                     help="save a standalone HTML playback of the run (headless)")
    reproduce = commands.add_parser(
        "reproduce", help="run every thesis scenario; write the figures and a scored report")
    reproduce.add_argument("--out", required=True, help="output folder")
    reproduce.add_argument("--quick", action="store_true",
                           help="shorter long runs, no baselines (about 3 min on 2 cores)")
    reproduce.add_argument("--jobs", type=int, help="processes at a time (default: one per core)")
    commands.add_parser("list", help="list the bundled scenarios")
    bench = commands.add_parser(
        "bench", help="time the floor (plant, wall, joint physics) and a scenario; print the ratio")
    bench.add_argument("scenario", nargs="?", default="nn_styrofoam")
    bench.add_argument("--duration", type=float, help="simulated time of the scenario (s)")
    return parser


def _cmd_list(args):
    from drake_contact.resources import bundled_scenario_names
    from drake_contact.scenario import load_scenario
    for name in bundled_scenario_names():
        description = load_scenario(name).description.strip().splitlines()
        print(f"{name:28s} {description[0] if description else ''}")
    return 0


def _cmd_bench(args):
    from drake_contact.bench import bench
    from drake_contact.scenario import load_scenario
    bench(load_scenario(args.scenario, duration=args.duration))
    return 0


def _cmd_run(args):
    from drake_contact.runner import run, terminal_progress
    from drake_contact.scenario import load_scenario
    from drake_contact.visualization import check_record_path, new_meshcat
    scenario = load_scenario(args.scenario, args.set, duration=args.duration, seed=args.seed)
    if not args.realtime_rate >= 0:
        raise ScenarioError(f"--realtime-rate = {args.realtime_rate} is out of range: must be >= 0")
    meshcat = None
    if args.record:
        check_record_path(args.record)  # before a Meshcat URL is printed
    if args.meshcat:
        meshcat = new_meshcat()
        print(f"Meshcat: {meshcat.web_url()}", flush=True)
    result = run(scenario, args.out, progress=terminal_progress(), figures=not args.no_figures,
                 baseline=False if args.no_baseline else None, meshcat=meshcat, record=args.record,
                 realtime_rate=args.realtime_rate if args.meshcat else 0.0)
    m = result.metrics
    print(f"{result.status}: {m['simulated_time_s']:.3f} s simulated in {m['wall_time_s']:.2f} s "
          f"(real-time factor {m['realtime_factor']:.2f}, {m['us_per_step']:.1f} us/step); "
          f"peak force {m['peak_force_n']:.4g} N; wrote {args.out}"
          + (f" and {args.record}" if args.record else ""))
    if result.status == "diverged":
        print(f"drake-contact: {result.message}", file=sys.stderr)
        return EXIT_DIVERGED
    if result.status == "interrupted":
        print(f"drake-contact: {result.message}", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0


def _cmd_reproduce(args):
    from drake_contact.reproduce import reproduce
    if args.jobs is not None and args.jobs < 1:
        raise ScenarioError(f"--jobs = {args.jobs} is out of range: must be >= 1")
    rows, interrupted = reproduce(args.out, quick=args.quick, jobs=args.jobs,
                                  progress=lambda line: print(line, flush=True))
    failed = [r.experiment for r in rows if r.passed is not True]
    print(f"{len(rows) - len(failed)} of {len(rows)} thesis results pass"
          + (f"; not passing: {', '.join(failed)}" if failed else ""))
    if interrupted:
        print("drake-contact: interrupted; the report is partial", file=sys.stderr)
        return EXIT_INTERRUPTED
    return EXIT_FAILED if failed else 0


def main(argv=None) -> int:
    args = _build_parser().parse_args(argv)
    try:
        return {"run": _cmd_run, "list": _cmd_list, "bench": _cmd_bench,
                "reproduce": _cmd_reproduce}[args.command](args)
    except ScenarioError as e:
        print(f"drake-contact: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
