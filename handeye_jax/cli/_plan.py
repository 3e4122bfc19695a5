"""``handeye-jax plan-acquisition``: the expected error of candidate acquisitions before they
are taken, and the cheapest one that meets a target (thin over :mod:`handeye_jax.twin`'s
planner)."""

from __future__ import annotations

import argparse
from pathlib import Path

from .._core import InputError, parse_numbers
from ._types import population, positive_mm, seed, whole_number

#: The most landmarks per side of a candidate grid, and the most pictures.
MAX_GRID = 12
MAX_PICTURES = 8
#: The most Monte Carlo twins per candidate.
MAX_TWINS = 1000


def _counts(lo: int, hi: int):
    def parse(text: str) -> tuple[int, ...]:
        try:
            values = parse_numbers(text, hi, "")
        except ValueError:
            values = None
        if not values or any(v != int(v) or not lo <= v <= hi for v in values):
            raise argparse.ArgumentTypeError(
                f"expected whole numbers {lo} to {hi} separated by commas (got {text!r})")
        return tuple(sorted({int(v) for v in values}))

    return parse


def _twins(text: str) -> int:
    return whole_number(text, 2, MAX_TWINS)


def _load_rig(path: Path):
    """The rig from a dataset (.toml), a result or a twin's truth (.json)."""
    from .._core import load_json
    from ..calibration import load_result
    from ..data import load_dataset
    from ..twin import load_truth, planning_truth

    if path.suffix.lower() == ".json":
        doc = load_json(path)
        if isinstance(doc, dict) and str(doc.get("format", "")).startswith(
            "handeye-jax.twin-truth"
        ):
            return load_truth(path)
        source = load_result(path)
        field = "data"
    else:
        source = load_dataset(path)
        field = "captures"
    try:
        return planning_truth(source)
    except ValueError as e:
        raise InputError(path, field, f"cannot plan from it: {e}") from None


def _cmd_plan_acquisition(args: argparse.Namespace) -> int:
    from ..problem import get_noise_model
    from ..twin import (
        grid_acquisition,
        monte_carlo_acquisition,
        optimise_layout,
        predict_acquisition,
        recommend,
    )

    path = Path(args.source)
    truth = _load_rig(path)
    noise = get_noise_model(args.noise)
    candidates = []
    for n in args.grid:
        for c in args.captures:
            try:
                acq = grid_acquisition(truth, n, c, seed=args.seed)
            except ValueError as e:
                raise InputError(path, "--captures", f"{n}x{n} with {c} pictures: {e}") from None
            candidates.append(acq)
            if args.optimise:
                candidates.append(optimise_layout(truth, acq, noise).acquisition)
    lin = [predict_acquisition(truth, a, noise) for a in candidates]
    mc = None
    if args.monte_carlo:
        from ..calibration import Settings

        settings = Settings(seed=args.seed, population=args.population)
        mc = [monte_carlo_acquisition(truth, a, args.monte_carlo, noise, settings=settings,
                                      seed=args.seed, progress=not args.quiet)
              for a in candidates]  # fmt: skip
    print(_table(lin, mc, args.stage))
    if args.target_mm is not None:
        chosen = recommend(mc or lin, args.target_mm, args.stage)
        how = "Monte Carlo" if mc else "linearised"
        if chosen is None:
            print(f"no candidate meets {args.target_mm:g} mm (stage {args.stage}, {how} mean); "
                  "try more touches (--grid) or pictures (--captures)")  # fmt: skip
        else:
            e = chosen.stage(args.stage)
            print(f"recommended: {chosen.name} ({chosen.touches} touches, {chosen.pictures} "
                  f"picture{'s' if chosen.pictures > 1 else ''}): stage {args.stage} "
                  f"{how} mean {e.mean_mm:.3f} mm <= {args.target_mm:g} mm")  # fmt: skip
    return 0


def _table(lin, mc, stage: int) -> str:
    head = ("| candidate | touches | pictures | stage 1 mean / p95 mm | stage 2 mean / p95 mm |"
            + (" MC stage 1 mean / p95 mm | MC stage 2 mean / p95 mm | MC twins |" if mc else ""))
    lines = ["expected held-out touching error (hand command x-y), linearised"
             + (" and Monte Carlo (MC)" if mc else ""), "", head,
             "|" + "---|" * (head.count("|") - 1)]  # fmt: skip
    for i, e in enumerate(lin):
        row = (f"| {e.name} | {e.touches} | {e.pictures} | {e.stage1.mean_mm:.3f} / "
               f"{e.stage1.p95_mm:.3f} | {e.stage2.mean_mm:.3f} / {e.stage2.p95_mm:.3f} |")
        if mc:
            m = mc[i]
            row += (f" {m.stage1.mean_mm:.3f} / {m.stage1.p95_mm:.3f} | {m.stage2.mean_mm:.3f} / "
                    f"{m.stage2.p95_mm:.3f} | {m.twins} |")
        lines.append(row)
    return "\n".join(lines)


def add_plan_acquisition_command(sub: argparse._SubParsersAction) -> None:
    """Add ``plan-acquisition`` to the command line's subcommands ``sub``."""
    p = sub.add_parser(
        "plan-acquisition",
        help="the expected touching error of candidate acquisitions, before they are taken",
        description="Take the rig of SOURCE (a dataset .toml, a result .json, or a twin's "
        "truth.json) as the truth and print, for each candidate acquisition (a snake grid of "
        "landmarks over the data's landmark area, touched at hand angles over 0-180 deg, with "
        "pictures from capture poses rising to 90 mm), the expected held-out touching error "
        "of each stage over the landmark area (targets on a 5 x 5 grid at 8 hand angles, seen "
        "from the first capture): mean and 95th percentile in mm, linearised from the noise "
        "model and, with --monte-carlo, from K noisy twins calibrated in one batch.",
    )
    p.add_argument("source", help="dataset (.toml), result (.json) or twin truth (truth.json)")
    p.add_argument("--grid", type=_counts(2, MAX_GRID), default=(3, 5, 7),
                   help="landmarks per side of each candidate grid, e.g. 3,5,7")  # fmt: skip
    p.add_argument("--captures", type=_counts(1, MAX_PICTURES), default=(1, 3),
                   help="pictures of each candidate, e.g. 1,3")  # fmt: skip
    p.add_argument("--target-mm", type=positive_mm, default=None, metavar="MM",
                   help="recommend the candidate with the fewest touches, then pictures, whose "
                   "mean error is at most this, mm (default: no recommendation)")  # fmt: skip
    p.add_argument("--stage", type=int, choices=(1, 2), default=1,
                   help="the stage whose error --target-mm is compared with")  # fmt: skip
    p.add_argument("--monte-carlo", type=_twins, default=0, metavar="K",
                   help=f"also calibrate K noisy twins of each candidate, 2 to {MAX_TWINS:,} "
                   "(default: linearised only)")  # fmt: skip
    p.add_argument("--noise", choices=("paper",), default="paper", help="the noise model")
    p.add_argument("--optimise", action="store_true",
                   help="add each candidate with its landmarks and hand angles moved by "
                   "gradient to lower its linearised stage-1 error")  # fmt: skip
    p.add_argument("--seed", type=seed, default=1,
                   help="seeds the capture poses and the Monte Carlo twins")  # fmt: skip
    p.add_argument("--population", type=population, default=500,
                   help="the Monte Carlo calibrations' DE population")  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress bar on stderr")
    p.set_defaults(func=_cmd_plan_acquisition, imports=("twin.predict_acquisition",))
