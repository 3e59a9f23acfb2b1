"""Errors the command line turns into one-line messages and exit codes."""


class UserError(Exception):
    """Bad input from the user: a scene value, a flag, a path. The CLI prints it and exits 2."""


class OutputError(Exception):
    """An output file could not be written (full disk, encoder failure, ...). The old file, if
    any, is untouched; the CLI prints one line naming the output and why, and exits 4."""


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised in the main thread like Ctrl-C so every clean-up path runs."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum
