"""Recalibration after a change of the rig, on synthetic twins (issue 17).

    python benchmarks/recalibration.py [--seeds 1 2 ... 10] [--parts pen tablet]
                                       [--ks 1 2 3 4 9] [--bounds] [--no-wrong]
                                       [--k3 M M M] [--k3-angles DEG DEG DEG]
                                       [--paper-data-term] [--quick] [--results PATH]

For each seed S: the twin of ``simulate old --seed S --preset paper`` is calibrated (every
parameter free): the old result. Then one part changes (``simulate new --truth
old/truth.json --change PART --seed 1000+S``: the same rig with a new pen offset or a moved
tablet, ``CHANGES`` of ``handeye_jax/_twin.py``; its noise drawn afresh) and the new twin's
dataset is cut to k of its nine landmarks, spread over the 3×3 grid:

* k = 1: the centre (m = 4);  k = 2: two opposite corners (m = 0, 8);
* k = 3: three corners (m = 0, 2, 6; or ``--k3``);  k = 4: the four corners;  k = 9: all.

Each k-subset is recalibrated from the old result with ``refit=(PART,)``: the other
parameters take the old posterior as their prior (MAP), or with ``fix`` are held at the old
values. Every fit is measured on the new twin's 20 held-out targets (the touching error,
:func:`handeye_jax.evaluate`, mm), next to the old result used unchanged, a
calibration of all nine new landmarks from scratch, a from-scratch calibration of the same k
landmarks (where it is determined, k >= 3) and the oracle (the new truth). The tables give
the mean over seeds of each fit's mean error over the targets.

The priors: "right" is the pen or tablet table's prior rows against the from-scratch fit of
the same landmarks; "wrong by 5 sigma": the pen changed and, unannounced, ``xt`` (not
refitted) moved by 5 of its prior sigmas; the recalibration with ``--refit pen`` should name
it in a warning with its pull.

``--bounds`` adds what no recalibration of k touches can beat by much: the joint fit of the
old and the new data (stage 1; the paper's mean lengths and least squares) and the refit with
every other parameter at its true value. ``--k3-angles`` touches the k = 3 landmarks of the
new twin at these hand angles. ``--paper-data-term``: the data term before the Gaussian one
(the paper's mean lengths, σ estimated from the new residuals; benchmarks/RESULTS.md,
"Recalibration: what three touches can reach").

Every calibration runs in this process with the default settings (seed S), no diagnostics
step; each kind of fit for all the seeds at once, in one ``calibrate_batch`` or
``recalibrate_batch`` (each result its own single run's, bit for bit); a fit's time is its
share of its batch's wall time, on a machine shared with other work.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from handeye_jax import (
    PRESETS,
    AbstractObjective,
    Dataset,
    Diagnostics,
    Heldout,
    HTMModel,
    InputError,
    LengthBlock,
    Settings,
    SquaresBlock,
    Stage1Objective,
    StageDiagnostics,
    Twin,
    calibrate_batch,
    change_truth,
    draw_truth,
    evaluate,
    float64,
    recalibrate,
    recalibrate_batch,
    simulate,
    vectorise_small_loops,
)
from handeye_jax.calibration import POLISH, PULL_FLAG
from handeye_jax.optim import Box, minimise

sys.path.insert(0, str(Path(__file__).resolve().parent))
from twin_study import write_section  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "RESULTS.md"
HEADING = "## Recalibration after a change, on twins (issue 17)"
#: The landmarks of each k, indices into the paper's 3×3 snake (0 1 2 / 5 4 3 / 6 7 8).
SUBSETS = {1: (4,), 2: (0, 8), 3: (0, 2, 6), 4: (0, 2, 6, 8), 9: tuple(range(9))}
#: The new twin's noise seed is this plus the old twin's.
NEW_SEED = 1000
#: Recalibrate as before the Gaussian data term (``--paper-data-term``).
PAPER_DATA_TERM = False
#: The wrong prior: this parameter's mean moved by this many of its prior sigmas.
WRONG_PARAM, WRONG_SIGMAS = "xt", 5.0


def subset(ds: Dataset, idx: tuple[int, ...]) -> Dataset:
    """The dataset of landmarks ``idx`` alone (named after them)."""
    i = np.asarray(idx)
    return ds.replace(
        name=f"{ds.name}-m{'-'.join(map(str, idx))}", tablet_px=ds.tablet_px[i],
        image_px=ds.image_px[i], depth_mm=ds.depth_mm[i], hand_xy_mm=ds.hand_xy_mm[i],
        hand_angle_deg=ds.hand_angle_deg[i], touch_error_px=ds.touch_error_px[i],
    )  # fmt: skip


def heldout(twin: Twin) -> Heldout:
    return Heldout(twin.heldout_image_px, twin.heldout_depth_mm, twin.heldout_hand_angle_deg,
                   twin.heldout_tablet_px)  # fmt: skip


def measure(result, twin: Twin, seconds: float) -> dict:
    """Stage 1 and 2 held-out mean errors (mm), the flagged pulls, the time."""
    rows = {r.label: r for r in evaluate(result, twin.truth, heldout(twin))}
    pulls = [p for s in (result.stage1, result.stage2) if s.prior for p in s.prior.pulls]
    return {
        "s1": rows["stage 1"].mean_mm, "s2": rows["stage 2"].mean_mm,
        "oracle": rows["oracle"].mean_mm, "time": seconds,
        "flagged": sorted(p.param for p in pulls if abs(p.pull) > PULL_FLAG),
        "pulls": {p.param: p.pull for p in pulls},
    }  # fmt: skip


def timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


class JointObjective(AbstractObjective):
    """Stage 1 on the old and the new data at once: the parameters of ``group`` have an old
    and a new value, every other one is shared. ``theta`` is the model's parameters (old
    values of ``group``) followed by the new values of ``group``. The exact combination of
    the two data sets that a prior from the old posterior approximates; ``squares``: least
    squares instead of the paper's mean error lengths."""

    old: Stage1Objective
    new: Stage1Objective
    group: tuple[int, ...]
    w_old: float
    w_new: float
    squares: bool = False

    def blocks(self, theta):
        d = len(HTMModel.param_names)
        new = theta[:d].at[jnp.asarray(self.group)].set(theta[d:])
        out = {}
        for tag, objective, t, w in (("old ", self.old, theta[:d], self.w_old),
                                     ("new ", self.new, new, self.w_new)):  # fmt: skip
            for name, b in objective.blocks(t).items():
                n = b.errors.shape[0]
                out[tag + name] = (SquaresBlock((b.errors * jnp.sqrt(w / n)).reshape(-1))
                                   if self.squares else LengthBlock(b.errors * w))  # fmt: skip
        return out

    def on_landmarks(self, idx):
        raise NotImplementedError


def joint_fit(old, old_ds: Dataset, new_ds: Dataset, part: str, start, squares: bool):
    """``start`` (a recalibration of ``new_ds``) with stage 1 replaced by the joint fit's new
    model: LM from the old parameters and ``start``'s new ``part``."""
    names = HTMModel.param_names
    group = tuple(names.index(n) for n in HTMModel.groups[part])
    n_old, n_new = old_ds.n_landmarks, new_ds.n_landmarks
    objective = JointObjective(
        Stage1Objective(HTMModel, old_ds.observations()),
        Stage1Objective(HTMModel, new_ds.observations()),
        group, n_old / (n_old + n_new), n_new / (n_old + n_new), squares,
    )  # fmt: skip
    x0 = np.array([old.stage1.params[n] for n in names]
                  + [start.stage1.params[names[i]] for i in group])  # fmt: skip
    lo, hi = HTMModel.search_bounds()
    lo, hi = np.r_[lo, lo[list(group)]], np.r_[hi, hi[list(group)]]
    x = minimise(objective, POLISH, Box(lo - 50.0, hi + 50.0), x0=x0).x
    params = dict(zip(names, x[: len(names)], strict=True))
    params |= {names[i]: float(x[len(names) + j]) for j, i in enumerate(group)}
    return replace(start, model=HTMModel.from_dict(params),
                   stage1=replace(start.stage1, params=params))  # fmt: skip


def bound_rows(old, old_ds, truth, twin, part, k, s) -> dict:
    """What no recalibration of k touches can beat by much: the joint fit of the old and
    new data, and the refit of ``part`` with every other parameter at its true value."""
    ds = subset(twin.dataset, SUBSETS[k])
    start, t = timed(recalibrate, ds, old, (part,), s, fix=True)
    rows = {}
    for squares in (False, True):
        r, t_joint = timed(joint_fit, old, old_ds, ds, part, start, squares)
        rows[f"joint {'squares' if squares else 'L1'}, {k}"] = measure(r, twin, t + t_joint)
    params = dict(truth.model)
    true = replace(old, model=HTMModel.from_dict(params),
                   stage1=replace(old.stage1, params=params), diagnostics=None)  # fmt: skip
    r, t = timed(recalibrate, ds, true, (part,), s, fix=True)
    rows[f"true others, {k}"] = measure(r, twin, t)
    for row in rows.values():  # stage 1 alone: their stage 2 is another fit's
        row["s2"] = math.nan
    return rows


def without_noise(result):
    """``result`` whose posteriors do not state their fit's noise σ (given as diagnostics'
    precisions alone): a recalibration from it weighs the new data by the paper's mean
    lengths and its pulls estimate σ from the new residuals, as before the Gaussian data
    term."""

    def precision_alone(stage: str) -> StageDiagnostics:  # σ 0: "no noise stated"
        rows = tuple(map(tuple, result.posterior(stage).precision.tolist()))
        return StageDiagnostics(sigma_mm=0.0, dof=0, std={}, precision=rows, singular_values=(),
                                weak_directions=())  # fmt: skip

    diagnostics = Diagnostics(stage1=precision_alone("stage1"), stage2=precision_alone("stage2"))
    return replace(result, diagnostics=diagnostics, fits=None)


def _batched(fn, datasets: list, *args, **kwargs):
    """``fn(datasets, ...)`` (a batch) and each problem's share of its wall time, s."""
    out, t = timed(fn, datasets, *args, **kwargs)
    return out, t / max(len(datasets), 1)


def _new_twin(truth, part: str, seed: int, angles) -> Twin:
    changed = change_truth(truth, part, seed)
    if angles is not None:
        a = np.array(changed.landmarks_hand_angle_deg, dtype=float)
        a[list(SUBSETS[3])] = angles
        changed = replace(changed, landmarks_hand_angle_deg=a)
    return simulate(changed, PRESETS["paper"], NEW_SEED + seed)


def run_seeds(
    seeds: list[int], parts, ks, settings: Settings, wrong: bool, bounds: bool, angles=None
) -> list[dict]:
    """Every fit of each seed: ``{part: {row: measure}}`` and the wrong-prior runs, one dict
    per seed. Each kind of fit runs for all the seeds at once, in one ``calibrate_batch`` or
    ``recalibrate_batch`` (each result its own single run's, bit for bit). ``angles``: the
    hand angles (deg) of the new twin's k = 3 landmarks (default: 22.5·m)."""
    each = [replace(settings, seed=seed) for seed in seeds]
    truths = [draw_truth(seed) for seed in seeds]
    old_twins = [simulate(t, PRESETS["paper"], seed) for t, seed in zip(truths, seeds,
                                                                       strict=True)]  # fmt: skip
    olds = calibrate_batch([t.dataset for t in old_twins], each)
    if PAPER_DATA_TERM:
        olds = [without_noise(o) for o in olds]
    out: list[dict] = [{} for _ in seeds]
    for part in parts:
        twins = [_new_twin(t, part, seed, angles) for t, seed in zip(truths, seeds, strict=True)]
        rows = [{"old result unchanged": measure(o, tw, 0.0)}
                for o, tw in zip(olds, twins, strict=True)]  # fmt: skip
        for r in rows:
            r["oracle (the new truth)"] = {**r["old result unchanged"], "s1": math.nan}

        def add(label: str, results, seconds: float, rows=rows, twins=twins) -> None:
            for r, x, tw in zip(rows, results, twins, strict=True):
                r[label] = measure(x, tw, seconds)

        add("from scratch, 9", *_batched(calibrate_batch, [tw.dataset for tw in twins], each))
        for k in ks:
            dss = [subset(tw.dataset, SUBSETS[k]) for tw in twins]
            for fix in (False, True):
                try:
                    got = _batched(recalibrate_batch, dss, olds, (part,), each, fix=fix)
                except InputError:  # fewer residuals than free parameters: refused
                    continue
                add(f"{'fix' if fix else 'prior'}, {k}", *got)
            if 3 <= k < 9:
                add(f"from scratch, {k}", *_batched(calibrate_batch, dss, each))
            for i, r in enumerate(rows):
                if bounds and f"prior, {k}" in r:
                    r |= bound_rows(olds[i], old_twins[i].dataset, truths[i], twins[i], part, k,
                                    each[i])  # fmt: skip
        for o, r in zip(out, rows, strict=True):
            o[part] = r
    if wrong and "pen" in parts:
        for o, w in zip(out, wrong_prior(olds, truths, seeds, ks, each), strict=True):
            o["wrong"] = w
    return out


def prior_sigma(result, name: str, part: str) -> float:
    """The prior σ of ``name`` in a recalibration of ``part`` from ``result``: the marginal of
    its stage-1 posterior over the parameters outside ``part``, mm or deg."""
    post = result.posterior("stage1")
    others = post.marginal([n for n in post.names if n not in HTMModel.groups[part]])
    return float(others.sigma[others.names.index(name)])


def wrong_prior(olds, truths, seeds: list[int], ks, each: list[Settings]) -> list[dict]:
    """The pen changed and, unknown to the operator, ``WRONG_PARAM`` moved by ``WRONG_SIGMAS``
    of its prior σ: each old result's prior is that wrong. Recalibrate with ``--refit pen``
    (each k for all the seeds in one ``recalibrate_batch``): the pull reported on it, the
    warnings naming it, per k; one dict per seed."""
    out, twins = [], []
    for old, truth, seed in zip(olds, truths, seeds, strict=True):
        sigma = prior_sigma(old, WRONG_PARAM, "pen")
        changed = change_truth(truth, "pen", seed)
        model = {**changed.model, WRONG_PARAM: changed.model[WRONG_PARAM] + WRONG_SIGMAS * sigma}
        twins.append(simulate(replace(changed, model=model), PRESETS["paper"], NEW_SEED + seed))
        out.append({"sigma": sigma})
    for k in ks:
        try:
            results = recalibrate_batch([subset(tw.dataset, SUBSETS[k]) for tw in twins], olds,
                                        ("pen",), each)  # fmt: skip
        except InputError:
            continue
        for o, r, tw in zip(out, results, twins, strict=True):
            m = measure(r, tw, 0.0)
            m["warnings"] = [w.text for w in r.warnings if f"pull {WRONG_PARAM} " in w.text]
            o[k] = m
    return out


def mean(runs, part, row, key) -> float:
    vals = [x[part][row][key] for x in runs if row in x[part]]
    return float(np.mean(vals)) if vals else math.nan


def part_table(runs, part: str, ks) -> str:
    full1 = mean(runs, part, "from scratch, 9", "s1")
    full2 = mean(runs, part, "from scratch, 9", "s2")
    lines = [
        f"| {part} changed: fit | landmarks | stage 1 mm | stage 2 mm | stage 1 / full 9 "
        "| stage 2 / full 9 | flagged pulls per fit | time s |",
        "|---|---|---|---|---|---|---|---|",
    ]

    def line(label, k, row):
        if not any(row in x[part] for x in runs):
            lines.append(f"| {label} | {k} | refused: fewer residuals than free parameters "
                         "| | | | | |")  # fmt: skip
            return
        s1, s2 = mean(runs, part, row, "s1"), mean(runs, part, row, "s2")
        done = [x[part][row] for x in runs if row in x[part]]
        flags = np.mean([len(m["flagged"]) for m in done]) if "prior" in row else None
        t = float(np.median([m["time"] for m in done]))
        two = ("-", "-") if math.isnan(s2) else (f"{s2:.3f}", f"{s2 / full2:.2f}")
        lines.append(
            f"| {label} | {k} | {s1:.3f} | {two[0]} | {s1 / full1:.2f} | {two[1]} | "
            f"{'-' if flags is None else f'{flags:.1f}'} | {t:.2f} |"
        )

    line("old result unchanged", "0", "old result unchanged")
    line("from scratch", "9", "from scratch, 9")
    for how in ("prior", "fix"):
        for k in ks:
            line(f"recalibrate --refit {part}" + (" --fix" if how == "fix" else ""), str(k),
                 f"{how}, {k}")  # fmt: skip
    for k in ks:
        if 3 <= k < 9:
            line("from scratch", str(k), f"from scratch, {k}")
    bounds = (
        ("joint fit of the old and new data", "joint L1"),
        ("joint fit, least squares", "joint squares"),
        (f"--refit {part} --fix, the others at their true values", "true others"),
    )
    for label, row in bounds:
        for k in ks:
            if any(f"{row}, {k}" in x[part] for x in runs):
                line(label, str(k), f"{row}, {k}")
    o = mean(runs, part, "oracle (the new truth)", "oracle")
    lines.append(f"| oracle (the new truth) | - | {o:.3f} | - | {o / full1:.2f} | - | - | - |")
    return "\n".join(lines)


def wrong_table(runs, ks) -> str:
    lines = [
        f"| landmarks | prior sigma of {WRONG_PARAM} mm | pull on {WRONG_PARAM} (mean, min) "
        f"| flagged ({WRONG_PARAM}) | other params flagged per fit | stage 2 mm |",
        "|---|---|---|---|---|---|",
    ]
    for k in ks:
        if not all(k in x["wrong"] for x in runs):
            continue
        pulls = [abs(x["wrong"][k]["pulls"][WRONG_PARAM]) for x in runs]
        named = sum(bool(x["wrong"][k]["warnings"]) for x in runs)
        others = np.mean([len([p for p in x["wrong"][k]["flagged"] if p != WRONG_PARAM])
                          for x in runs])  # fmt: skip
        sig = np.mean([x["wrong"]["sigma"] for x in runs])
        s2 = np.mean([x["wrong"][k]["s2"] for x in runs])
        lines.append(
            f"| {k} | {sig:.3f} | {np.mean(pulls):.1f}, {np.min(pulls):.1f} | {named} of "
            f"{len(runs)} | {others:.1f} | {s2:.3f} |"
        )
    return "\n".join(lines)


def main(argv=None) -> str:
    vectorise_small_loops()  # as the command line does
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 11)))
    ap.add_argument("--parts", nargs="+", choices=("pen", "tablet", "camera"),
                    default=["pen", "tablet"])  # fmt: skip
    ap.add_argument("--ks", type=int, nargs="+", choices=sorted(SUBSETS), default=sorted(SUBSETS))
    ap.add_argument("--population", type=int, default=Settings.population)
    ap.add_argument("--generations", type=int, default=Settings.generations)
    ap.add_argument("--no-wrong", action="store_true", help="skip the wrong-prior runs")
    ap.add_argument("--bounds", action="store_true",
                    help="add the joint fit of the old and new data (paper's F, least squares) "
                    "and the refit with the other parameters at their true values")  # fmt: skip
    ap.add_argument("--paper-data-term", action="store_true",
                    help="the method before the Gaussian data term: a prior without the noise "
                    "of its fit, so the data stay the paper's mean lengths and the pulls "
                    "estimate the noise from the new residuals")  # fmt: skip
    ap.add_argument("--k3", type=int, nargs=3, metavar="M", default=list(SUBSETS[3]),
                    help="the landmarks of k = 3")  # fmt: skip
    ap.add_argument("--k3-angles", type=float, nargs=3, metavar="DEG",
                    help="the hand angles of the k = 3 landmarks in the new twin (default: "
                    "the paper's 22.5 m)")  # fmt: skip
    ap.add_argument("--quick", action="store_true",
                    help="smoke test: seed 1, the pen, k = 4, a small DE")  # fmt: skip
    ap.add_argument("--results", type=Path, help="also write the tables into this Markdown file")
    args = ap.parse_args(argv)
    settings = Settings(population=args.population, generations=args.generations)
    if args.quick:  # the test suite's budget (tests/common.py): its compiled programs serve
        args.seeds, args.parts, args.ks = [1], ["pen"], [4]
        settings = Settings(population=200, generations=400)
    SUBSETS[3] = tuple(args.k3)
    global PAPER_DATA_TERM
    PAPER_DATA_TERM = args.paper_data_term
    t0 = time.perf_counter()
    with float64():  # the helpers here build models and objectives of their own
        runs = run_seeds(args.seeds, args.parts, args.ks, settings, not args.no_wrong,
                         args.bounds, args.k3_angles)  # fmt: skip
    command = "python benchmarks/recalibration.py" + (" --quick" if args.quick else "")
    if not args.quick:
        command += f" --seeds {' '.join(map(str, args.seeds))} --parts {' '.join(args.parts)}"
        command += f" --ks {' '.join(map(str, args.ks))}" + (" --bounds" if args.bounds else "")
        command += " --paper-data-term" if args.paper_data_term else ""
        if tuple(args.k3) != (0, 2, 6):
            command += f" --k3 {' '.join(map(str, args.k3))}"
        if args.k3_angles is not None:
            command += f" --k3-angles {' '.join(f'{a:g}' for a in args.k3_angles)}"
        if (args.population, args.generations) != (Settings.population, Settings.generations):
            command += f" --population {args.population} --generations {args.generations}"
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
    text = [
        HEADING, "",
        f"command: {command}",
        f"machine: {platform.machine()}, jax {jax.__version__}; float64; "
        f"{time.strftime('%Y-%m-%d')}; {time.perf_counter() - t0:.0f} s; load {load:.1f}",
        f"held-out touching error on the new twin's 20 targets, mean over {len(runs)} seeds of "
        "each fit's mean, mm; landmarks of each k: " +
        "; ".join(f"{k}: m = {', '.join(map(str, SUBSETS[k]))}" for k in args.ks) +
        f"; a pull is flagged above {PULL_FLAG:g} sigma; time: "
        "each fit's share of its batch's wall time (a kind of fit for all the seeds in one "
        "batch; the first batch of a kind includes compiling)",
    ]  # fmt: skip
    for part in args.parts:
        text += ["", part_table(runs, part, args.ks)]
    if not args.no_wrong and "pen" in args.parts:
        what = (
            f"the pen changed and {WRONG_PARAM} moved by {WRONG_SIGMAS:g} prior sigma, --refit pen"
        )
        text += ["", f"A prior wrong by {WRONG_SIGMAS:g} sigma ({what}):", "",
                 wrong_table(runs, args.ks)]  # fmt: skip
    out = "\n".join(text)
    print(out)
    if args.results is not None:
        write_section(args.results, HEADING, out)
    return out


if __name__ == "__main__":
    main()
