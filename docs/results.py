"""The reference results the documentation shows: ``python docs/results.py``.

    python docs/results.py                  # every study whose snapshot is stale
    python docs/results.py --study faults   # this study (repeatable), stale or not
    python docs/results.py --check          # which snapshots are stale; exit 1 if any
    python docs/results.py --readme         # README.md's status, from the reproduction

A study runs with ``drake-contact`` into ``docs/_generated/<study>/`` (not
committed; an interrupted refresh resumes the runs it finished there, and
the folder is removed once the snapshot is written unless ``--keep``), then its
**snapshot** is written to ``docs/results/<study>/`` (committed): the
Markdown and CSV tables the pages include, the figures they show as
web-sized PNGs, and ``snapshot.json``: the commit and date it was made at,
how long the refresh took, the command, and its **fingerprint**:

- ``physics``: a hash of the golden logs (``tests/golden/*.npz``), which
  are re-recorded for every change of the physics and only then;
- ``definition``: a hash of what the study runs (its campaign's resolved
  declaration: scenarios, walls, cases, seeds; or the reproduction's
  scenarios, seeds and claims).

A snapshot whose fingerprint no longer matches the code is stale:
``tests/test_results.py`` fails, naming the command that refreshes it.
The pages read the snapshot (``docs/_ext/drake_contact_docs.py``'s
``generated`` directive), so the site shows results without running
anything; the README's status paragraph is written from the
reproduction's snapshot. Run it with the interpreter that has drake_contact installed
(``.venv/bin/python docs/results.py``).
"""

import argparse
import dataclasses as dc
import datetime
import fnmatch
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import yaml

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
GENERATED = DOCS / "_generated"
RESULTS = DOCS / "results"
GOLDEN = ROOT / "tests" / "golden"
README = ROOT / "README.md"
#: The README's status paragraph lies between these lines, written from the
#: reproduction's snapshot (:func:`readme_status`).
STATUS_BEGIN = "<!-- status: written by docs/results.py from docs/results/reproduce -->"
STATUS_END = "<!-- /status -->"
#: A snapshot's figures are at most this wide (px).
FIGURE_WIDTH_PX = 1000


@dc.dataclass(frozen=True)
class Study:
    # Its drake-contact arguments (--out is added).
    arguments: tuple
    # The files of its output folder the snapshot keeps (globs), besides the
    # figures its kept Markdown shows.
    keep: tuple


#: The benchmark's contenders, named (its default is every installed
#: controller plug-in, which would make the study depend on the machine):
#: the thesis's, the robust ones, the baselines and the two example
#: plug-ins the test command installs (jt_pi, and the learned policies:
#: learned_residual and each training seed of PPO and CMA-ES).
BENCHMARK_CONTENDERS = ("hybrid,hybrid_pi,nn,nn_robust,adaptive_hybrid,admittance,impedance,"
                        "jt_pi,learned_residual,parallel_force,"
                        "learned_ppo_s0,learned_ppo_s1,learned_ppo_s2,"
                        "learned_cmaes_s0,learned_cmaes_s1,learned_cmaes_s2")
_SWEEP_KEEP = ("maps.md", "results.csv", "sweep.yaml", "map_*.png")

STUDIES = {
    # The thesis reproduced, seeds 0-2 (the README's main command).
    "reproduce": Study(("reproduce",),
                       ("report.md", "claims.csv", "runs.csv", "reproduce.yaml")),
    # Fig 6.15 with the thesis's own cause (the tip sticking to the wall).
    "fig6_15_wall_friction": Study(("sweep", "fig6_15_wall_friction"), _SWEEP_KEEP),
    "benchmark": Study(("benchmark", "--controllers", BENCHMARK_CONTENDERS,
                        "--identifiers", "all"),
                       ("leaderboard.md", "leaderboard.csv", "identifier_leaderboard.csv",
                        "runs.csv", "identifiers.csv", "benchmark.yaml", "figures/*.png")),
    # The stability maps.
    "stability_nn": Study(("sweep", "stability_nn"), _SWEEP_KEEP),
    "stability_hybrid": Study(("sweep", "stability_hybrid"), _SWEEP_KEEP),
    "identification_accuracy": Study(("sweep", "identification_accuracy"), _SWEEP_KEEP),
    "stability_nn_robust": Study(("sweep", "stability_nn_robust"), _SWEEP_KEEP),
    # The identification grids: any wall, and walls that drift or step.
    "identify_any": Study(("sweep", "identify_any"), _SWEEP_KEEP),
    "identify_any_nn_auto": Study(("sweep", "identify_any_nn_auto"), _SWEEP_KEEP),
    "identify_drift": Study(("sweep", "identify_drift"), _SWEEP_KEEP),
    "identify_step": Study(("sweep", "identify_step"), _SWEEP_KEEP),
    # The robust-control grids, and the thesis's hybrid PI on the same task.
    "robust_nn": Study(("sweep", "robust_nn"), _SWEEP_KEEP),
    "adaptive_hybrid": Study(("sweep", "adaptive_hybrid"), _SWEEP_KEEP),
    "hybrid_pi_map": Study(("sweep", "hybrid_pi_map"), _SWEEP_KEEP),
    # The robust contenders (the default's thesis hybrid and nn would double
    # its refresh).
    "faults": Study(("faults", "--controllers", "nn_robust,adaptive_hybrid"),
                    ("faults.md", "faults.csv", "runs.csv", "faults.yaml")),
}


def refresh_command(name: str) -> str:
    return f"python docs/results.py --study {name}"


def _digest(chunks) -> str:
    h = hashlib.sha256()
    for chunk in chunks:
        h.update(chunk)
    return h.hexdigest()[:16]


def physics_fingerprint(golden: Path = GOLDEN) -> str:
    """A hash of the golden logs (their names and bytes)."""
    files = sorted(golden.glob("*.npz"))
    if not files:
        raise FileNotFoundError(f"no golden logs in {golden}")
    return _digest(part for f in files for part in (f.name.encode(), f.read_bytes()))


def _option(arguments: tuple, flag: str, default=None):
    return arguments[arguments.index(flag) + 1] if flag in arguments else default


def definition(name: str) -> dict:
    """What study ``name`` runs, as plain data: its arguments and the
    campaign's resolved declaration (what it writes as ``<campaign>.yaml``)."""
    arguments = STUDIES[name].arguments
    command = arguments[0]
    if command == "faults":
        from drake_contact.app.fault_study import FaultStudy
        resolved = FaultStudy(_option(arguments, "--suite", "standard"),
                              _option(arguments, "--controllers")).resolved()
    elif command == "benchmark":
        from drake_contact.app.benchmark import BenchmarkCampaign
        resolved = BenchmarkCampaign(_option(arguments, "--suite", "standard"),
                                     _option(arguments, "--controllers"),
                                     _option(arguments, "--identifiers")).resolved()
    elif command == "sweep":
        from drake_contact.app.sweep import SweepCampaign, load_sweep
        resolved = SweepCampaign(load_sweep(arguments[1])).resolved()
    elif command == "reproduce":
        from drake_contact.app.reproduce import Reproduction
        from drake_contact.app.claims import CLAIMS
        resolved = Reproduction(GENERATED / name, progress=None).resolved()
        # The claims it scores: their criteria, deviations and calibrations.
        resolved["claims"] = [{field.name: getattr(claim, field.name)
                               for field in dc.fields(claim)
                               if isinstance(getattr(claim, field.name), (str, int, float))}
                              for claim in CLAIMS]
    else:
        raise KeyError(name)
    return {"arguments": list(arguments), "resolved": resolved}


def definition_fingerprint(name: str) -> str:
    text = yaml.safe_dump(definition(name), sort_keys=True)
    return _digest([text.encode()])


def fingerprint(name: str, golden: Path = GOLDEN) -> dict:
    return {"physics": physics_fingerprint(golden), "definition": definition_fingerprint(name)}


def stale(name: str, results: Path = RESULTS, golden: Path = GOLDEN) -> str | None:
    """Why study ``name``'s snapshot is stale (None: it is not)."""
    path = results / name / "snapshot.json"
    if not path.exists():
        return "no snapshot"
    recorded = json.loads(path.read_text())["fingerprint"]
    now = fingerprint(name, golden)
    changed = [part for part in ("physics", "definition") if recorded.get(part) != now[part]]
    if changed:
        return " and ".join(changed) + " changed since it was made"
    return None


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, text=True,
                              capture_output=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _shrink(source: Path, target: Path):
    """A copy of the PNG ``source`` at most FIGURE_WIDTH_PX wide, in 256
    colours (a plot's lines and text need no more; a third of the bytes)."""
    from PIL import Image
    with Image.open(source) as image:
        image = image.convert("RGB")
        if image.width > FIGURE_WIDTH_PX:
            height = round(image.height * FIGURE_WIDTH_PX / image.width)
            image = image.resize((FIGURE_WIDTH_PX, height), Image.LANCZOS)
        image.quantize(256, method=Image.Quantize.MEDIANCUT).save(target, optimize=True)


def _linked_figures(markdown: Path, source: Path) -> list[str]:
    """The local images a kept Markdown file shows, relative to ``source``."""
    found = []
    for link in re.findall(r"!\[[^]]*\]\(([^)\s]+)\)", markdown.read_text()):
        if "://" in link:
            continue
        path = (markdown.parent / link).resolve()
        if path.is_file() and path.is_relative_to(source.resolve()):
            found.append(path.relative_to(source.resolve()).as_posix())
    return found


def write_snapshot(name: str, source: Path, refresh_s: float, results: Path = RESULTS) -> Path:
    """Study ``name``'s snapshot from its output folder ``source``: the
    files its globs name and the figures its kept Markdown shows."""
    target = results / name
    if target.exists():
        shutil.rmtree(target)
    target.mkdir(parents=True)
    kept = {path.relative_to(source).as_posix() for path in source.rglob("*")
            if path.is_file() and any(fnmatch.fnmatch(path.relative_to(source).as_posix(), g)
                                      for g in STUDIES[name].keep)}
    kept |= {figure for relative in list(kept) if relative.endswith(".md")
             for figure in _linked_figures(source / relative, source)}
    for relative in sorted(kept):
        path = source / relative
        (target / relative).parent.mkdir(parents=True, exist_ok=True)
        if path.suffix == ".png":
            _shrink(path, target / relative)
        else:
            shutil.copyfile(path, target / relative)
    stamp = {"study": name, "commit": _commit(),
             "date": datetime.date.today().isoformat(),
             "refresh_s": round(refresh_s), "command": refresh_command(name),
             "runs": "drake-contact " + " ".join(STUDIES[name].arguments),
             "fingerprint": fingerprint(name)}
    (target / "snapshot.json").write_text(json.dumps(stamp, indent=1) + "\n")
    return target


def readme_status(results: Path = RESULTS, *, details: bool = True) -> str:
    """The README's status paragraph, from the reproduction's snapshot: its
    claims' verdicts (``claims.csv``, a line per claim and seed); the
    reproduction page shows it too (``details=False``: without the link to
    that page)."""
    import csv
    stamp = json.loads((results / "reproduce" / "snapshot.json").read_text())
    with open(results / "reproduce" / "claims.csv", newline="") as stream:
        lines = list(csv.DictReader(stream))
    seeds = sorted({int(line["seed"]) for line in lines})
    claims = {line["id"]: line for line in lines}.values()
    verdicts = [c["verdict"] for c in claims]
    calibration = [v for v in verdicts if v.startswith("calibration")]
    deviations = [c for c in claims if c["verdict"] == "documented deviation"]
    not_isolated = sum("cause not isolated" in c["cause"].lower() for c in deviations)
    other = len(verdicts) - len(calibration) - len(deviations) - verdicts.count("reproduced")
    seed_text = (f"seeds {seeds[0]}-{seeds[-1]}" if seeds == list(range(seeds[0], seeds[-1] + 1))
                 and len(seeds) > 1 else "seeds " + ", ".join(map(str, seeds)))
    return (f"**Status** (the reference reproduction, {seed_text}, at {stamp['commit']} on "
            f"{stamp['date']}): of the thesis's {len(verdicts) - len(calibration)} checkable "
            f"claims that no calibration decides, {verdicts.count('reproduced')} reproduced on "
            f"every seed and {len(deviations)} documented deviations with their causes "
            f"({len(deviations) - not_isolated} shown by an ablation or by the fit, "
            f"{not_isolated} not isolated, with what was tried), {other} not as expected. "
            f"The walls are calibrated to the thesis's own readings and the sensor's noise to "
            f"its observations ({len(calibration)} calibration rows, "
            f"{sum(v == 'calibration (holds)' for v in calibration)} holding)."
            + (" Details: [The thesis reproduced](docs/reproduction.md)." if details else ""))


def readme_with_status(text: str, results: Path = RESULTS) -> str:
    """``text`` (the README) with its status paragraph written anew."""
    head, _, rest = text.partition(STATUS_BEGIN + "\n")
    _, _, tail = rest.partition(STATUS_END)
    if not rest or not tail and STATUS_END not in rest:
        raise ValueError(f"README.md has no {STATUS_BEGIN} ... {STATUS_END} block")
    return f"{head}{STATUS_BEGIN}\n{readme_status(results)}\n{STATUS_END}{tail}"


def refresh(name: str, keep: bool = False) -> int:
    """Runs study ``name`` (resuming what an interrupted refresh left in its
    output folder) and writes its snapshot; then removes the output folder
    unless ``keep``."""
    out = GENERATED / name
    command = [sys.executable, "-m", "drake_contact", *STUDIES[name].arguments,
               "--out", str(out)]
    print("+", " ".join(command[1:]), flush=True)
    start = time.perf_counter()
    status = subprocess.run(command, env=dict(os.environ, MPLBACKEND="Agg")).returncode
    seconds = time.perf_counter() - start
    # The reproduction exits 1 when a result is not as expected: its
    # snapshot shows that. A campaign exits 1 when runs failed: no snapshot.
    if status not in ((0, 1) if STUDIES[name].arguments[0] == "reproduce" else (0,)):
        print(f"  {name}: exit {status} after {seconds:.0f} s: no snapshot", flush=True)
        return status
    write_snapshot(name, out, seconds)
    if name == "reproduce":
        README.write_text(readme_with_status(README.read_text()))
    if not keep:
        # Its run folders hold every run's log (the full refresh writes
        # about 35 GB); the snapshot has what the pages show.
        shutil.rmtree(out, ignore_errors=True)
    print(f"  {name}: exit {status}, {seconds:.0f} s; snapshot in {RESULTS / name}", flush=True)
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--study", action="append", choices=sorted(STUDIES),
                        help="refresh this study (repeatable), stale or not")
    parser.add_argument("--check", action="store_true",
                        help="list the stale snapshots and exit 1 if any")
    parser.add_argument("--keep", action="store_true",
                        help="keep each study's runs in docs/_generated/<study>/ (their logs "
                        "take about 35 GB for a full refresh); default: removed once its "
                        "snapshot is written")
    parser.add_argument("--readme", action="store_true",
                        help="only write README.md's status from the reproduction's snapshot")
    args = parser.parse_args(argv)
    if args.readme:
        README.write_text(readme_with_status(README.read_text()))
        return 0
    reasons = {name: stale(name) for name in STUDIES}
    if args.check:
        for name, reason in reasons.items():
            print(f"{name}: {'stale: ' + reason if reason else 'up to date'}")
        return 1 if any(reasons.values()) else 0
    names = args.study or [name for name, reason in reasons.items() if reason]
    if not names:
        print("every snapshot is up to date")
    status = 0
    for name in names:
        status = refresh(name, keep=args.keep) or status
    return status


if __name__ == "__main__":
    sys.exit(main())
