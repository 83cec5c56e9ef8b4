"""The reference results the documentation shows: ``python docs/results.py``.

    python docs/results.py                  # every study whose snapshot is stale
    python docs/results.py --study faults   # this study (repeatable), stale or not
    python docs/results.py --check          # which snapshots are stale; exit 1 if any

A study runs with ``drake-contact`` into ``docs/_generated/<study>/`` (not
committed; a campaign resumes the runs it finished there before), then its
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
anything. Run it with the interpreter that has drake_contact installed
(``.venv/bin/python docs/results.py``).
"""

import argparse
import dataclasses as dc
import datetime
import fnmatch
import hashlib
import json
import os
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
#: A snapshot's figures are at most this wide (px).
FIGURE_WIDTH_PX = 1000


@dc.dataclass(frozen=True)
class Study:
    # Its drake-contact arguments (--out is added).
    arguments: tuple
    # The files of its output folder the snapshot keeps (globs).
    keep: tuple


STUDIES = {
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


def definition(name: str) -> dict:
    """What study ``name`` runs, as plain data."""
    arguments = STUDIES[name].arguments
    if arguments[0] == "faults":
        from drake_contact.app.fault_study import FaultStudy
        controllers = arguments[arguments.index("--controllers") + 1] \
            if "--controllers" in arguments else None
        suite = arguments[arguments.index("--suite") + 1] if "--suite" in arguments \
            else "standard"
        return {"arguments": list(arguments),
                "resolved": FaultStudy(suite, controllers).resolved()}
    raise KeyError(name)


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
    """A copy of the PNG ``source`` at most FIGURE_WIDTH_PX wide."""
    from PIL import Image
    with Image.open(source) as image:
        if image.width > FIGURE_WIDTH_PX:
            height = round(image.height * FIGURE_WIDTH_PX / image.width)
            image = image.resize((FIGURE_WIDTH_PX, height), Image.LANCZOS)
        image.save(target, optimize=True)


def write_snapshot(name: str, source: Path, refresh_s: float, results: Path = RESULTS) -> Path:
    """Study ``name``'s snapshot from its output folder ``source``."""
    target = results / name
    if target.exists():
        shutil.rmtree(target)
    target.mkdir(parents=True)
    for path in sorted(source.rglob("*")):
        relative = path.relative_to(source).as_posix()
        if not path.is_file() or not any(fnmatch.fnmatch(relative, g)
                                         for g in STUDIES[name].keep):
            continue
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


def refresh(name: str) -> int:
    """Runs study ``name`` (resuming) and writes its snapshot."""
    out = GENERATED / name
    command = [sys.executable, "-m", "drake_contact", *STUDIES[name].arguments,
               "--out", str(out)]
    print("+", " ".join(command[1:]), flush=True)
    start = time.perf_counter()
    status = subprocess.run(command, env=dict(os.environ, MPLBACKEND="Agg")).returncode
    seconds = time.perf_counter() - start
    # A study's exit status says whether its results are as expected; the
    # snapshot shows them either way, unless the study did not finish.
    if status not in (0, 1):
        print(f"  {name}: exit {status} after {seconds:.0f} s: no snapshot", flush=True)
        return status
    write_snapshot(name, out, seconds)
    print(f"  {name}: exit {status}, {seconds:.0f} s; snapshot in "
          f"{(RESULTS / name).relative_to(ROOT)}", flush=True)
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--study", action="append", choices=sorted(STUDIES),
                        help="refresh this study (repeatable), stale or not")
    parser.add_argument("--check", action="store_true",
                        help="list the stale snapshots and exit 1 if any")
    args = parser.parse_args(argv)
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
        status = refresh(name) or status
    return status


if __name__ == "__main__":
    sys.exit(main())
