"""Errors the command line turns into one-line messages and exit codes."""
import signal


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


# The signals the command line's handlers were given during this command (cli.main clears it).
# Kept beside the exception they raise because a library can swallow that exception: a bare
# ``except:`` in Python code the main thread happens to be in when the signal arrives (Taichi has
# several). A Ctrl-C to an overlapped run was once lost that way under load: the run finished and
# exited 0. ``raise_if_interrupted`` at each frame and before any output is written raises it again.
received: list[int] = []


def interrupt_for(signum: int) -> KeyboardInterrupt:
    """The exception a handler raises for ``signum``: KeyboardInterrupt for SIGINT, else Terminated."""
    return KeyboardInterrupt() if signum == signal.SIGINT else Terminated(signum)


def raise_if_interrupted():
    """Raise the interrupt of a signal received during this command, if any (see ``received``)."""
    if received:
        raise interrupt_for(received[-1])
