"""``handeye-jax``: a thin command line over the Python API.

Every failure caused by input prints one line naming the file and field and exits with
status 2; nothing is written unless it is complete. Ctrl-C at any moment before the outputs
are written ends the run with status 130 and every file as it was (``_interrupt.py``).

This module imports no JAX at its top, so that the Ctrl-C handling is in place before the
second or more that importing JAX takes.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from . import _interrupt
from ._atomic import check_output, write_output
from ._errors import InputError
from ._validate import MAX_GENERATIONS, MAX_POPULATION, MAX_RESTARTS, parse_float, parse_int

PROG = "handeye-jax"
#: The models ``--model`` offers: ``models.model_registry()`` (JAX) names the same (tested).
MODELS = ("dh", "htm")


class _HelpFormatter(argparse.HelpFormatter):
    """Every option's help ends with its default, unless the help already names it."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if not action.option_strings or "default" in text.lower():
            return text
        if action.default is False and action.nargs == 0:  # a flag: off unless given
            return f"{text} (default: off)"
        if action.default is None or action.default is argparse.SUPPRESS:
            return text  # such options say in their help what happens without them
        return f"{text} (default: %(default)s)"


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str):  # one line, no usage block
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("handeye-jax")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "0+unknown"


def _whole_number(text: str) -> int:
    try:
        return parse_int(text)  # ASCII digits only
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None


def _positive_int(text: str) -> int:
    v = _whole_number(text)
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1 (got {v})")
    return v


def _population(text: str) -> int:
    v = _positive_int(text)
    if v < 4:
        raise argparse.ArgumentTypeError(f"DE/rand/1 needs at least 4 members (got {v})")
    if v > MAX_POPULATION:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_POPULATION:,} (got {v})")
    return v


def _generations(text: str) -> int:
    v = _positive_int(text)
    if v > MAX_GENERATIONS:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_GENERATIONS:,} (got {v})")
    return v


def _positive_number(text: str) -> float:
    try:
        v = parse_float(text)  # ASCII only
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0 < v < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0 (got {text})")
    return v


def _restarts(text: str) -> int:
    v = _whole_number(text)
    if not 0 <= v <= MAX_RESTARTS:
        raise argparse.ArgumentTypeError(f"must be 0 to {MAX_RESTARTS:,} (got {v})")
    return v


def _seed(text: str) -> int:
    v = _whole_number(text)
    if not 0 <= v < 2**63:  # as simulate's: the diagnostics seed numpy's generators with it
        why = f"must be 0 to 2^63 - 1: numpy's generators take no other seed (got {v})"
        raise argparse.ArgumentTypeError(why)
    return v


def _output_path(
    path: str | Path | None, option: str = "--out", inputs: Sequence[str | Path | None] = ()
) -> Path | None:
    """The output file of ``option``, checked before the work: its folder exists and can be
    written, and it is not a folder nor one of the command's ``inputs``."""
    return None if path is None else check_output(path, option, inputs)


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from ._calibrate import Settings, calibrate, diagnose, recalibrate
    from ._dataset_io import load_dataset
    from ._result_io import load_result, result_to_json
    from ._summary import format_summary

    out = _output_path(args.out, "--out", [args.dataset, args.prior])
    if (args.refit or args.fix) and not args.prior:
        raise InputError(None, "--refit" if args.refit else "--fix",
                         "needs --prior OLD.result.json, the result to start from")  # fmt: skip
    if args.prior and not args.refit:
        raise InputError(None, "--refit", "name what changed: camera, tablet, pen or parameters")
    if args.accept_rig_change and not args.prior:
        raise InputError(None, "--accept-rig-change", "needs --prior OLD.result.json")
    previous = load_result(args.prior) if args.prior else None
    model = args.model or (previous.model_name if previous else Settings().model)
    if previous is not None and model != previous.model_name:
        raise InputError(args.prior, "model",
                         f"is {previous.model_name!r}; --model says {model!r}")  # fmt: skip
    dataset = load_dataset(args.dataset)
    settings = Settings(
        model=model,
        seed=args.seed,
        population=args.population,
        generations=args.generations,
        early_stop=not args.no_early_stop,
        restarts=args.restarts,
        loss=args.loss,
        loss_scale_mm=args.loss_scale_mm,
    )
    if previous is None:
        result = calibrate(dataset, settings, progress=not args.quiet)
    else:
        from ._params import resolve_names
        from .models import get_model

        refit = tuple(g.strip() for g in args.refit.split(",") if g.strip())
        try:
            resolve_names(get_model(model), refit)
        except ValueError as e:
            raise InputError(None, "--refit", str(e)) from None
        result = recalibrate(dataset, previous, refit, settings, fix=args.fix,
                             source=Path(args.prior).name, progress=not args.quiet,
                             accept_rig_change=args.accept_rig_change)  # fmt: skip
    if not args.no_diagnostics:
        result = diagnose(result, search=dataset.search)
    print(format_summary(result))
    if out is not None:
        write_output(out, result_to_json(result), "--out")
        print(f"result written to {out}")
    return 0


def _cmd_predict(args: argparse.Namespace) -> int:
    from ._predict import check_reach, points_csv_text, read_capture_columns, read_points_csv
    from ._predictor import Predictor, result_reach, stored_result

    out = _output_path(args.out, "--out", [args.result, args.points])
    checked = stored_result(args.result)  # NumPy only: no JAX for a file as it was written
    if checked is None:  # older or edited: validated, its frames checked against its parameters
        _start_jax()
        from ._compute_frames import load_frames

        checked = (load_frames(args.result), result_reach(args.result))
    predictor = Predictor.from_frames(*checked)
    header, rows, values = read_points_csv(args.points)
    position, angle = read_capture_columns(args.points, header, rows)
    hand_xy = predictor.hand_command(values[:, :2], values[:, 2], values[:, 3], stage=args.stage,
                                     capture_position_mm=position, capture_hand_angle_deg=angle,
                                     axes=predictor.axes)  # fmt: skip
    check_reach(args.points, hand_xy, predictor.reach.including(position), args.result)
    text = points_csv_text(header, rows, hand_xy)
    if out is None:
        sys.stdout.write(text)
    else:
        write_output(out, text, "--out")
        print(f"{len(rows)} hand commands (stage {args.stage}, mm) written to {out}")
    return 0


def _cmd_tablet(args: argparse.Namespace) -> int:
    from .tablet import serve

    # Trials are saved while serving: refuse an unwritable file now, not at the first save.
    _output_path(args.trials, "--trials", [args.dataset, args.targets, args.result])
    return serve(
        args.dataset, host=args.host, port=args.port, targets=args.targets,
        result=args.result, trials_path=args.trials, ppi=args.ppi, scale=args.scale,
    )  # fmt: skip


def _port(text: str) -> int:
    try:
        v = parse_int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 0 <= v <= 65535:
        raise argparse.ArgumentTypeError(f"must be 0 to 65535 (got {v})")
    return v


def _positive_mm(text: str) -> float:
    try:
        v = parse_float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not v > 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite length > 0 mm (got {text})")
    return v


def _cmd_report(args: argparse.Namespace) -> int:
    import logging

    # Matplotlib logs advice about itself (a temporary cache folder when its own cannot be
    # written, a slow first font scan); with no handler of ours it would reach stderr.
    mpl_log = logging.getLogger("matplotlib")
    if not mpl_log.handlers:
        mpl_log.addHandler(logging.NullHandler())
    from ._report import write_report

    written = write_report(args.result, args.out, args.dataset, field="--out")
    folder = written[0].parent if written else args.out
    print(f"{len(written)} figures (PNG and SVG) written to {folder}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    # Nothing here imports JAX, OpenCV, matplotlib or tomlkit: the commands do, when they run.
    from ._cli_dataset import add_dataset_commands
    from ._cli_export import add_export_command
    from ._cli_twin import add_twin_commands
    from ._settings import Settings

    d = Settings()
    parser = _Parser(
        prog=PROG,
        description="Hand-eye calibration of a camera + pen end-effector from tablet landmarks.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    cal = sub.add_parser(
        "calibrate",
        help="fit the model (stage 1) and the affine correction (stage 2) to a dataset",
        description="Fit a dataset by DE + Levenberg-Marquardt in two stages. The paper's own "
        "settings are --population 10000 --generations 10000 --no-early-stop.",
    )
    cal.add_argument("dataset", help="dataset file (handeye-jax.dataset TOML; mm, deg, px)")
    cal.add_argument(
        "--model", choices=MODELS, default=None,
        help=f"the transform chain: htm, six-DoF transforms (eqs. 1-8); dh, the "
        f"Denavit-Hartenberg variant (eqs. 12-16) (default: {d.model}, or --prior's)",
    )  # fmt: skip
    cal.add_argument("--seed", type=_seed, default=d.seed, help="PRNG seed")
    cal.add_argument(
        "--population", type=_population, default=d.population,
        help="DE population N, both stages",
    )  # fmt: skip
    cal.add_argument(
        "--generations", type=_generations, default=d.generations,
        help="most DE generations G, both stages",
    )  # fmt: skip
    cal.add_argument(
        "--no-early-stop", action="store_true",
        help="run all generations instead of stopping when the population has converged",
    )  # fmt: skip
    cal.add_argument(
        "--loss", choices=("l1", "huber", "cauchy"), default=d.loss,
        help="l1: the paper's mean error length (default); huber / cauchy: robust to outliers",
    )  # fmt: skip
    cal.add_argument(
        "--loss-scale-mm", type=_positive_mm, default=d.loss_scale_mm, metavar="MM",
        help="robust loss scale, mm; errors above 3x it are flagged",
    )  # fmt: skip
    cal.add_argument(
        "--restarts", type=_restarts, default=d.restarts,
        help="LM restarts per stage besides the best DE member (other optima of the final "
        "population, then Latin-hypercube starts); 0 runs none",
    )  # fmt: skip
    cal.add_argument(
        "--prior", metavar="OLD.result.json",
        help="recalibrate from this earlier result of the same rig (default: none, calibrate "
        "from scratch): the parameters not in --refit take its posterior as their prior",
    )  # fmt: skip
    cal.add_argument(
        "--refit", metavar="GROUPS",
        help="with --prior: what changed, comma-separated groups (camera, tablet, pen) or "
        "parameter names, searched afresh (default: none)",
    )  # fmt: skip
    cal.add_argument(
        "--fix", action="store_true",
        help="with --prior: hold the parameters not in --refit at its values instead of "
        "giving them its posterior as a prior",
    )  # fmt: skip
    cal.add_argument(
        "--accept-rig-change", action="store_true",
        help="with --prior: accept data whose intrinsics (fx, fy, cx, cy), tablet ppi or "
        "scale, or hand-angle convention differ from the prior's (e.g. a re-calibrated "
        "camera); the summary and the result say so. Without it they are refused",
    )  # fmt: skip
    cal.add_argument(
        "--no-diagnostics", action="store_true",
        help="skip uncertainty, leave-one-out and convention check (about a second faster)",
    )  # fmt: skip
    cal.add_argument(
        "--out", metavar="RESULT.json",
        help="write the result (JSON) here (default: print the summary only)",
    )  # fmt: skip
    cal.add_argument("--quiet", action="store_true", help="no progress bars on stderr")
    cal.set_defaults(func=_cmd_calibrate, imports=("._calibrate", "._dataset_io", "._result_io"))
    add_twin_commands(sub)  # simulate, detect, evaluate
    add_export_command(sub)
    add_dataset_commands(sub)  # convert, plan

    pre = sub.add_parser(
        "predict",
        help="hand commands for image points",
        description="Read a CSV with header u,v,depth,hand_angle (px, px, mm, deg) and write it "
        "back with hand_x,hand_y (mm, robot base frame) added: where to send the hand so "
        "that the pen touches each point; and hand_z (mm) when the calibration's touches "
        "recorded the hand's heights. Optional columns capture_x,capture_y,capture_z (mm) "
        "and capture_angle (deg): the hand pose each point's picture was taken from "
        "(default: the calibration's first capture).",
    )
    pre.add_argument("result", help="result file from 'calibrate --out'")
    pre.add_argument("points", help="CSV with header u,v,depth,hand_angle")
    pre.add_argument(
        "--out", metavar="OUT.csv", help="write the CSV here (default: standard output)"
    )
    pre.add_argument(
        "--stage", type=_whole_number, choices=(1, 2), default=2,
        help="2: eq. (25) with the affine correction (default); 1: eq. (8), model only",
    )  # fmt: skip
    pre.set_defaults(func=_cmd_predict, jax=False)  # only for files it must check (see there)

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
    tab.add_argument("--port", type=_port, default=8765, help="TCP port")
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
    tab.add_argument("--ppi", type=_positive_number,
                     help="tablet px per inch (default: the dataset's)")  # fmt: skip
    tab.add_argument("--scale", type=_positive_number,
                     help="display scale (default: the dataset's)")  # fmt: skip
    tab.set_defaults(func=_cmd_tablet, serves=True)
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
    return parser


def _start_jax(*modules: str, announce: bool = False) -> None:
    """Before JAX's first computation: XLA's flags and the persistent compilation cache (and
    ``announce`` each program compiled for it); the command's ``modules`` (names relative to
    this package) imported."""
    with _interrupt.deferred():  # the imports take a second or more: Ctrl-C waits for them
        from ._xla import vectorise_small_loops

        vectorise_small_loops()
        _enable_compilation_cache(announce)
        for name in modules:
            importlib.import_module(name, __package__)


def _enable_compilation_cache(announce: bool = False) -> None:
    """Keep XLA's compiled programs between runs, so only the first run pays for compiling.

    The command line owns its process, so it may set this global JAX option; the library does
    not. ``HANDEYE_JAX_CACHE_DIR`` moves the cache; ``HANDEYE_JAX_CACHE_DIR=off`` turns it off.
    """
    where = os.environ.get("HANDEYE_JAX_CACHE_DIR")
    if where == "off":
        return
    if where is None:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        where = os.path.join(base, "handeye-jax", "xla")
    try:
        os.makedirs(where, exist_ok=True)
    except OSError:
        return  # an unwritable cache only costs time
    import jax

    from ._xla import store_programs

    jax.config.update("jax_compilation_cache_dir", where)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    # Beside XLA's compiled code, the programs themselves: a warm run neither traces nor lowers.
    store_programs(os.path.join(where, "programs"), _announce if announce else None)


def _announce(name: str) -> None:
    from tqdm import tqdm  # above a progress bar, if one is drawn

    short = name.rsplit(".", 1)[-1].lstrip("_")
    tqdm.write(f"compiling {short} for this machine (once: later runs load it)", file=sys.stderr)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line on ``argv`` (default: ``sys.argv[1:]``); returns the exit status."""
    with _interrupt.recording_interrupts():
        try:
            return _run_command(argv)
        except KeyboardInterrupt:  # Ctrl-C or SIGTERM
            what, code = _interrupt.stopped_by()
            print(f"{PROG}: {what}; nothing was written", file=sys.stderr)
            return code


def _run_command(argv: Sequence[str] | None) -> int:
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if getattr(args, "serves", False):  # a server: Ctrl-C is how it ends, after its saves
            _interrupt.stop_recording()
        if getattr(args, "jax", True):
            announce = getattr(args, "quiet", True) is False  # calibrate, unless --quiet
            _start_jax(*getattr(args, "imports", ()), announce=announce)
        code = args.func(args)
        _interrupt.check()  # a Ctrl-C that a callback swallowed, and nothing written since
        return code
    except InputError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    except Exception as e:  # the user gets one line; developers can ask for the traceback
        if _interrupt.pending():  # a Ctrl-C that C++ code turned into another error
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
