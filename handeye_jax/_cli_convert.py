"""``handeye-jax convert``: a version-1 dataset written as version 2 (thin over the API)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._atomic import check_output, same_file
from ._dataset_io import FORMAT_V2, backup_path, convert_path, convert_to_v2, load_dataset
from ._errors import InputError


def _cmd_convert(args: argparse.Namespace) -> int:
    old = Path(args.dataset)
    ds = load_dataset(old)
    if ds.version == 2:  # nothing to do is not a failure: scripts may convert unconditionally
        print(f"{old} is already {FORMAT_V2}; nothing written")
        return 0
    out = Path(args.out) if args.out is not None else convert_path(old)
    in_place = out.exists() and same_file(out, old)
    if in_place and not args.force:
        raise InputError(out, "--out", "is the dataset itself; give --force to convert it in "
                         "place (the old file is kept as a .bak beside it)")  # fmt: skip
    check_output(out, "--out", [] if in_place else [old])
    kept = None
    if out.exists():
        if not args.force:
            raise InputError(out, "--out", "exists; give --force to replace it (the old file "
                             "is kept as a .bak beside it) or choose another --out")  # fmt: skip
        kept = backup_path(out)
    convert_to_v2(old, out, overwrite=args.force, backup=kept)
    print(
        f"{old} converted to {FORMAT_V2}: {out} ({ds.n_landmarks} landmarks, 1 capture, "
        f"{ds.n_touches} touches)" + (f"; previous {out.name} kept as {kept}" if kept else "")
    )
    return 0


def add_convert_command(sub: argparse._SubParsersAction) -> None:
    """Add ``convert`` to the command line's subcommands ``sub``."""
    p = sub.add_parser(
        "convert",
        help="write a version-1 dataset as handeye-jax.dataset/2",
        description="Read a handeye-jax.dataset/1 file (the paper's single capture) and write "
        "the same data as handeye-jax.dataset/2: one [[captures]] at the hand angle where "
        "phi = 0, one [[touches]] per landmark. The values are identical (it calibrates to "
        "the same result); comments are not carried over. A file that is already version 2 "
        "is left alone (exit 0).",
    )
    p.add_argument("dataset", help="the version-1 dataset (TOML)")
    p.add_argument(
        "--out", metavar="NEW.toml",
        help="where to write (default: NAME.v2.toml beside NAME.toml); may be the dataset "
        "itself with --force",
    )  # fmt: skip
    p.add_argument(
        "--force", action="store_true",
        help="replace an existing --out (also the dataset itself); the replaced file is kept "
        "as OUT.<UTC time>.bak",
    )  # fmt: skip
    p.set_defaults(func=_cmd_convert)
