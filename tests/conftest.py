"""Shared test helpers: tests that need a system program say so in the
summary instead of skipping in silence."""

import shutil

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
