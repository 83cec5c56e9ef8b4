"""The ``drake-contact`` command (also ``python -m drake_contact``).

    drake-contact run SCENARIO --out DIR [--duration S] [--seed N] [--set k=v ...]
                      [--meshcat [--realtime-rate R]] [--record FILE.html]
                      [--graphviz FILE.dot|FILE.svg]
    drake-contact reproduce [--quick] --out DIR [--jobs N] [--seeds 0-2]
    drake-contact list
    drake-contact bench [SCENARIO] [--duration S] [--profile]
    drake-contact sweep SWEEP --out DIR [--workers N | --scheduler ADDRESS] [--quick]

Bad input exits with status 2 and one line naming the field and its allowed
range; a campaign (sweep, benchmark, faults, reproduce) first builds every
distinct configuration it will run, so a bad one exits with 2 the same way
before any run starts. A diverged run exits with status 3 after writing its
logs; Ctrl-C exits with 130 after writing the logs (and, for reproduce, a
partial report); sweep, benchmark and faults exit with 1 when a run failed
(raised, or its worker died each time), unless --allow-failures (a diverged
run is a result: exit 0); reproduce exits with 1 when a thesis result is not
as expected (one that stops reproducing, a documented deviation that now
passes, or one whose run failed or diverged).
"""

import argparse
import os
import sys
from pathlib import Path

# numpy's OpenBLAS starts worker threads that spin after each call. On a
# run's 3- to 36-vectors they never share work, yet they cost 9 % of a core
# beside each run (measured: nn_styrofoam, user CPU 4.12 s against 3.78 s for
# 3.9 s of wall time), which two runs on two cores fight over. One thread,
# unless the user chose; set before numpy loads, and inherited by the runs'
# processes (reproduce's, Dask's workers).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _return_freed_arrays_to_the_system():
    """glibc serves an allocation of 128 KiB or more by its own mmap, and
    frees it to the system, only until the first such free: then it raises
    that threshold (up to 32 MiB), and a long run's 4.8 MB columns, read
    by the metrics and figures one after the other, stay in the process's
    heap. Fixing the threshold returns each array when freed: a 600 s
    neural run with figures peaks at 300 MB instead of 313 (ru_maxrss).
    No per-step allocation is that large. Not glibc: nothing to do."""
    try:
        import ctypes
        M_MMAP_THRESHOLD = -3
        ctypes.CDLL("libc.so.6").mallopt(M_MMAP_THRESHOLD, 128 * 1024)
    except (OSError, AttributeError):
        pass


_return_freed_arrays_to_the_system()

from drake_contact.errors import ScenarioError  # noqa: E402
from drake_contact.app.campaign import DEFAULT_ENSEMBLE, MAX_ENSEMBLE  # noqa: E402

EXIT_BAD_INPUT = 2
EXIT_DIVERGED = 3
EXIT_FAILED = 1  # reproduce: a thesis result not as expected; a campaign: a run failed
EXIT_INTERRUPTED = 130


def _version() -> str:
    """The installed distribution's version (the source tree's when run
    from a checkout without an install)."""
    from importlib import metadata
    try:
        return metadata.version("drake_contact")
    except metadata.PackageNotFoundError:
        return "unknown (not installed)"


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        # One line, status 2, like every other bad input.
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


def _build_parser():
    parser = _Parser(prog="drake-contact",
                     description=__doc__.splitlines()[0].replace("``", ""))
    parser.add_argument("--version", action="version",
                        version=f"drake-contact {_version()}")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    run = commands.add_parser("run", help="simulate one scenario and write its logs")
    run.add_argument("scenario", help="a scenario file, or a bundled scenario's name")
    run.add_argument("--out", required=True, help="output folder")
    run.add_argument("--duration", type=float, help="simulated time (s)")
    run.add_argument("--seed", type=int, help="seed of every random source")
    run.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                     help="override a scenario field, e.g. environment.stiffness=6.2e4")
    run.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    baseline = run.add_mutually_exclusive_group()
    baseline.add_argument("--no-baseline", action="store_true",
                          help="neural controller: skip the hybrid-only baseline run")
    baseline.add_argument("--baseline-window", action="store_true",
                          help="neural controller: run the hybrid-only baseline only to 1 s "
                               "past the scoring window (enough for baseline_force_rmse_n)")
    run.add_argument("--meshcat", action="store_true",
                     help="show the arm, wall and contact force live in Meshcat (prints the URL)")
    run.add_argument("--realtime-rate", type=float, default=1.0, metavar="R",
                     help="with --meshcat: simulated s per wall s (default 1; 0 = unpaced)")
    run.add_argument("--record", metavar="FILE",
                     help="save a standalone HTML playback of the run (headless)")
    run.add_argument("--graphviz", metavar="FILE",
                     help="draw the scenario's diagram to FILE: Graphviz DOT text (.dot) or, "
                          "with Graphviz's dot installed, an SVG (.svg)")
    reproduce = commands.add_parser(
        "reproduce", help="run every thesis scenario; write the figures and a scored report")
    reproduce.add_argument("--out", required=True, help="output folder")
    reproduce.add_argument("--quick", action="store_true",
                           help="shorter long runs, no baselines (about 2 min on 2 idle cores)")
    reproduce.add_argument("--jobs", type=int,
                           help="local Dask workers, runs at a time (default: one per core)")
    _add_ensemble_argument(reproduce)
    reproduce.add_argument("--seeds", default="0-2",
                           help="seeds to score every result on, e.g. 0-2 (default) or 0,5")
    commands.add_parser("list", help="list the bundled scenarios")
    bench = commands.add_parser(
        "bench", help="time the plant floor, the physics (plant, wall, friction, tip "
                      "kinematics) and a scenario; print us/step and their ratios")
    bench.add_argument("scenario", nargs="?", default="nn_styrofoam",
                       help="a scenario file, or a bundled scenario's name (default nn_styrofoam)")
    bench.add_argument("--duration", type=float,
                       help="simulated time of every timed run (s; default the scenario's, "
                            "at most 20)")
    bench.add_argument("--profile", action="store_true",
                       help="also run the scenario once under cProfile: us/step per Python system")
    bench.add_argument("--ensemble", metavar="N,N,...",
                       help="also time ensembles of these sizes (e.g. 1,4,16,64): us per "
                            "environment-step, speed-up over one run alone, memory")
    sweep = commands.add_parser(
        "sweep", help="run a parameter sweep on a Dask cluster; write results.csv, maps, sweep.html")
    sweep.add_argument("sweep", help="a sweep file, or a bundled sweep's name")
    sweep.add_argument("--out", required=True, help="output folder (rerun it to resume)")
    _add_cluster_arguments(sweep)
    sweep.add_argument("--quick", action="store_true",
                       help="the sweep's short version (its quick: section)")
    benchmark = commands.add_parser(
        "benchmark", help="every controller on the same tasks and walls, on a Dask cluster; "
                          "write leaderboard.csv, .md, .html")
    benchmark.add_argument("--out", required=True, help="output folder (rerun it to resume)")
    benchmark.add_argument("--controllers", metavar="A,B,...",
                           help="contenders (default: the thesis's, the robust ones and every "
                                "installed controller but the push harness)")
    benchmark.add_argument("--identifiers", metavar="all|A,B,...",
                           help="also benchmark identifiers, side by side under nn_robust "
                                "(all: every one)")
    benchmark.add_argument("--suite", default="standard", help="quick or standard (default)")
    _add_cluster_arguments(benchmark)
    faults = commands.add_parser(
        "faults", help="every fault kind against the controllers, supervisor off and on, on a "
                       "Dask cluster; write faults.md, faults.csv, runs.csv")
    faults.add_argument("--out", required=True, help="output folder (rerun it to resume)")
    faults.add_argument("--controllers", metavar="A,B,...",
                        help="contenders (default: hybrid, nn, nn_robust, adaptive_hybrid)")
    faults.add_argument("--suite", default="standard", help="quick or standard (default)")
    _add_cluster_arguments(faults)
    return parser


def _add_cluster_arguments(command):
    """--workers N or --scheduler ADDRESS: where the Dask points run; and
    --allow-failures (these are the campaigns that exit 1 on a failed run)."""
    where = command.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int,
                       help="worker processes of a local cluster (default: one per core)")
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="a running Dask scheduler, e.g. tcp://10.0.0.5:8786")
    _add_ensemble_argument(command)
    command.add_argument("--allow-failures", action="store_true",
                         help="exit 0 even when runs failed (raised, or their worker died each "
                              "time it was tried); they are still counted and shown as failed. "
                              "Default: exit 1. A diverged run is a result and never fails "
                              "the command")


def _add_ensemble_argument(command):
    command.add_argument("--ensemble", type=int, metavar="N", default=DEFAULT_ENSEMBLE,
                         help="at most N environments simulated together in one diagram per "
                              "task, for points that share a controller and a duration "
                              f"(default {DEFAULT_ENSEMBLE}; 1: each point alone); the logs are "
                              "the same")


def _check_campaign_arguments(args):
    """One line, exit 2, for a bad --workers, --jobs or --ensemble."""
    for flag in ("workers", "jobs"):
        value = getattr(args, flag, None)
        if value is not None and value < 1:
            raise ScenarioError(f"--{flag} = {value} is out of range: must be >= 1")
    if not 1 <= args.ensemble <= MAX_ENSEMBLE:
        raise ScenarioError(f"--ensemble = {args.ensemble} is out of range: must be in "
                            f"[1, {MAX_ENSEMBLE}]")


def _cmd_faults(args):
    from drake_contact.app.fault_study import SUITES, check_contenders, run_fault_study
    from drake_contact.app.campaign import points_progress
    _check_campaign_arguments(args)
    if args.suite not in SUITES:
        raise ScenarioError(f"--suite = {args.suite} is unknown: choose one of "
                            f"{', '.join(SUITES)}")
    check_contenders(args.controllers)
    _check_out(args.out)
    result = run_fault_study(args.out, contenders=args.controllers, suite=args.suite,
                             workers=args.workers, scheduler=args.scheduler,
                             progress=points_progress(), ensemble=args.ensemble)
    print(_campaign_line(result))
    for safety in ("off", "on"):
        mine = [e for e in result.tables["faults"] if e["safety"] == safety]
        runs = sum(e["runs"] - e["runs_failed"] - e["runs_not_finished"] for e in mine)
        failed = sum(e["runs_failed"] for e in mine)
        print(f"supervisor {safety:3s}: {sum(e['runs_past_limit'] for e in mine)}/{runs} runs "
              f"more than 10 % over the limit, {sum(e['runs_recovered'] for e in mine)} recovered "
              f"tracking, {sum(e['runs_ended_safe'] for e in mine)} ended safe"
              + (f"; {failed} runs FAILED (not scored)" if failed else ""))
    print(f"wrote {args.out}/faults.md, faults.csv and runs.csv")
    return _campaign_exit(result, args)


def _cmd_list(args):
    from drake_contact.resources import bundled_scenario_names
    from drake_contact.scenario import load_scenario
    for name in bundled_scenario_names():
        description = load_scenario(name).description.strip().splitlines()
        print(f"{name:28s} {description[0] if description else ''}")
    return 0


def _cmd_bench(args):
    from drake_contact.app.bench import bench, load_bench_scenario, profile_scenario
    from drake_contact.errors import SimulationDiverged
    scenario = load_bench_scenario(args.scenario, duration=args.duration)
    sizes = _ensemble_sizes(args.ensemble)
    try:
        result = bench(scenario, name=args.scenario)
        print(result.format(), flush=True)
        if args.profile:
            print()
            print(profile_scenario(scenario, name=args.scenario).format())
        if sizes:
            from drake_contact.app.bench import format_ensembles, time_ensemble
            timings = []
            for size in sizes:
                timings.append(time_ensemble(scenario, size))
            print()
            print(format_ensembles(timings, result.scenario.us_per_step, args.scenario,
                                   scenario.simulation.duration))
    except SimulationDiverged as e:
        print(f"drake-contact: {e}", file=sys.stderr)
        return EXIT_DIVERGED
    except KeyboardInterrupt:
        print("drake-contact: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0


def _ensemble_sizes(text):
    """--ensemble N,N,... as a list of ints (one line, exit 2, when bad)."""
    if not text:
        return []
    try:
        sizes = [int(part) for part in text.split(",")]
    except ValueError:
        sizes = []
    if not sizes or not all(1 <= n <= MAX_ENSEMBLE for n in sizes):
        raise ScenarioError(f"--ensemble = {text} is out of range: must be sizes in "
                            f"[1, {MAX_ENSEMBLE}] separated by commas, e.g. 1,4,16")
    return sizes


def _cmd_run(args):
    from drake_contact.app.runner import run, terminal_progress
    from drake_contact.scenario import load_scenario
    from drake_contact.visualization import check_record_path, new_meshcat
    from drake_contact.app.drawing import check_diagram_path, write_diagram
    from drake_contact.diagram import MakeContactDiagram
    scenario = load_scenario(args.scenario, args.set, duration=args.duration, seed=args.seed)
    if not args.realtime_rate >= 0:
        raise ScenarioError(f"--realtime-rate = {args.realtime_rate} is out of range: must be >= 0")
    meshcat = None
    if args.record:
        check_record_path(args.record)  # before a Meshcat URL is printed
    if args.graphviz:
        check_diagram_path(args.graphviz)  # before building
    _check_out(args.out)  # every input checked: now the folder may be made
    if args.graphviz:
        write_diagram(MakeContactDiagram(scenario), args.graphviz)
    if args.meshcat:
        meshcat = new_meshcat()
        print(f"Meshcat: {meshcat.web_url()}", flush=True)
    try:
        result = run(scenario, args.out, progress=terminal_progress(),
                     figures=not args.no_figures,
                     baseline=(False if args.no_baseline else
                               "window" if args.baseline_window else None), meshcat=meshcat,
                     record=args.record, realtime_rate=args.realtime_rate if args.meshcat else 0.0)
    except KeyboardInterrupt:
        print("drake-contact: interrupted before the simulation started", file=sys.stderr)
        return EXIT_INTERRUPTED
    m = result.metrics
    print(f"{result.status}: {m['simulated_time_s']:.3f} s simulated in {m['wall_time_s']:.2f} s "
          f"(real-time factor {m['realtime_factor']:.2f}, {m['us_per_step']:.1f} us/step); "
          f"peak force {m['peak_force_n']:.4g} N"
          + (f", steady force {m['steady_force_n']:.4g} N (true, mean of the last "
             f"{scenario.simulation.settle_window:g} s)" if "steady_force_n" in m else "")
          + f"; wrote {args.out}"
          + (f" and {args.record}" if args.record else "")
          + (f" and {args.graphviz}" if args.graphviz else ""))
    for warning in m.get("warnings", []):
        print(f"drake-contact: warning: {warning}", file=sys.stderr)
    if result.status == "diverged":
        print(f"drake-contact: {result.message}", file=sys.stderr)
        return EXIT_DIVERGED
    if result.status == "interrupted":
        print(f"drake-contact: {result.message}", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0


def _cmd_reproduce(args):
    from drake_contact.app.claims import summary
    from drake_contact.app.reproduce import parse_seeds, reproduce, summary_line
    _check_campaign_arguments(args)
    try:
        seeds = parse_seeds(args.seeds)
    except ValueError as e:
        raise ScenarioError(f"--seeds = {args.seeds} is out of range: {e}") from None
    _check_out(args.out)
    rows, claims, interrupted = reproduce(
        args.out, quick=args.quick, jobs=args.jobs, seeds=seeds,
        progress=lambda line: print(line, flush=True), ensemble=args.ensemble)
    print(summary(claims))
    print("beyond the thesis: " + summary_line(rows))
    if interrupted:
        print("drake-contact: interrupted; the report is partial", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0 if all(r.as_expected for r in [*rows, *claims]) else EXIT_FAILED


def _cmd_sweep(args):
    from drake_contact.app.campaign import points_progress
    from drake_contact.app.sweep import load_sweep, run_sweep, summary_lines
    _check_campaign_arguments(args)
    sweep = load_sweep(args.sweep, quick=args.quick)
    _check_out(args.out)
    result = run_sweep(sweep, args.out, workers=args.workers, scheduler=args.scheduler,
                       progress=points_progress(), ensemble=args.ensemble)
    for line in summary_lines(sweep, result):
        print(line)
    print(f"wrote {args.out}/results.csv and {args.out}/sweep.html")
    return _campaign_exit(result, args)


def _cmd_benchmark(args):
    from drake_contact.app.benchmark import (
        SUITES, contender_names, identifier_names, run_benchmark)
    from drake_contact.app.campaign import points_progress
    _check_campaign_arguments(args)
    if args.suite not in SUITES:
        raise ScenarioError(f"--suite = {args.suite} is unknown: choose one of "
                            f"{', '.join(SUITES)}")
    contender_names(args.controllers)  # bad names: one line before any folder is made
    identifier_names(args.identifiers)
    _check_out(args.out)
    result = run_benchmark(args.out, contenders=args.controllers,
                           identifiers=args.identifiers, suite=args.suite,
                           workers=args.workers, scheduler=args.scheduler,
                           progress=points_progress(), ensemble=args.ensemble)
    overall = sorted((e for e in result.tables["leaderboard"] if e["task"] == "all"),
                     key=lambda e: (e["rank"] is None, e["rank"] or e["runs_failed"]))
    print(_campaign_line(result))
    for e in overall:
        rank = "  -." if e["rank"] is None else f"{e['rank']:3d}."
        print(f"{rank} {e['contender']:18s} "
              + (f"FAILED {e['runs_failed']}/{e['runs']} runs, not ranked; "
                 if e["runs_failed"] else f"mean task rank {e['mean_rank']:.2f}, ")
              + f"lost contact in {e['runs_losing_contact']}/{e['runs']} runs, "
              + (f"diverged in {e['runs_diverged']}, " if e["runs_diverged"] else "")
              + "median force RMSE "
              + (f"{e['force_rmse_n_median']:.2f} N" if e['force_rmse_n_median'] is not None
                 else "-"))
    for e in sorted((e for e in result.tables.get("identifier_leaderboard", [])
                     if e["task"] == "all"),
                    key=lambda e: e["rank"]):
        print(f"{e['rank']:3d}. identifier {e['identifier']:14s} K_e within 5 % in "
              f"{e['runs_settled_5pct']}/{e['runs']} runs, median |K_e error| "
              + (f"{e['stiffness_abs_error_pct_median']:.2f} %"
                 if e['stiffness_abs_error_pct_median'] is not None else "-"))
    print(f"wrote {args.out}/leaderboard.md, leaderboard.csv and leaderboard.html")
    return _campaign_exit(result, args)


def _campaign_line(result) -> str:
    return (f"{result.ran + result.skipped} runs ({result.ran} now, {result.skipped} from "
            f"before) in {result.startup_s + result.wall_s:.0f} s on {result.workers} workers, "
            f"{result.checked} configurations built first in {result.check_s:.1f} s: "
            f"{len(result.failed)} failed, {len(result.diverged)} diverged")


def _campaign_exit(result, args) -> int:
    """A campaign's exit status: 130 interrupted; 1 when a run failed (one
    line on stderr names the first), unless --allow-failures; else 0 (a
    diverged run is a result)."""
    if result.interrupted:
        return EXIT_INTERRUPTED
    if not result.failed:
        return 0
    name, message = next(iter(result.failed.items()))
    print(f"drake-contact: {len(result.failed)} of {result.ran + result.skipped} runs failed, "
          f"first {name}: {message}"
          + ("" if args.allow_failures else " (--allow-failures to exit 0 anyway)"),
          file=sys.stderr)
    return 0 if args.allow_failures else EXIT_FAILED


def _check_out(path):
    """Creates the output folder (once the input is known to be valid), or
    refuses it in one line (ScenarioError)."""
    try:
        Path(path).mkdir(parents=True, exist_ok=True)
        probe = Path(path) / ".drake_contact_write_test"
        probe.write_text("")
        probe.unlink()
    except OSError as e:
        raise ScenarioError(f"--out = {path}: cannot write there ({e.strerror or e}): "
                            "give a folder you can create and write") from None


def main(argv=None) -> int:
    args = _build_parser().parse_args(argv)
    try:
        return {"run": _cmd_run, "list": _cmd_list, "bench": _cmd_bench,
                "reproduce": _cmd_reproduce, "sweep": _cmd_sweep,
                "benchmark": _cmd_benchmark, "faults": _cmd_faults}[args.command](args)
    except ScenarioError as e:
        print(f"drake-contact: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
