"""Planner accuracy (issue 27 §3): the expected error of five acquisitions, linearised against
Monte Carlo, and Monte Carlo against the error measured on fresh rendered twins.

    python benchmarks/planner_accuracy.py [--truth-seed 1] [--twins 20] [--fresh 10]
                                          [--steps 40] [--results PATH] [--quick]

On one `paper`-like rig (``draw_truth(--truth-seed)``), for the paper's 3×3 grid, 5×5, 7×7,
3×3 with 3 pictures and the 3-picture grid's layout optimised by gradient
(:func:`~handeye_jax.twin.optimise_layout`):

* **linearised**: :func:`~handeye_jax.twin.predict_acquisition` (the `paper` noise model);
* **Monte Carlo**: :func:`~handeye_jax.twin.monte_carlo_acquisition`, ``--twins`` noisy copies
  drawn from the same noise model, calibrated in one batch (default settings);
* **measured**: ``--fresh`` twins of the same rig with the acquisition's landmarks, hand
  angles and capture poses, made by :func:`~handeye_jax.simulate` (rendered pictures,
  detected landmarks, the `paper` preset's touches and rounding), calibrated
  (default settings, in one batch) and sent to the same workspace's targets
  (:func:`~handeye_jax.evaluate_points`).

The workspace: targets on a 5×5 grid over the paper grid's area at 8 hand angles, seen from
the rig's capture. Prints a Markdown table and writes it to ``benchmarks/RESULTS.md``.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import jax
import numpy as np

from handeye_jax import (
    PRESETS,
    Settings,
    calibrate_batch,
    simulate,
    vectorise_small_loops,
)
from handeye_jax.problem import get_noise_model
from handeye_jax.twin import (
    LayoutSearch,
    default_workspace,
    draw_truth,
    errors_on_workspace,
    grid_acquisition,
    monte_carlo_acquisition,
    optimise_layout,
    predict_acquisition,
    summarise,
    workspace_heldout,
)
from handeye_jax.vision import BlobCountError

sys.path.insert(0, str(Path(__file__).resolve().parent))
from twin_study import write_section  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "RESULTS.md"
HEADING = "## Planner accuracy: linearised, Monte Carlo and measured (issue 27 §3)"
#: The targets: linearised within ±20 % of Monte Carlo, Monte Carlo within ±15 % of measured.
LIN_TOL, MC_TOL = 0.20, 0.15


def measured(truth, acq, fresh: int, workspace, noise, settings, seed0: int):
    """The acquisition on ``fresh`` rendered twins: simulate → calibrate_batch → evaluate.
    Several pictures are taken from the acquisition's capture poses
    (``simulate(captures=poses)``) with 2-px dots (one-pixel dots vanish from the higher
    captures, as in benchmarks/multicapture.py); a twin whose detector misses a dot is
    replaced by the next seed's. Returns the errors and how many twins were replaced."""
    rig = replace(truth, landmarks_tablet_px=acq.tablet_px,
                  landmarks_hand_angle_deg=acq.hand_angle_deg,
                  dot_px=1.0 if acq.pictures == 1 else 2.0)  # fmt: skip
    seeds, twins, missed = [], [], 0
    for s in range(seed0, seed0 + 4 * fresh):
        try:
            if acq.pictures == 1:
                twins.append(simulate(rig, PRESETS["paper"], s, n_heldout=1))
            else:
                twins.append(simulate(rig, PRESETS["paper"], s, n_heldout=1,
                                      captures=list(acq.capture_poses)))  # fmt: skip
        except BlobCountError:
            missed += 1
            continue
        seeds.append(s)
        if len(twins) == fresh:
            break
    rngs = [np.random.default_rng(s + 10**6) for s in seeds]
    held = [workspace_heldout(truth, workspace, noise, r) for r in rngs]
    results = calibrate_batch([t.dataset for t in twins],
                              [replace(settings, seed=s) for s in seeds])  # fmt: skip
    e1, e2 = errors_on_workspace(results, truth, held)
    return summarise(acq.name, acq, e1, e2, method="measured"), missed


def ratio_cell(a: float, b: float, tol: float) -> str:
    d = a / b - 1.0
    return f"{d:+.0%} {'✓' if abs(d) <= tol else '✗'}"


def main() -> None:
    vectorise_small_loops()  # as the command line does
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--truth-seed", type=int, default=1)
    ap.add_argument("--twins", type=int, default=20, help="Monte Carlo twins per acquisition")
    ap.add_argument("--fresh", type=int, default=10, help="rendered twins per acquisition")
    ap.add_argument("--steps", type=int, default=40, help="the optimiser's steps")
    ap.add_argument("--results", type=Path, default=RESULTS, help="Markdown file to update")
    ap.add_argument("--quick", action="store_true",
                    help="a smoke run: 3×3 and its optimised layout, 2 twins each, small DE")
    args = ap.parse_args()
    t0 = time.perf_counter()
    truth = draw_truth(args.truth_seed)
    noise = get_noise_model("paper")
    workspace = default_workspace(truth)
    settings = Settings()
    if args.quick:
        settings = Settings(population=200, generations=400)
        args.twins, args.fresh, args.steps = 2, 2, 2
    paper3 = grid_acquisition(truth, 3, 3, seed=args.truth_seed)
    candidates = [grid_acquisition(truth, 3)]
    if not args.quick:
        candidates += [grid_acquisition(truth, 5), grid_acquisition(truth, 7), paper3]
    t_opt = time.perf_counter()
    opt = optimise_layout(truth, paper3, noise, workspace, LayoutSearch(steps=args.steps))
    t_opt = time.perf_counter() - t_opt
    candidates.append(opt.acquisition)
    rows = []
    for acq in candidates:
        lin = predict_acquisition(truth, acq, noise, workspace)
        mc = monte_carlo_acquisition(truth, acq, args.twins, noise, workspace, settings,
                                     seed=1000 * args.truth_seed)  # fmt: skip
        me, missed = measured(truth, acq, args.fresh, workspace, noise, settings,
                              2000 * args.truth_seed)  # fmt: skip
        rows.append((acq, lin, mc, me, missed))
        print(f"{acq.name}: linearised {lin.stage1.mean_mm:.3f}, MC {mc.stage1.mean_mm:.3f}, "
              f"measured {me.stage1.mean_mm:.3f} mm (stage 1)", file=sys.stderr)  # fmt: skip
    lines = [
        "| acquisition | touches | pictures | stage | linearised mean / p95 mm "
        "| MC mean ± se / p95 mm | measured mean ± se / p95 mm | linearised vs MC (±20 %) "
        "| MC vs measured (±15 %) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for acq, lin, mc, me, missed in rows:
        for k in (1, 2):
            a, b, c = lin.stage(k), mc.stage(k), me.stage(k)
            se_mc = f" ± {mc.stage1_spread_mm:.3f}" if k == 1 else ""
            se_me = f" ± {me.stage1_spread_mm:.3f}" if k == 1 else ""
            se_me += f" ({me.twins} twins, {missed} replaced)" if k == 1 and missed else ""
            lines.append(
                f"| {acq.name} | {acq.touches} | {acq.pictures} | {k} | {a.mean_mm:.3f} / "
                f"{a.p95_mm:.3f} | {b.mean_mm:.3f}{se_mc} / {b.p95_mm:.3f} | "
                f"{c.mean_mm:.3f}{se_me} / {c.p95_mm:.3f} | "
                f"{ratio_cell(a.mean_mm, b.mean_mm, LIN_TOL)} | "
                f"{ratio_cell(b.mean_mm, c.mean_mm, MC_TOL)} |"
            )  # fmt: skip
    h = opt.history_mm
    command = (f"python benchmarks/planner_accuracy.py --truth-seed {args.truth_seed} "
               f"--twins {args.twins} --fresh {args.fresh} --steps {args.steps}"
               + (" --quick" if args.quick else ""))  # fmt: skip
    text = (
        f"{HEADING}\n\ncommand: {command}\n"
        f"machine: {platform.machine()}, jax {jax.__version__}; float64; "
        f"{time.strftime('%Y-%m-%d')}; {time.perf_counter() - t0:.0f} s in all\n\n"
        f"One rig, `draw_truth({args.truth_seed})`; the `paper` noise model; the workspace: "
        f"{workspace.k} targets (5×5 over the paper grid's area × 8 hand angles in [0, 180) "
        "deg, seen from the rig's capture), error = |hand command − true command| in x-y. "
        f"Linearised: the ML fit's covariance propagated to the commands. MC: {args.twins} "
        "noisy copies of the acquisition from the noise model, calibrated in one batch "
        f"(calibrate_batch, {'population 200, generations 400' if args.quick else 'defaults'}). "
        f"Measured: {args.fresh} fresh twins of the same rig and layout by `simulate` (rendered "
        "pictures, detected landmarks, the `paper` preset; the acquisition's capture poses; "
        "1-px dots with one picture, 2-px with three, as one-pixel dots vanish from the "
        "higher captures), "
        "calibrated the same way, evaluated on the same targets (`evaluate_points`). se: "
        "the standard error of the mean over twins. The optimised layout: the 3-picture grid's "
        f"landmarks, hand angles and pictures 2 and 3 after {len(h) - 1} accepted "
        f"projected-gradient steps ({t_opt:.0f} s), linearised stage-1 mean {h[0]:.3f} → "
        f"{h[-1]:.3f} mm.\n\n"
        + "\n".join(lines)
    )
    print(text)
    if not args.quick:
        write_section(args.results, HEADING, text)


if __name__ == "__main__":
    main()
