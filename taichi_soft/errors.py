"""Errors the command line turns into one-line messages and exit codes."""


class UserError(Exception):
    """Bad input from the user: a scene value, a flag, a path. The CLI prints it and exits 2."""


class SimulationDiverged(Exception):
    """Raised by callers that want an exception when a run blows up (the CLI exits 3)."""
