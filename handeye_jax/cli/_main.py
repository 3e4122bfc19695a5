"""``handeye-jax``: a thin command line over the Python API.

Every failure caused by input prints one line naming the file and field and exits with
status 2; nothing is written unless it is complete. Ctrl-C at any moment before the outputs
are written ends the run with status 130 and every file as it was (``interrupts.py``).

This module imports no JAX at its top, so that the Ctrl-C handling is in place before the
second or more that importing JAX takes. Each command group has its module (``_calibrate``,
``_batch``, ``_twin``, ``_plan``, ``_vision``, ``_robot``, ``_dataset``, ``_tablet``,
``_report``); the argument types they share are in ``_types``.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence

from .._core import InputError, interrupts, package_version
from ._runtime import start_jax
from ._types import MODELS, PROG, Parser

__all__ = ["MODELS", "PROG", "build_parser", "main", "run"]


class _Version(argparse.Action):
    """``--version``: the installed version, read only when asked (the package metadata's
    reader cost every command's start about a fifth: benchmarks/RESULTS.md)."""

    def __call__(self, parser, namespace, values, option_string=None):
        sys.stdout.write(f"{parser.prog} {package_version()}\n")  # as argparse's own does
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    # Nothing here imports JAX, OpenCV, matplotlib or tomlkit: the commands do, when they run.
    from ._batch import add_calibrate_batch_command
    from ._calibrate import add_calibrate_command
    from ._dataset import add_dataset_commands
    from ._plan import add_plan_acquisition_command
    from ._report import add_report_command
    from ._robot import add_export_command, add_predict_command
    from ._robot_input import add_robot_input_commands
    from ._tablet import add_tablet_command
    from ._twin import add_evaluate_command, add_simulate_command
    from ._vision import add_detect_command

    parser = Parser(
        prog=PROG,
        description="Hand-eye calibration of a camera + pen end-effector from tablet landmarks.",
    )
    parser.add_argument("--version", action=_Version, nargs=0,
                        help="show the program's version number and exit")  # fmt: skip
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    for add in (add_calibrate_command, add_calibrate_batch_command, add_simulate_command,
                add_detect_command, add_evaluate_command, add_export_command,
                add_dataset_commands, add_robot_input_commands, add_predict_command,
                add_plan_acquisition_command, add_tablet_command, add_report_command):  # fmt: skip
        add(sub)  # in this order in --help
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line on ``argv`` (default: ``sys.argv[1:]``); returns the exit status."""
    with interrupts.recording_interrupts():
        try:
            return _run_command(argv)
        except KeyboardInterrupt:  # Ctrl-C or SIGTERM
            what, code = interrupts.stopped_by()
            print(f"{PROG}: {what}; nothing was written", file=sys.stderr)
            return code


def _run_command(argv: Sequence[str] | None) -> int:
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if getattr(args, "serves", False):  # a server: Ctrl-C is how it ends, after its saves
            interrupts.stop_recording()
        if getattr(args, "jax", True):
            # calibrate, unless --quiet or --no-progress
            announce = not (getattr(args, "quiet", True) or getattr(args, "no_progress", False))
            start_jax(*getattr(args, "imports", ()), announce=announce)
        code = args.func(args)
        interrupts.check()  # a Ctrl-C that a callback swallowed, and nothing written since
        return code
    except InputError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # `... | head`: the reader has what it wanted; files are complete
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # 128 + SIGPIPE, as a shell tool killed by the closed pipe reports
    except Exception as e:  # the user gets one line; developers can ask for the traceback
        if interrupts.pending():  # a Ctrl-C that C++ code turned into another error
            raise KeyboardInterrupt from None
        if os.environ.get("HANDEYE_JAX_DEBUG"):
            raise
        what = " ".join(str(e).split())  # one line, even for OpenCV's multi-line messages
        print(
            f"{PROG}: internal error: {type(e).__name__}: {what} "
            "(set HANDEYE_JAX_DEBUG=1 for the traceback)",
            file=sys.stderr,
        )
        return 1


def run() -> None:
    """The console script: :func:`main`, then an exit that skips the interpreter's teardown.

    Everything the command writes is complete by then (files atomically, streams flushed
    here), but a normal exit also tears down XLA's compiled programs, which took 0.4–0.7 s of
    every command on the 2-core machine. ``HANDEYE_JAX_DEBUG=1`` keeps the normal exit, for
    profilers and coverage tools that report at exit.
    """
    code = main()
    if os.environ.get("HANDEYE_JAX_DEBUG"):
        sys.exit(code)
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except OSError:  # e.g. a closed pipe: the output is gone either way
        code = code or 1
    os._exit(code)


if __name__ == "__main__":
    run()
