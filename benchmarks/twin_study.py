"""Synthetic-twin study: simulate → detect → calibrate → evaluate, one row per seed.

    python benchmarks/twin_study.py [--seeds 1 2 3 4 5] [--preset paper] [--dot-px D]
                                    [--population N --generations G] [--results PATH]

For each seed, a rig truth is drawn, the twin renders its pictures, the landmarks are detected
in the written PNGs, the dataset is calibrated (HTM, DE + LM, both stages; every seed in one
``calibrate_batch``, each result its own ``calibrate``'s bit for bit), and the held-out
touching error of stage 1, stage 2, the oracle (the true parameters with the same measured
observations) and the oracle with a stage 2 fitted on top is measured on 20 targets the fit
never saw. Prints a Markdown table and writes it to ``benchmarks/RESULTS.md`` under a heading
per preset (replacing only that section).
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

from handeye_jax import (
    PRESETS,
    Settings,
    calibrate_batch,
    detect_landmarks,
    draw_truth,
    evaluate_twin,
    fill_dataset,
    load_dataset,
    simulate,
    vectorise_small_loops,
    write_twin,
)

RESULTS = Path(__file__).resolve().parent / "RESULTS.md"
HEADING = "## Synthetic twin: held-out touching error"


def prepare_seed(seed: int, preset: str, folder: Path, dot_px: float = 1.0):
    """The twin of ``seed`` written to ``folder`` and its landmarks detected in the written
    PNGs: the dataset to calibrate and what the row needs of the detection."""
    truth = draw_truth(seed, dot_px=dot_px)
    twin = simulate(truth, PRESETS[preset], seed)
    write_twin(twin, folder)
    ds = load_dataset(folder / "dataset.toml")
    found = detect_landmarks(folder / "capture.png", folder / "depth.png", ds.tablet_px)
    centroid = found.image_px - twin.landmarks_image_px
    detection = {
        "centroid_rms_px": float(np.sqrt(np.mean(np.sum(centroid**2, axis=1)))),
        "depth_max_mm": float(np.max(np.abs(found.depth_mm - twin.landmarks_depth_mm))),
    }
    return fill_dataset(ds, found), detection


def row(seed: int, folder: Path, detection: dict, result) -> dict:
    """One seed's row: its calibration evaluated on the twin's held-out targets."""
    rows = {r.label: r for r in evaluate_twin(result, folder)}
    return {"seed": seed, **detection, "F1": result.stage1.F, "F2": result.stage2.F,
            "rows": rows, "warnings": [w.text.split(" is on")[0] for w in result.warnings]}


def table(runs: list[dict]) -> str:
    head = (
        "| seed | centroid RMS px | depth max err mm | F1st mm | F2nd mm "
        "| stage 1 mean / max mm | stage 2 mean / max mm | oracle mean / max mm "
        "| oracle + stage 2 mean / max mm "
        "| stage 1 mean / max tablet px | stage 2 mean / max tablet px "
        "| oracle mean / max tablet px | oracle + stage 2 mean / max tablet px | on a bound |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    )
    lines = [head]

    def mm(r):
        return f"{r.mean_mm:.3f} / {r.max_mm:.3f}"

    def px(r):
        return f"{r.mean_px:.2f} / {r.max_px:.2f}"

    for x in runs:
        r = x["rows"]
        lines.append(
            f"| {x['seed']} | {x['centroid_rms_px']:.3f} | {x['depth_max_mm']:.2f} | "
            f"{x['F1']:.3f} | {x['F2']:.3f} | {mm(r['stage 1'])} | {mm(r['stage 2'])} | "
            f"{mm(r['oracle'])} | {mm(r['oracle + stage 2'])} | "
            f"{px(r['stage 1'])} | {px(r['stage 2'])} | {px(r['oracle'])} | "
            f"{px(r['oracle + stage 2'])} | "
            f"{', '.join(x['warnings']) or '-'} |"
        )

    def avg(label, attr):
        return np.mean([getattr(x["rows"][label], attr) for x in runs])

    lines.append(
        f"| mean | {np.mean([x['centroid_rms_px'] for x in runs]):.3f} | "
        f"{np.max([x['depth_max_mm'] for x in runs]):.2f} (max) | "
        f"{np.mean([x['F1'] for x in runs]):.3f} | {np.mean([x['F2'] for x in runs]):.3f} | "
        + " | ".join(
            f"{avg(lab, 'mean_mm'):.3f} / {avg(lab, 'max_mm'):.3f}"
            for lab in ("stage 1", "stage 2", "oracle", "oracle + stage 2")
        )
        + " | "
        + " | ".join(
            f"{avg(lab, 'mean_px'):.2f} / {avg(lab, 'max_px'):.2f}"
            for lab in ("stage 1", "stage 2", "oracle", "oracle + stage 2")
        )
        + " | |"
    )
    better = sum(x["rows"]["stage 2"].mean_mm < x["rows"]["stage 1"].mean_mm for x in runs)
    on_truth = sum(
        x["rows"]["oracle + stage 2"].mean_mm < x["rows"]["oracle"].mean_mm for x in runs
    )
    lines.append(
        f"\nstage 2 has the lower mean held-out error in {better} of {len(runs)} seeds; "
        f"on top of the true parameters, in {on_truth} of {len(runs)}."
    )
    return "\n".join(lines)


def write_section(path: Path, heading: str, text: str) -> None:
    """Put ``text`` (which starts with ``heading``) in ``path``, replacing only that section."""
    old = path.read_text() if path.exists() else ""
    if heading + "\n" in old:
        start = old.index(heading + "\n")
        nxt = old.find("\n## ", start + len(heading))
        new = old[:start] + text + ("\n" + old[nxt + 1 :] if nxt >= 0 else "")
    else:
        new = old.rstrip("\n") + "\n\n" + text
    path.write_text(new.rstrip("\n") + "\n")


def main() -> None:
    vectorise_small_loops()  # as the command line does
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--preset", choices=sorted(PRESETS), default="paper")
    ap.add_argument("--dot-px", type=float, default=1.0,
                    help="landmark dot size, tablet px (paper: 1; harsh needs 2)")  # fmt: skip
    ap.add_argument("--population", type=int, default=Settings.population)
    ap.add_argument("--generations", type=int, default=Settings.generations)
    ap.add_argument("--results", type=Path, default=RESULTS, help="Markdown file to update")
    args = ap.parse_args()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        folders = [Path(tmp) / f"seed{seed}" for seed in args.seeds]
        made = [prepare_seed(seed, args.preset, f, args.dot_px)
                for seed, f in zip(args.seeds, folders, strict=True)]  # fmt: skip
        # Every seed in one batch: each result is its own calibrate's, bit for bit.
        results = calibrate_batch(
            [ds for ds, _ in made],
            [Settings(model="htm", seed=seed, population=args.population,
                      generations=args.generations) for seed in args.seeds],
            progress=True,
        )  # fmt: skip
        runs = [row(seed, f, detection, r) for seed, f, (_, detection), r in
                zip(args.seeds, folders, made, results, strict=True)]  # fmt: skip
    seeds = " ".join(map(str, args.seeds))
    command = f"python benchmarks/twin_study.py --seeds {seeds} --preset {args.preset}"
    if args.dot_px != 1.0:
        command += f" --dot-px {args.dot_px:g}"
    if (args.population, args.generations) != (Settings.population, Settings.generations):
        command += f" --population {args.population} --generations {args.generations}"
    heading = f"{HEADING} (preset {args.preset}"
    heading += f", {args.dot_px:g} px dots)" if args.dot_px != 1.0 else ")"
    text = (
        f"{heading}\n\ncommand: {command}\n"
        f"machine: {platform.machine()}, jax {jax.__version__}; float64; "
        f"{time.strftime('%Y-%m-%d')}; {time.perf_counter() - t0:.0f} s\n"
        f"each seed: a rig truth drawn from `twin.RANGES`, preset `{args.preset}`, "
        f"{args.dot_px:g}-tablet-px dots, landmarks "
        "detected in the written PNGs, HTM calibration (DE + LM), 20 held-out targets inside "
        "the landmark area at hand angles in [0, 180) deg. Touching error = where the true pen "
        "lands on the display minus the target; oracle = the true parameters with the same "
        "measured observations of the targets; oracle + stage 2 = the true parameters with a "
        "stage-2 correction fitted to the same dataset.\n\n" + table(runs)
    )
    print(text)
    write_section(args.results, heading, text)


if __name__ == "__main__":
    main()
