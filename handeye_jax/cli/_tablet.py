"""``handeye-jax tablet``: the page the tablet shows, served (thin over
:mod:`handeye_jax.tablet`)."""

from __future__ import annotations

import argparse

from ._types import output_path, port, positive_number


def _cmd_tablet(args: argparse.Namespace) -> int:
    from ..tablet import EvaluationFiles, Listen, serve

    # Trials are saved while serving: refuse an unwritable file now, not at the first save.
    output_path(args.trials, "--trials", [args.dataset, args.targets, args.result])
    listen = Listen(host=args.host, port=args.port)  # a new secret, the default deadline
    files = EvaluationFiles(targets=args.targets, result=args.result, trials=args.trials)
    return serve(args.dataset, listen=listen, files=files, ppi=args.ppi, scale=args.scale)


def add_tablet_command(sub: argparse._SubParsersAction) -> None:
    """Add ``tablet`` to the command line's subcommands ``sub``."""
    tab = sub.add_parser(
        "tablet",
        help="serve the tablet page: draw landmarks, record touches, measure touching errors",
        description="Serve the page the tablet shows. Calibration mode writes each landmark's "
        "touch_error_px (tablet px) into the dataset, changing only those values so its "
        "comments stay (previous versions kept as DATASET.<UTC time>.bak: the first and the "
        "last 50); evaluation "
        "mode saves trials of touches with their mean and max error in px and mm. Only who "
        "opens the printed URL (or scans its QR code) gets in: it carries a secret, new at "
        "each start.",
    )
    tab.add_argument(
        "--dataset",
        help="dataset whose landmarks to draw and touch errors to write (default: none; "
        "calibration mode needs it)",
    )
    tab.add_argument(
        "--host", default="127.0.0.1",
        help="address to listen on (default 127.0.0.1; 0.0.0.0 lets a tablet on the LAN in, "
        "and the page's URL is printed with this PC's LAN address)",
    )  # fmt: skip
    tab.add_argument("--port", type=port, default=8765, help="TCP port")
    tab.add_argument(
        "--targets", metavar="TARGETS.json",
        help="evaluation targets, tablet px (default: none; the page offers the dataset's "
        "landmarks or a grid)",
    )  # fmt: skip
    tab.add_argument(
        "--result", metavar="RESULT.json",
        help="the result being evaluated (default: none)",
    )  # fmt: skip
    tab.add_argument(
        "--trials", metavar="TRIALS.json",
        help="where evaluation trials are saved (default: DATASET_STEM.trials.json beside the "
        "dataset, or tablet-trials.json)",
    )  # fmt: skip
    tab.add_argument("--ppi", type=positive_number,
                     help="tablet px per inch (default: the dataset's)")  # fmt: skip
    tab.add_argument("--scale", type=positive_number,
                     help="display scale (default: the dataset's)")  # fmt: skip
    tab.set_defaults(func=_cmd_tablet, serves=True)
