"""Shared test helpers: tests that need a system program say so in the
summary instead of skipping in silence; the quick reproduction, run once
for every test that reads its runs."""

import shutil
import subprocess
import sys

import pytest

#: Skip reasons that name a missing program start with this.
NOT_TESTED = "not tested:"

#: The Debian package that brings each program the suite can use.
PACKAGES = {"chromium": "chromium", "dot": "graphviz"}


def needs_tool(command: str, what: str):
    """Skips the calling test when ``command`` is not on PATH, with a reason
    that the run's summary repeats: what was not tested and how to install
    the program."""
    if shutil.which(command) is None:
        pytest.skip(f"{NOT_TESTED} {what} ({command} is not on PATH; install it with "
                    f"`apt-get install {PACKAGES[command]}`)")


def skip_unless_tool(command: str, what: str):
    """The marker form of :func:`needs_tool`."""
    return pytest.mark.skipif(
        shutil.which(command) is None,
        reason=f"{NOT_TESTED} {what} ({command} is not on PATH; install it with "
               f"`apt-get install {PACKAGES[command]}`)")


#: Every test that reads the quick reproduction's runs carries this mark, so
#: one xdist worker runs them all and the session fixture below runs once.
ON_QUICK_REPRODUCTION = pytest.mark.xdist_group("reproduce_quick")


@pytest.fixture(scope="session")
def quick_reproduction(tmp_path_factory):
    """``drake-contact reproduce --quick --seeds 0``, run once: its output
    folder and the finished process. Its runs (``<out>/<scenario>/seed_0``:
    scenario.yaml, log.npz, metrics.json, figures) are the thesis's
    scenarios at seed 0, so the tests of those runs read them rather than
    simulate the same scenarios again."""
    out = tmp_path_factory.mktemp("reproduce")
    result = subprocess.run(
        [sys.executable, "-m", "drake_contact", "reproduce", "--quick", "--out", str(out),
         "--seeds", "0"],
        capture_output=True, text=True, timeout=600)
    return out, result


def pytest_terminal_summary(terminalreporter):
    """One line per thing not tested for a missing program, after the
    summary (pytest -q shows skips only as a count)."""
    reasons = {}
    for report in terminalreporter.stats.get("skipped", []):
        longrepr = report.longrepr
        reason = longrepr[2] if isinstance(longrepr, tuple) else str(longrepr)
        reason = reason.removeprefix("Skipped: ")
        if reason.startswith(NOT_TESTED):
            reasons[reason] = reasons.get(reason, 0) + 1
    for reason, count in sorted(reasons.items()):
        terminalreporter.write_line(f"{reason} [{count} test{'s' if count > 1 else ''}]")
