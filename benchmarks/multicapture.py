"""Issue 18's acceptance: calibrations from several captures, held out from any capture pose.

    python benchmarks/multicapture.py [--seeds 1 ... 10] [--captures 3] [--heldout 20]
                                      [--population N --generations G] [--quick]
                                      [--results PATH] [--figure PATH]

1. Noise-free: three-capture twins (exact image points and depths; captures rising 90 mm, at
   three hand angles; touches with the hand's height), HTM on the twin's own rig (seeds 1-4:
   all four hand-angle conventions) and DH on data its own truth made (both signs, two
   zeros). F of both stages, and the largest x-y and z command error over targets on and
   50 mm above the display, seen from the first capture and from a new pose 60 mm higher at
   another hand angle that no fit used.
2. ``paper`` noise, 10 seeds, 9 touches, 3 captures (detected landmarks): the held-out mean
   x-y error (where the pen tip lands off the target, seen from above) and z error, by
   capture rise and target height, for the three-capture calibration, the same twin
   calibrated from its first capture alone (the paper's acquisition: no hand heights), and
   the oracle (true parameters, same measurements). Stage 1 and stage 2 side by side.
3. A figure: held-out x-y error against the capture's height above the first, for one
   capture and for three (``benchmarks/results/multicapture.png``).

Prints Markdown and writes it to ``benchmarks/RESULTS.md`` under its heading.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from handeye_jax import (
    PRESETS,
    Heldout,
    Rig,
    Scene,
    Settings,
    calibrate,
    draw_truth,
    evaluate_points,
    get_model,
    simulate,
    snake_grid_px,
    synthesize_dataset,
    vectorise_small_loops,
)
from handeye_jax.twin import HeldoutLevels, heldout_targets, seen_from, true_command

sys.path.insert(0, str(Path(__file__).resolve().parent))
from twin_study import write_section  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "RESULTS.md"
FIGURE = Path(__file__).resolve().parent / "results" / "multicapture.png"
HEADING = "## Several captures: held out from any capture pose (issue 18)"
#: Capture rises of the figure's held-out targets, mm above the first capture.
FIGURE_RISES_MM = (-40.0, 0.0, 30.0, 60.0, 90.0, 120.0)
DH_TRUTH = dict(theta_c1=5.0, a_c1=60.0, alpha_c=8.0, beta_c=-2.0, gamma_c=-10.0,
                theta_t1=30.0, a_t1=140.0, alpha_t=20.0, beta_t=-4.0, gamma_t=-12.0, xp=-3.0,
                yp=-22.0)  # fmt: skip


def _heldout(twin) -> Heldout:
    return Heldout(twin.heldout_image_px, twin.heldout_depth_mm, twin.heldout_hand_angle_deg,
                   twin.heldout_tablet_px, twin.heldout_capture_position_mm,
                   twin.heldout_capture_angle_deg, twin.heldout_true_mm,
                   twin.heldout_above_mm)  # fmt: skip


def noise_free_htm(seed: int, settings: Settings) -> dict:
    truth = replace(draw_truth(seed, dot_px=2.0), pen_z_mm=95.0)
    twin = simulate(truth, PRESETS["none"], seed, exact=True, n_heldout=10, captures=3)
    r = calibrate(twin.dataset, replace(settings, model="htm", seed=seed))
    rows = {e.label: e for e in evaluate_points(r, truth, _heldout(twin))}
    return {
        "what": f"HTM twin seed {seed}", "convention": (truth.hand_angle_zero_deg,
                                                        truth.hand_angle_sign),
        "F1": r.stage1.F, "F2": r.stage2.F,
        "xy": max(rows[s].xy_mm.max() for s in ("stage 1", "stage 2")),
        "z": max(rows[s].z_mm.max() for s in ("stage 1", "stage 2")),
    }  # fmt: skip


def noise_free_dh(zero: float, sign: int, settings: Settings) -> dict:
    """DH fitted to data its own truth made (the twin's rig is an HTM one)."""
    import handeye_jax

    with handeye_jax.float64():
        truth = get_model("dh").from_dict(DH_TRUTH)
    rig = Rig(617.7, 617.7, 316.5, 242.3, [320.0, -70.0, 290.0], zero, sign)
    a0 = -zero * sign
    poses = [([320.0, -70.0, 290.0], a0), ([330.0, -80.0, 335.0], a0 + 15.0),
             ([310.0, -50.0, 380.0], a0 - 20.0)]  # fmt: skip
    ds = synthesize_dataset(truth, rig, snake_grid_px(), 22.5 * np.arange(9), captures=poses,
                            scene=Scene(pen_z_mm=95.0, camera_z_mm=3.0))  # fmt: skip
    r = calibrate(ds, replace(settings, model="dh", seed=1))
    rng = np.random.default_rng(0)
    with handeye_jax.float64():
        x_bt = np.asarray(truth.tablet_to_base(snake_grid_px() * ds.mm_per_tablet_px))
    lo, hi = x_bt.min(axis=0), x_bt.max(axis=0)
    xy, z = [], []
    for rise, above in ((0.0, 0.0), (0.0, 50.0), (60.0, 0.0), (60.0, 50.0)):
        p = np.c_[rng.uniform(lo[0], hi[0], 10), rng.uniform(lo[1], hi[1], 10),
                  np.full(10, 120.0 + above)]  # fmt: skip
        position = np.array([320.0, -70.0, 290.0 + rise]) + [rise / 4, -rise / 6, 0.0]
        angle = a0 + (25.0 if rise else 0.0)
        uv, depth = seen_from(truth, rig, p, position, angle, camera_z_mm=3.0)
        theta = rng.uniform(0.0, 180.0, 10)
        want = true_command(truth, rig, p, theta, pen_z_mm=95.0)
        for stage in (1, 2):
            got = r.predict(uv, depth, theta, stage, capture_position_mm=position,
                            capture_hand_angle_deg=angle, axes="xyz")  # fmt: skip
            xy.append(np.linalg.norm(got[:, :2] - want[:, :2], axis=1).max())
            z.append(np.abs(got[:, 2] - want[:, 2]).max())
    return {"what": "DH, its own truth", "convention": (zero, sign), "F1": r.stage1.F,
            "F2": r.stage2.F, "xy": max(xy), "z": max(z)}  # fmt: skip


def noisy(seed: int, captures: int, n_heldout: int, settings: Settings) -> dict:
    truth = draw_truth(seed, dot_px=2.0)  # one-pixel dots vanish from the higher captures
    twin = simulate(truth, PRESETS["paper"], seed, n_heldout=n_heldout, captures=captures)
    ds = twin.dataset
    caps = ds.captures
    s = replace(settings, model="htm", seed=seed)
    many = calibrate(ds, s)
    one = calibrate(ds.replace(captures=[caps[0]], hand_z_mm=np.full(ds.n_touches, np.nan),
                               version=1), s)  # fmt: skip
    held = _heldout(twin)
    out = {
        "seed": seed,
        "spread_mm": float(np.ptp([c.hand_position_mm[2] for c in caps])),
        "many": {e.label: e for e in evaluate_points(many, truth, held)},
        "one": {e.label: e for e in evaluate_points(one, truth, held)},
        "F1": (many.stage1.F, one.stage1.F),
    }
    # The figure: targets on the display seen from captures at more heights.
    rng = np.random.default_rng([seed, 18])
    levels = HeldoutLevels(n_heldout, rises_mm=FIGURE_RISES_MM, above_mm=(0.0,))
    fig = Heldout(**_fields(heldout_targets(truth, PRESETS["paper"], rng, levels)))
    out["figure"] = {
        "many": {e.label: e for e in evaluate_points(many, truth, fig)},
        "one": {e.label: e for e in evaluate_points(one, truth, fig)},
    }
    return out


def _fields(h: dict) -> dict:
    return dict(image_px=h["heldout_image_px"], depth_mm=h["heldout_depth_mm"],
                hand_angle_deg=h["heldout_hand_angle_deg"], tablet_px=h["heldout_tablet_px"],
                capture_position_mm=h["heldout_capture_position_mm"],
                capture_angle_deg=h["heldout_capture_angle_deg"], true_mm=h["heldout_true_mm"],
                above_mm=h["heldout_above_mm"])  # fmt: skip


def _mean(runs, which, label, pick, what="xy_mm"):
    vals = []
    for x in runs:
        e = x[which][label]
        arr = getattr(e, what)
        if arr is None:
            return float("nan")
        vals.append(arr[pick(e)].mean())
    return float(np.mean(vals))


def noisy_table(runs: list[dict]) -> str:
    groups = [
        ("first capture, on the display", lambda e: (np.round(e.rise_mm) == 0) & (e.above_mm == 0)),
        ("first capture, 50 mm above", lambda e: (np.round(e.rise_mm) == 0) & (e.above_mm == 50)),
        ("60 mm higher (new pose), on the display",
         lambda e: (np.round(e.rise_mm) == 60) & (e.above_mm == 0)),
        ("60 mm higher (new pose), 50 mm above",
         lambda e: (np.round(e.rise_mm) == 60) & (e.above_mm == 50)),
        ("all targets 50 mm above the display", lambda e: e.above_mm == 50),
        ("all targets", lambda e: np.ones(len(e.xy_mm), bool)),
    ]  # fmt: skip
    cols = [("many", "stage 1"), ("many", "stage 2"), ("one", "stage 1"), ("one", "stage 2"),
            ("many", "oracle")]  # fmt: skip
    n = len(runs[0]["many"]["stage 1"].xy_mm)
    lines = [
        f"mean over {len(runs)} seeds of each twin's mean held-out error, mm ({n} targets per "
        "twin; x-y: where the pen tip lands off the target, seen from above; z: the hand's "
        "height). 3 captures: this acquisition; 1 capture: the same twin from its first "
        "capture alone, without hand heights (the paper's acquisition).",
        "",
        "| targets seen from | 3 captures, stage 1 x-y | 3 captures, stage 2 x-y "
        "| 1 capture, stage 1 x-y | 1 capture, stage 2 x-y | oracle x-y "
        "| 3 captures, stage 1 z | oracle z |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, pick in groups:
        xy = [f"{_mean(runs, w, lab, pick):.3f}" for w, lab in cols]
        z = [f"{_mean(runs, 'many', lab, pick, 'z_mm'):.3f}" for lab in ("stage 1", "oracle")]
        lines.append(f"| {name} | " + " | ".join(xy + z) + " |")
    per = ["", "| seed | capture spread mm | F1st 3 captures mm | F1st 1 capture mm "
           "| 3 captures, +60 mm x-y | 1 capture, +60 mm x-y | 3 captures, 50 mm above x-y "
           "| 3 captures z |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for x in runs:
        m, o = x["many"]["stage 1"], x["one"]["stage 1"]
        up = np.round(m.rise_mm) == 60
        per.append(
            f"| {x['seed']} | {x['spread_mm']:.1f} | {x['F1'][0]:.3f} | {x['F1'][1]:.3f} | "
            f"{m.xy_mm[up & (m.above_mm == 0)].mean():.3f} | "
            f"{o.xy_mm[up & (o.above_mm == 0)].mean():.3f} | "
            f"{m.xy_mm[m.above_mm == 50].mean():.3f} | {m.z_mm.mean():.3f} |"
        )
    return "\n".join(lines + per)


def figure(runs: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.6), dpi=120)
    series = [("one", "stage 1", "1 capture (the paper's acquisition), stage 1", "tab:red", "o"),
              ("one", "stage 2", "1 capture, stage 2", "tab:orange", "v"),
              ("many", "stage 1", "3 captures, stage 1", "tab:blue", "s"),
              ("many", "stage 2", "3 captures, stage 2", "tab:cyan", "^"),
              ("many", "oracle", "oracle (true parameters)", "black", "x")]  # fmt: skip
    for which, label, legend, colour, marker in series:
        mean, lo, hi = [], [], []
        for rise in FIGURE_RISES_MM:
            per = [x["figure"][which][label] for x in runs]
            v = [e.xy_mm[np.round(e.rise_mm) == rise].mean() for e in per]
            mean.append(np.mean(v))
            lo.append(np.min(v))
            hi.append(np.max(v))
        ax.plot(FIGURE_RISES_MM, mean, marker=marker, color=colour, label=legend)
        ax.fill_between(FIGURE_RISES_MM, lo, hi, color=colour, alpha=0.12, linewidth=0)
    caps = [x["spread_mm"] for x in runs]
    ax.axvspan(0.0, float(np.mean(caps)), color="tab:blue", alpha=0.06,
               label="heights of the 3 calibration captures")  # fmt: skip
    ax.set_yscale("log")
    ax.set_xlabel("capture height above the calibration's first capture (mm)")
    ax.set_ylabel("held-out x-y error, mean over targets (mm)")
    ax.set_title(f"Held-out error vs capture height ({len(runs)} paper-noise twins; "
                 "band: min-max over twins)", fontsize=10)  # fmt: skip
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main() -> None:
    vectorise_small_loops()  # as the command line does
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 11)))
    ap.add_argument("--captures", type=int, default=3)
    ap.add_argument("--heldout", type=int, default=20)
    ap.add_argument("--population", type=int, default=Settings.population)
    ap.add_argument("--generations", type=int, default=Settings.generations)
    ap.add_argument(
        "--quick",
        action="store_true",
        help="one noise-free case of each model, one noisy seed; writes nothing",
    )
    ap.add_argument("--results", type=Path, default=RESULTS, help="Markdown file to update")
    ap.add_argument("--figure", type=Path, default=None,
                    help=f"the PNG to write (default {FIGURE.name}; --quick: none)")  # fmt: skip
    args = ap.parse_args()
    t0 = time.perf_counter()
    settings = Settings(population=args.population, generations=args.generations)
    if args.quick:
        settings = replace(settings, population=min(args.population, 200),
                           generations=min(args.generations, 200), restarts=4)  # fmt: skip
        args.seeds, args.heldout = args.seeds[:1], min(args.heldout, 4)
    clean = [noise_free_htm(s, settings) for s in ((1,) if args.quick else (1, 2, 3, 4))]
    dh = ((90.0, -1),) if args.quick else ((90.0, -1), (0.0, 1), (90.0, 1), (0.0, -1))
    clean += [noise_free_dh(z, s, settings) for z, s in dh]
    lines = [
        HEADING, "",
        "`python benchmarks/multicapture.py` (defaults: seeds 1-10, 3 captures, 20 held-out "
        f"targets per group, population {settings.population}, at most {settings.generations} "
        f"generations); {platform.machine()}, {time.strftime('%Y-%m-%d')}.", "",
        "Noise-free (exact image points and depths, three captures over 90 mm at three hand "
        "angles, hand heights recorded); commands from the first capture and from a pose 60 mm "
        "higher at another hand angle that no fit used, for targets on and 50 mm above the "
        "display, stages 1 and 2:", "",
        "| data | convention (zero deg, sign) | F1st mm | F2nd mm | max x-y error mm "
        "| max z error mm |",
        "|---|---|---|---|---|---|",
    ]  # fmt: skip
    for c in clean:
        lines.append(f"| {c['what']} | {c['convention'][0]:g}, {c['convention'][1]:+d} | "
                     f"{c['F1']:.1e} | {c['F2']:.1e} | {c['xy']:.1e} | {c['z']:.1e} |")  # fmt: skip
    runs = []
    for seed in args.seeds:
        runs.append(noisy(seed, args.captures, args.heldout, settings))
        print(f"seed {seed} done ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    lines += ["", f"`paper` noise, {len(runs)} seeds, 9 touches, {args.captures} captures:", "",
              noisy_table(runs), ""]  # fmt: skip
    text = "\n".join(lines) + f"\nTotal {time.perf_counter() - t0:.0f} s.\n"
    print(text)
    if args.figure is not None or not args.quick:
        figure(runs, args.figure or FIGURE)
        print(f"figure: {args.figure or FIGURE}")
    if not args.quick:
        write_section(args.results, HEADING, text)
        print(f"results: {args.results}")


if __name__ == "__main__":
    main()
