"""``handeye-jax report``: a result's figures written (thin over :mod:`handeye_jax.report`)."""

from __future__ import annotations

import argparse


def _cmd_report(args: argparse.Namespace) -> int:
    import logging

    # Matplotlib logs advice about itself (a temporary cache folder when its own cannot be
    # written, a slow first font scan); with no handler of ours it would reach stderr.
    mpl_log = logging.getLogger("matplotlib")
    if not mpl_log.handlers:
        mpl_log.addHandler(logging.NullHandler())
    from ..report import write_report

    written = write_report(args.result, args.out, args.dataset, field="--out")
    folder = written[0].parent if written else args.out
    print(f"{len(written)} figures (PNG and SVG) written to {folder}")
    return 0


def add_report_command(sub: argparse._SubParsersAction) -> None:
    """Add ``report`` to the command line's subcommands ``sub``."""
    rep = sub.add_parser(
        "report",
        help="figures (PNG and SVG) of a calibration result",
        description="Draw the data, both chains with their residuals, per-landmark errors, the "
        "DE convergence and the leave-one-out errors of a result.",
    )
    rep.add_argument("result", help="result file from 'calibrate --out'")
    rep.add_argument("--out", metavar="DIR", help="folder for the figures (default: "
                     "RESULT_report next to the result)")  # fmt: skip
    rep.add_argument(
        "--dataset",
        help="the dataset, for results that do not carry their data (default: the result's "
        "own copy)",
    )
    rep.set_defaults(func=_cmd_report)
