"""Build the documentation site: ``python docs/build.py``.

The site alone takes 30-60 s on 2 cores (the tutorial notebook runs in the
build); the test suite builds it the same way, with warnings as errors.
The pages show the reference results' committed snapshots
(``docs/results/``, made by ``docs/results.py``) where a study has one.
``--figures`` first runs the other long studies whose tables and figures
the pages show, into ``docs/_generated/<study>/`` (39 minutes on a 2-core
machine; a study already there is resumed, so rerunning is quick).
``--study NAME`` (repeatable) chooses the studies, including the longer ones
not in the default set. Run it with the interpreter that has drake_contact
and the ``docs`` extra installed (``.venv/bin/python docs/build.py``).
"""

import argparse
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

DOCS = Path(__file__).resolve().parent
GENERATED = DOCS / "_generated"

#: Study name -> (its drake-contact arguments (--out added), about how long
#: it took on a 2-core machine, made by --figures without --study). The
#: default five took 39 min in all on 2026-11-27 (with other work on the
#: machine for the first 30). The standard benchmark ran 132 of its 480
#: runs in 20 min that day; stability_nn took 38 min on 2026-11-26 and was
#: not rerun since. (The full fault study is a snapshot: docs/results.py.)
STUDIES = {
    "reproduce": (["reproduce"], "12-20 min", True),
    "stability_hybrid": (["sweep", "stability_hybrid", "--workers", "2"], "4-7 min", True),
    "identification_accuracy": (["sweep", "identification_accuracy", "--workers", "2"],
                                "5 min", True),
    "benchmark_quick": (["benchmark", "--suite", "quick", "--identifiers", "all",
                         "--workers", "2"], "4 min", True),
    "faults_quick": (["faults", "--suite", "quick", "--workers", "2"], "2 min", True),
    "benchmark": (["benchmark", "--identifiers", "all", "--workers", "2"], "70 min", False),
    "stability_nn": (["sweep", "stability_nn", "--workers", "2"], "40 min or more", False),
}


def run_study(name: str) -> int:
    arguments, _, _ = STUDIES[name]
    command = [sys.executable, "-m", "drake_contact", *arguments, "--out",
               str(GENERATED / name)]
    print("+", " ".join(command[1:]), flush=True)
    start = time.perf_counter()
    status = subprocess.run(command, env=dict(os.environ, MPLBACKEND="Agg")).returncode
    print(f"  {name}: exit {status}, {time.perf_counter() - start:.0f} s", flush=True)
    return status


def build(out: Path, *, warnings_as_errors: bool = True) -> int:
    from sphinx.cmd.build import build_main

    # The tutorial runs in this interpreter's "python3" kernel (ipykernel's,
    # installed with it): its folder goes first, so a python3 kernel the user
    # installed for another interpreter is not picked up.
    own = str(Path(sys.prefix) / "share" / "jupyter")
    os.environ["JUPYTER_PATH"] = os.pathsep.join(
        [own] + [p for p in os.environ.get("JUPYTER_PATH", "").split(os.pathsep) if p])

    arguments = ["-b", "html", "-q", str(DOCS), str(out)]
    if warnings_as_errors:
        arguments[:0] = ["-W", "--keep-going"]
    return build_main(arguments)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=DOCS / "_build" / "html",
                        help="where the HTML goes (default docs/_build/html)")
    parser.add_argument("--figures", action="store_true",
                        help="first run the studies the pages show (docs/_generated/)")
    parser.add_argument("--study", action="append", choices=sorted(STUDIES),
                        help="with --figures: this study (repeatable); default: "
                        + ", ".join(name for name, (_, _, default) in STUDIES.items() if default))
    args = parser.parse_args(argv)
    start = time.perf_counter()
    if args.figures:
        studies = args.study or [name for name, (_, _, default) in STUDIES.items() if default]
        for name in studies:
            # A study's own exit status says whether its results are as
            # expected (reproduce exits 1 on a result that changed); the
            # pages show them either way.
            run_study(name)
    if shutil.which("dot") is None:
        print("note: the tutorial draws its diagram with Graphviz's dot, which is not on this "
              "machine: the page will say so instead. Install it (Debian/Ubuntu: sudo apt-get "
              "install graphviz; macOS: brew install graphviz) and build again to draw it.",
              flush=True)
    status = build(args.out)
    print(f"site: {args.out / 'index.html'} ({time.perf_counter() - start:.0f} s)")
    return status


if __name__ == "__main__":
    sys.exit(main())
