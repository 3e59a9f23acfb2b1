"""Command line: ``python main.py [run|list|...]``.

Exit status: 0 success, 2 bad input (one line on stderr, nothing overwritten), 3 the run
diverged (summary and states so far are still written), 4 an output could not be written (one
line per output; each keeps its old file), 5 a sweep's task failed every attempt (the others' outputs are
still written), 130 / 143 / 129 interrupted by SIGINT / SIGTERM / SIGHUP (nothing half-written is
left; a sweep keeps what finished).
"""
from __future__ import annotations

import argparse
import os
import signal
import sys

from .commands import bench, compare, demo, fit, gallery, listing, run
from .commands.common import (DEFAULT_OUT, EXIT_BAD_INPUT, EXIT_DIVERGED, EXIT_OK, EXIT_OUTPUT,  # noqa: F401
                              EXIT_REPLAY_DIFFERS, EXIT_TASKS_FAILED, EXIT_UNRELIABLE, Parser)
from . import errors
from .errors import OutputError, Terminated, UserError

# The main job (`python main.py`): the assignment's cube dropped on the plane.
DEFAULT_SCENE, DEFAULT_INTEGRATOR = "plane", "rk4"


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="main.py", description="taichi-soft: mass-spring soft bodies on Taichi")
    sub = parser.add_subparsers(dest="command", parser_class=Parser)
    for command in (run, compare, demo, bench, gallery, fit, listing):  # the order of --help
        command.add_parser(sub)
    return parser


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    errors.received.clear()
    previous = _catch_termination()
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if args.command is None:
            return main_job()
        return args.func(args)
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OutputError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_OUTPUT
    except KeyboardInterrupt as e:
        signum = e.signum if isinstance(e, Terminated) else signal.SIGINT
        print(f"interrupted ({signal.Signals(signum).name}); no output was written or replaced", file=sys.stderr)
        return 128 + signum
    except BrokenPipeError:
        # The reader of stdout went away (``main.py list | head``): stop quietly, as a shell tool does,
        # and keep Python's exit-time flush from raising the same error again.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + signal.SIGPIPE
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _catch_termination() -> dict:
    """SIGINT raises KeyboardInterrupt and SIGTERM and SIGHUP raise ``Terminated`` in the main
    thread, so a killed run drops its temporary files; each signal is also noted in
    ``errors.received`` (a swallowed exception is raised again at the next frame or output).
    Returns the old handlers."""
    def handler(signum, frame):
        errors.received.append(signum)
        raise errors.interrupt_for(signum)

    previous = {}
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        try:
            previous[signum] = signal.signal(signum, handler)
        except ValueError:  # not the main thread (main() called from a worker): leave them
            pass
    return previous


def main_job() -> int:
    """``python main.py`` with no arguments: renders the default scene to out/<scene>-<integrator>.mp4."""
    return main(["run", "--scene", DEFAULT_SCENE, "--integrator", DEFAULT_INTEGRATOR,
                 "--video", f"{DEFAULT_OUT}/{DEFAULT_SCENE}-{DEFAULT_INTEGRATOR}.mp4"])
