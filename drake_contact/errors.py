"""Errors that the command line reports as one line, without a traceback."""


class ScenarioError(ValueError):
    """Bad input: names the offending field and its allowed range.

    The message is a single line meant for a user, e.g.
    ``environment.stiffness = -5.0 is out of range: must be > 0 N/m``.
    """


class SimulationDiverged(RuntimeError):
    """A run produced NaN or a force above the configured limit.

    ``time_s`` is the simulated time of the first bad sample and ``where``
    names the signal; the runner has already written the logs up to then.
    """

    def __init__(self, message, *, time_s, where):
        super().__init__(message)
        self.time_s = time_s
        self.where = where
