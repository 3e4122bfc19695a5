"""``handeye-jax calibrate-batch``: many datasets calibrated in one batch, their results written
into a folder with a summary table (thin over :func:`handeye_jax.calibrate_batch`); under
``--coordinator`` one batch split over several processes (``jax.distributed``)."""

from __future__ import annotations

import argparse
import glob
import sys
from pathlib import Path

from .._core import BATCH_WAVE, InputError, check_folder_output, write_folder_atomic
from ._calibrate import add_settings_options, settings_from
from ._types import MODELS, positive_int, whole_number

#: The summary table's file in the results folder.
SUMMARY = "summary.csv"
#: How a dataset file is found in a folder (its sub-folders too: a twin's dataset.toml).
PATTERN = "**/*.toml"


def dataset_files(where: str) -> list[Path]:
    """The dataset files ``where`` names: every ``.toml`` file in a folder and its sub-folders,
    or the files a glob pattern matches, sorted."""
    if Path(where).is_dir():
        files = sorted(Path(where).glob(PATTERN))
    else:
        files = sorted(Path(p) for p in glob.glob(where, recursive=True))
    files = [f for f in files if f.is_file()]
    if not files:
        raise InputError(where, "", "no dataset files (a folder of *.toml files, or a glob "
                                    "pattern such as 'twins/*/dataset.toml')")  # fmt: skip
    return files


def result_names(files: list[Path]) -> list[str]:
    """Each dataset's result file name: ``STEM.result.json``, or the path's folders joined by
    ``-`` where stems repeat (``twin1/dataset.toml`` -> ``twin1-dataset.result.json``)."""
    stems = [f.stem for f in files]
    if len(set(stems)) == len(stems):
        return [f"{s}.result.json" for s in stems]
    parents = [f.resolve().parent.parts for f in files]
    shared = 0
    while all(len(p) > shared and p[shared] == parents[0][shared] for p in parents):
        shared += 1
    names = ["-".join((*f.resolve().parent.parts[shared:], f.stem)) + ".result.json"
             for f in files]  # fmt: skip
    seen: dict[str, Path] = {}
    for f, name in zip(files, names, strict=True):
        if name in seen:
            raise InputError(f, "", f"its result would be {name}, as {seen[name]}'s: rename one")
        seen[name] = f
    return names


def _cmd_calibrate_batch(args: argparse.Namespace) -> int:
    import jax

    if args.processes > 1 and not args.coordinator:
        raise InputError(None, "--processes", "needs --coordinator HOST:PORT (process 0's)")
    if args.process_id >= args.processes:
        raise InputError(None, "--process-id", f"must be 0 to {args.processes - 1} "
                                               f"(got {args.process_id})")  # fmt: skip
    if args.coordinator:
        jax.distributed.initialize(args.coordinator, num_processes=args.processes,
                                   process_id=args.process_id)  # fmt: skip
    from ..calibration import calibrate_batch, result_to_json
    from ..data import load_dataset

    files = dataset_files(args.datasets)
    names = result_names(files)
    check_folder_output(args.out, [*names, SUMMARY], "--out", files)
    lead = jax.process_index() == 0
    datasets, kept, skipped = [], [], {}
    for i, f in enumerate(files):
        try:
            datasets.append(load_dataset(f))
            kept.append(i)
        except InputError as e:
            skipped[i] = str(e)
    settings = settings_from(args, args.model)
    results = calibrate_batch(datasets, settings, progress=lead and not args.quiet,
                              wave=args.wave, errors="return")  # fmt: skip
    outputs, rows = {}, []
    done = dict(zip(kept, results, strict=True))
    for i, f in enumerate(files):
        r = done.get(i)
        if r is None or isinstance(r, InputError):
            skipped.setdefault(i, str(r))
            rows.append((str(f), "", "", "", "", "skipped: " + skipped[i]))
            continue
        outputs[names[i]] = result_to_json(r).encode("utf-8")
        rows.append((str(f), str(r.data.n_rows), f"{r.stage1.F:.4f}", f"{r.stage2.F:.4f}",
                     f"{r.timings_s['total']:.3f}", names[i]))  # fmt: skip
    if not lead:
        return 2 if skipped else 0
    for i in sorted(skipped):
        print(f"{files[i]}: skipped: {skipped[i]}", file=sys.stderr)
    outputs[SUMMARY] = _csv(rows).encode("utf-8")
    write_folder_atomic(args.out, outputs, "--out")
    print(_table(rows))
    print(f"{len(files) - len(skipped)} of {len(files)} datasets calibrated; results and "
          f"{SUMMARY} written to {args.out}")  # fmt: skip
    return 2 if skipped else 0


_HEAD = ("dataset", "rows", "F1_mm", "F2_mm", "time_s", "result")


def _csv(rows) -> str:
    import csv
    import io

    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(_HEAD)
    writer.writerows(rows)
    return out.getvalue()


def _table(rows) -> str:
    """The summary as aligned text (a skipped dataset's reason cut to one short line)."""
    shown = [(*r[:5], r[5] if len(r[5]) < 60 else r[5][:57] + "...") for r in rows]
    widths = [max(len(str(c)) for c in col) for col in zip(_HEAD, *shown, strict=True)]
    lines = ["  ".join(str(c).ljust(w) for c, w in zip(row, widths, strict=True)).rstrip()
             for row in (_HEAD, *shown)]  # fmt: skip
    return "\n".join(lines)


def add_calibrate_batch_command(sub: argparse._SubParsersAction) -> None:
    """Add ``calibrate-batch`` to the command line's subcommands ``sub``."""
    from ..calibration import Settings

    cal = sub.add_parser(
        "calibrate-batch",
        help="calibrate many datasets in one batch (each as calibrate would, bit for bit)",
        description="Fit every dataset of a folder or glob pattern in one batch, each step of "
        "both stages one compiled program for many problems, sharded over this machine's "
        "devices, or over several machines' with --coordinator. Each result is the one "
        "calibrate (without diagnostics) gives for that dataset alone. A dataset that fails "
        "validation is named in one line and skipped (exit status 2); the others still run.",
    )
    cal.add_argument(
        "datasets", metavar="DIR_OR_GLOB",
        help="a folder (every *.toml in it and its sub-folders) or a quoted glob pattern",
    )  # fmt: skip
    cal.add_argument(
        "--out", metavar="RESULTS_DIR", required=True,
        help=f"write each result (NAME.result.json) and {SUMMARY} into this folder "
        "(created if missing; files of the same names are replaced)",
    )  # fmt: skip
    cal.add_argument("--model", choices=MODELS, default=Settings().model,
                     help="the transform chain (htm or dh)")  # fmt: skip
    add_settings_options(cal)
    cal.add_argument(
        "--wave", type=positive_int, default=BATCH_WAVE,
        help="the most problems per device fitted at once (memory against speed)",
    )  # fmt: skip
    cal.add_argument(
        "--coordinator", metavar="HOST:PORT",
        help="run as one of --processes processes (jax.distributed): the address of process "
        "0, which prints and writes the results; each process fits its share (default: one "
        "process, this machine's devices)",
    )  # fmt: skip
    cal.add_argument("--processes", type=positive_int, default=1,
                     help="with --coordinator: how many processes share the batch")  # fmt: skip
    cal.add_argument("--process-id", type=lambda t: whole_number(t, 0), default=0,
                     help="with --coordinator: this process's number, 0 to --processes - 1")
    cal.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    cal.set_defaults(func=_cmd_calibrate_batch,
                     imports=("calibration.calibrate_batch", "data.load_dataset"))  # fmt: skip
