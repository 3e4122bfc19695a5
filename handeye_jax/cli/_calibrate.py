"""``handeye-jax calibrate``: a dataset fitted, or refitted from an earlier result, and its
summary printed (thin over :mod:`handeye_jax.calibration`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from .._core import SEARCH_PRESETS, InputError, write_output
from ._types import (
    MODELS,
    generations,
    landmark_indices,
    landmarks_named,
    output_path,
    population,
    positive_mm,
    resamples,
    restarts,
    seed,
)


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from ..calibration import Settings, calibrate, load_result, recalibrate, result_to_json
    from ..data import load_dataset
    from ..diagnostics import diagnose
    from ..report import format_summary

    out = output_path(args.out, "--out", [args.dataset, args.prior])
    if (args.refit or args.fix) and not args.prior:
        raise InputError(None, "--refit" if args.refit else "--fix",
                         "needs --prior OLD.result.json, the result to start from")  # fmt: skip
    if args.prior and not args.refit:
        raise InputError(None, "--refit", "name what changed: camera, tablet, pen or parameters")
    if args.accept_rig_change and not args.prior:
        raise InputError(None, "--accept-rig-change", "needs --prior OLD.result.json")
    if args.bootstrap and args.prior:
        raise InputError(None, "--bootstrap", "not with --prior: a recalibration's prior is not "
                         "resampled; bootstrap the calibration it came from")  # fmt: skip
    previous = load_result(args.prior) if args.prior else None
    model = args.model or (previous.model_name if previous else Settings().model)
    if previous is not None and model != previous.model_name:
        raise InputError(args.prior, "model",
                         f"is {previous.model_name!r}; --model says {model!r}")  # fmt: skip
    dataset = load_dataset(args.dataset)
    if args.landmarks is not None:
        dataset = _landmarks_of(dataset, args.landmarks, args.dataset)
    settings = settings_from(args, model)
    progress = not (args.quiet or args.no_progress)
    if previous is None:
        result = calibrate(dataset, settings, progress=progress)
    else:
        from ..models import get_model
        from ..problem import resolve_names

        refit = tuple(g.strip() for g in args.refit.split(",") if g.strip())
        try:
            resolve_names(get_model(model), refit)
        except ValueError as e:
            raise InputError(None, "--refit", str(e)) from None
        result = recalibrate(dataset, previous, refit, settings, fix=args.fix,
                             source=Path(args.prior).name, progress=progress,
                             accept_rig_change=args.accept_rig_change)  # fmt: skip
    if not args.no_diagnostics:
        result = diagnose(result, search=dataset.search)
    if args.bootstrap:
        from ..diagnostics import bootstrap, with_bootstrap

        result = with_bootstrap(result, bootstrap(result, args.bootstrap, progress=progress))
    summary = format_summary(result, verbose=args.verbose, quiet=args.quiet,
                             saved=None if out is None else str(out))  # fmt: skip
    if out is not None:  # before printing: a closed pipe on stdout must not lose the result
        write_output(out, result_to_json(result), "--out")
    print(summary)
    return 0


def _landmarks_of(dataset, ms: tuple[int, ...], path):
    """The dataset of landmarks ``ms`` alone (their views and touches), said in one line."""
    n = dataset.n_landmarks
    missing = [m for m in ms if m >= n]
    if missing:
        raise InputError(path, "--landmarks", f"{landmarks_named(missing)}: the dataset has "
                         f"{n} landmarks, m = 0 to {n - 1}")  # fmt: skip
    print(f"fitting {landmarks_named(ms)} of the {n} in {Path(path).name} (--landmarks)")
    return dataset.landmark_subset(ms)


def add_calibrate_command(sub: argparse._SubParsersAction) -> None:
    """Add ``calibrate`` to the command line's subcommands ``sub``."""
    from ..calibration import Settings

    d = Settings()
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
    add_settings_options(cal)
    cal.add_argument(
        "--landmarks", type=landmark_indices, metavar="M,M,...",
        help="fit these landmarks of the dataset alone, e.g. 0,4,8 (their views and touches; "
        "default: every landmark)",
    )  # fmt: skip
    _add_prior_options(cal)
    cal.add_argument(
        "--no-diagnostics", action="store_true",
        help="skip uncertainty, leave-one-out and convention check (about a second faster)",
    )  # fmt: skip
    cal.add_argument(
        "--bootstrap", type=resamples, metavar="B", default=None,
        help="after the fit, refit B resamples of the touches (and of each picture's views, "
        "with several captures) in one batch and report how far the hand commands of the "
        "stage to deploy move between them (mean and 95th percentile, mm) against the "
        "covariance's prediction and the expected touching error; stored in the result, "
        "drawn by 'report' (e.g. 200; each resample is a whole calibration; default: none)",
    )  # fmt: skip
    cal.add_argument(
        "--out", metavar="RESULT.json",
        help="write the result (JSON) here (default: nothing is saved; the summary says so)",
    )  # fmt: skip
    shown = cal.add_mutually_exclusive_group()
    shown.add_argument(
        "--quiet", action="store_true",
        help="print the verdict alone (the stage to deploy, the expected touching error, the "
        "camera and pen on the flange, whether the result was saved) and errors; no progress "
        "bars",
    )  # fmt: skip
    shown.add_argument(
        "--verbose", action="store_true",
        help="add the optimisers' detail (DE, LM, restarts), every parameter with its "
        "standard deviation, the largest residuals and the diagnostics",
    )  # fmt: skip
    cal.add_argument("--no-progress", action="store_true", help="no progress bars on stderr")
    cal.set_defaults(func=_cmd_calibrate, imports=("calibration.calibrate", "data.load_dataset",
                                                    "diagnostics.diagnose"))  # fmt: skip


def settings_from(args: argparse.Namespace, model: str):
    """The :class:`~handeye_jax.Settings` of the options :func:`add_settings_options` adds."""
    from ..calibration import Settings

    return Settings(
        model=model,
        seed=args.seed,
        population=args.population,
        generations=args.generations,
        early_stop=not args.no_early_stop,
        restarts=args.restarts,
        loss=args.loss,
        loss_scale_mm=args.loss_scale_mm,
        search=args.search,
    )


def add_settings_options(cal: argparse.ArgumentParser) -> None:
    """The fit's settings as options (seed, DE budget, loss, restarts)."""
    from ..calibration import Settings

    d = Settings()
    cal.add_argument("--seed", type=seed, default=d.seed, help="PRNG seed")
    cal.add_argument(
        "--population", type=population, default=d.population,
        help="DE population N, both stages",
    )  # fmt: skip
    cal.add_argument(
        "--generations", type=generations, default=d.generations,
        help="most DE generations G, both stages",
    )  # fmt: skip
    cal.add_argument(
        "--no-early-stop", action="store_true",
        help="run all generations instead of stopping when the population has converged",
    )  # fmt: skip
    cal.add_argument(
        "--loss", choices=("ml", "l1", "huber", "cauchy"), default=d.loss,
        help="ml: maximum likelihood under the noise model, its scales estimated from the data "
        "(default; the only loss whose uncertainty and expected error are validated); l1: the "
        "paper's mean error length (reproduces its tables); huber / cauchy: robust to outliers",
    )  # fmt: skip
    cal.add_argument(
        "--loss-scale-mm", type=positive_mm, default=d.loss_scale_mm, metavar="MM",
        help="robust loss scale, mm; errors above 3x it are flagged",
    )  # fmt: skip
    cal.add_argument(
        "--search", choices=SEARCH_PRESETS, default=None,
        help="where stage 1's search ranges come from: estimate, a box around a closed-form "
        "estimate of the rig from the data, as wide as its uncertainty (no ranges to guess); "
        "paper, the paper's Tables 5 and 6; the dataset's [search] ranges override either "
        "(default: the dataset's [search] preset, else estimate)",
    )  # fmt: skip
    cal.add_argument(
        "--restarts", type=restarts, default=d.restarts,
        help="LM restarts per stage besides the best DE member (other optima of the final "
        "population, then Latin-hypercube starts); 0 runs none",
    )  # fmt: skip


def _add_prior_options(cal: argparse.ArgumentParser) -> None:
    """``--prior``, ``--refit`` and ``--fix``: a recalibration."""
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
