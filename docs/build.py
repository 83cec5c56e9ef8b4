"""Build the documentation site: ``python docs/build.py``.

The site takes 30-60 s on 2 cores (the tutorial notebook runs in the
build); the test suite builds it the same way, with warnings as errors.
The pages' measured results (tables and figures) are the reference
results' committed snapshots, ``docs/results/`` (``docs/results.py``
refreshes them), so the build runs no study. Run it with the interpreter
that has drake_contact and the ``docs`` extra installed
(``.venv/bin/python docs/build.py``).
"""

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

DOCS = Path(__file__).resolve().parent


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
    args = parser.parse_args(argv)
    start = time.perf_counter()
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
