"""Errors that the command line reports as one line, without a traceback."""

import difflib
import math


class ScenarioError(ValueError):
    """Bad input: names the offending field and its allowed range.

    The message is a single line meant for a user, e.g.
    ``environment.stiffness = -5.0 is out of range: must be > 0 N/m``.
    """

    def __init__(self, message):
        # A value as typed may hold a line break (a name 'a\nb'): it is shown
        # escaped, so that the message stays one line.
        super().__init__(str(message).replace("\r", "\\r").replace("\n", "\\n"))


def did_you_mean(value, choices) -> str:
    """``" (did you mean 'x'?)"`` for the choice closest to a mistyped
    ``value``, or ``""`` when none is close (difflib's ratio under 0.6)."""
    close = difflib.get_close_matches(str(value), [str(c) for c in choices], n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


class SimulationDiverged(RuntimeError):
    """A run produced NaN or a force above the configured limit.

    ``time_s`` is the simulated time of the first bad sample and ``where``
    names the signal; the runner has already written the logs up to then.
    """

    def __init__(self, message, *, time_s, where):
        super().__init__(message)
        self.time_s = time_s
        self.where = where


def require_finite(values, context, where, what="the arm's state"):
    """Raises SimulationDiverged unless every entry of ``values`` is finite.

    Systems that load a state into a plant context call this first: Drake
    aborts the process (not an exception) on a non-finite state.
    """
    # One sum is finite iff every entry is (inf - inf is nan): cheaper than
    # np.isfinite(...).all() on a hot path.
    if not math.isfinite(float(values.sum())):
        t = context.get_time()
        raise SimulationDiverged(
            f"diverged at t = {t:.3f} s: {what} is not finite ({where})", time_s=t, where=where)
