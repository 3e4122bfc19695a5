"""How a calibration's time grows with the population and with the number of landmarks.

    python benchmarks/scaling.py            # both sections below
    python benchmarks/scaling.py --sections calibration --calibration-landmarks 30 100
    python benchmarks/scaling.py --quick    # tiny sizes, for the test suite

Section ``de``: one DE generation, stage-1 HTM objective, float64, after compilation, median
over chunks of 64 generations, against N = 10^2 … 10^5 and 9 … 900 landmarks (exact synthetic
data on a k×k snake grid, so the objective's work per member grows with the landmarks).
Prints the time per member (ns), whose flatness shows where the cost is linear, and saves
scaling.png/.svg.

Section ``calibration``: a whole default calibration (``calibrate``, diagnostics on) of
synthetic data with 30 … 10,000 landmarks on a grid, with the ``paper`` preset's noise (touch
errors σ 0.45 mm reported in whole tablet px, hand positions in whole mm, 0.15 px on the image
points). Each size runs in a fresh process, so its peak memory (``ru_maxrss``) is its own; the
times are the result's ``timings_s`` (DE, LM polish with its restarts, diagnostics; both
stages summed), the first call including compilation, the second without. Saves
scaling_calibration.json and, with ``--before FILE`` (that JSON from another checkout, e.g.
``PYTHONPATH=/path/to/main python benchmarks/scaling.py --sections calibration``), plots
both in scaling_calibration.png/.svg.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np

from handeye_jax import (
    HTMModel,
    Rig,
    Stage1Objective,
    load_dataset,
    snake_grid_px,
    synthesize_dataset,
)
from handeye_jax import geometry as geo

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import PAPER, de_generation_ms  # noqa: E402

TRUTH = dict(xc=-2.0, yc=34.0, alpha_c=-0.5, beta_c=0.5, gamma_c=0.7, xt=193.3, yt=31.6,
             alpha_t=1.5, beta_t=-11.9, gamma_t=-1.3, xp=-0.5, yp=-22.3)  # fmt: skip


RIG = Rig(617.7, 617.7, 316.5, 242.3, [320.0, -70.0, 290.0], 90.0, -1.0)
#: Landmark counts of the calibration section and their grids (columns × rows).
GRIDS = {9: (3, 3), 30: (6, 5), 100: (10, 10), 300: (20, 15), 1_000: (40, 25),
         3_000: (60, 50), 10_000: (100, 100)}  # fmt: skip


def landmark_objective(k: int) -> Stage1Objective:
    """Exact synthetic data on a k×k grid spanning the paper's landmark area."""
    grid = snake_grid_px(tuple(np.linspace(400, 1040, k)), tuple(np.linspace(150, 550, k)))
    angles = np.linspace(0.0, 180.0, k * k)
    ds = synthesize_dataset(HTMModel.from_dict(TRUTH), RIG, grid, angles)
    return Stage1Objective(HTMModel, ds.observations())


def noisy_landmarks(n: int, seed: int = 0):
    """A dataset of ``n`` landmarks (a count of :data:`GRIDS`) with the paper preset's noise."""
    kx, ky = GRIDS[n]
    grid = snake_grid_px(tuple(np.linspace(400, 1040, kx)), tuple(np.linspace(150, 550, ky)))
    rng = np.random.default_rng(seed)
    touch_px = rng.normal(0.0, 0.45, (n, 2)) / geo.mm_per_tablet_px(267.0, 2.0)
    ds = synthesize_dataset(HTMModel.from_dict(TRUTH), RIG, grid, np.linspace(0.0, 180.0, n),
                            touch_error_px=touch_px).replace(name=f"grid-{n}")  # fmt: skip
    return ds.replace(
        image_px=ds.image_px + rng.normal(0.0, 0.15, (n, 2)),
        hand_xy_mm=np.round(ds.hand_xy_mm), touch_error_px=np.round(touch_px),
    )  # fmt: skip


def calibrate_once(n: int, quick: bool, diagnostics: bool = True, warm: bool = True) -> dict:
    """In this process: calibrate :func:`noisy_landmarks` (cold, then warm again)."""
    from handeye_jax import Settings, calibrate, diagnose

    settings = Settings()
    if quick:
        settings = Settings(population=50, generations=60)
    ds = noisy_landmarks(n)
    out = {"landmarks": n}
    for run in ("cold", "warm")[: 1 + warm]:
        r = calibrate(ds, settings)
        t = (diagnose(r, search=ds.search) if diagnostics else r).timings_s
        out[run] = {
            "de": t["stage1_de"] + t["stage2_de"],
            "polish": t["stage1_polish"] + t["stage2_polish"],
            "diagnostics": t.get("diagnostics", 0.0),
            "total": t["total"],
        }
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def calibration_section(
    landmarks, quick: bool, timeout_s: float, memory_gb: float, diagnostics: bool, warm: bool
) -> list:
    """Each size in a fresh process with a time and an address-space limit (``quick``: in
    this one)."""
    print("\n| landmarks | DE s | LM + restarts s | diagnostics s | total s | total warm s "
          "| peak memory MB |\n|---|---|---|---|---|---|---|")  # fmt: skip
    rows = []
    for n in landmarks:
        if quick:  # in this process, reusing its compiled programs: a smoke test
            rows.append(calibrate_once(n, quick, diagnostics, warm))
            _print_row(rows[-1])
            continue
        cmd = [sys.executable, __file__, "--one-calibration", str(n), "--memory-gb",
               str(memory_gb)] + ["--no-diagnostics"] * (not diagnostics) + ["--no-warm"] * (
               not warm)  # fmt: skip
        try:
            p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired:
            print(f"| {n:,} | not finished in {timeout_s:.0f} s | | | | | |", flush=True)
            rows.append({"landmarks": n, "failed": f"timeout {timeout_s:.0f} s"})
            continue
        if p.returncode != 0:
            why = (p.stderr.strip().splitlines() or ["?"])[-1][:120]
            print(f"| {n:,} | failed (exit {p.returncode}, {memory_gb:g} GB limit): {why} "
                  "| | | | | |", flush=True)  # fmt: skip
            rows.append({"landmarks": n, "failed": why})
            continue
        rows.append(json.loads(p.stdout.strip().splitlines()[-1]))
        _print_row(rows[-1])
    return rows


def _print_row(row: dict) -> None:
    c = row["cold"]
    warm = f"{row['warm']['total']:.2f}" if "warm" in row else "-"
    print(f"| {row['landmarks']:,} | {c['de']:.2f} | {c['polish']:.2f} | {c['diagnostics']:.2f} "
          f"| {c['total']:.2f} | {warm} | {row['peak_rss_mb']:.0f} |", flush=True)  # fmt: skip


def plot_calibration(rows: list, before: list | None, out_dir: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    parts = (("polish", "LM polish (and restarts)", "C0"), ("diagnostics", "diagnostics", "C1"),
             ("de", "DE", "C2"), ("total", "total", "k"))  # fmt: skip
    for data, style, tag in ((rows, "o-", "this run"), (before or [], "x--", "--before run")):
        ok = [r for r in data if "cold" in r]
        if not ok:
            continue
        n = np.array([r["landmarks"] for r in ok], float)
        for key, label, colour in parts:
            y = np.array([r["cold"][key] for r in ok])
            ax.loglog(n, y, style, color=colour, label=f"{label}, {tag}", lw=1.5)
    ok = [r for r in rows if "cold" in r]
    if ok:
        n = np.array([r["landmarks"] for r in ok], float)
        y = ok[-1]["cold"]["total"] * n / n[-1]
        ax.loglog(n, y, ":", color="grey", label="linear (through the last total)")
    failed = [(tag, r) for tag, data in (("this run", rows), ("--before run", before or []))
              for r in data if "failed" in r]  # fmt: skip
    for i, (tag, r) in enumerate(failed):
        why = r["failed"].split(": ")[-1][:70]  # e.g. XLA's "Out of memory allocating … bytes."
        ax.annotate(f"{tag}: {r['landmarks']:,} landmarks failed:\n{why}",
                    xy=(0.02, 0.97 - 0.12 * i), xycoords="axes fraction", va="top",
                    fontsize=7, color="firebrick")  # fmt: skip
    ax.set_xlabel("landmarks")
    ax.set_ylabel("time of a first calibration (s, compilation included)")
    ax.set_title("calibrate, default settings, against the number of landmarks")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2, loc="lower right")
    fig.tight_layout()
    for ext in ("png", "svg"):
        fig.savefig(out_dir / f"scaling_calibration.{ext}", dpi=130)
    plt.close(fig)


def plot(populations, pop_ms, landmarks, lm_ms, lm_population: int, out_dir: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, x, y, xlabel in (
        (axes[0], populations, pop_ms, "population N"),
        (axes[1], landmarks, lm_ms, "landmarks"),
    ):
        x, y = np.asarray(x, float), np.asarray(y, float)
        ax.loglog(x, y, "o-", lw=2, label="measured")
        ax.loglog(x, y[-1] * x / x[-1], "--", color="grey", label="linear (through last point)")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("time per DE generation (ms)")
        ax.grid(True, which="both", alpha=0.3)
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:,.0f}"))
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.xaxis.set_minor_formatter(FuncFormatter(lambda v, _: ""))
        ax.yaxis.set_minor_formatter(FuncFormatter(lambda v, _: ""))
        ax.legend()
    axes[0].set_title("DE generation time vs population (9 landmarks)")
    axes[1].set_title(f"DE generation time vs landmarks (N = {lm_population:,})")
    fig.suptitle("handeye-jax DE scaling, float64, 2-core CPU", fontsize=12)
    fig.tight_layout()
    for ext in ("png", "svg"):
        fig.savefig(out_dir / f"scaling.{ext}", dpi=130)
    plt.close(fig)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sections", nargs="+", choices=("de", "calibration"),
                    default=["de", "calibration"])  # fmt: skip
    ap.add_argument("--populations", type=int, nargs="+",
                    default=[100, 300, 1_000, 3_000, 10_000, 30_000, 100_000])  # fmt: skip
    ap.add_argument("--grid", type=int, nargs="+", default=[3, 6, 10, 20, 30],
                    help="k for k×k landmark grids (k=30: 900 landmarks)")  # fmt: skip
    ap.add_argument("--landmark-population", type=int, default=1_000)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--calibration-landmarks", type=int, nargs="+", choices=sorted(GRIDS),
                    default=[30, 100, 300, 1_000, 10_000])  # fmt: skip
    ap.add_argument("--timeout", type=float, default=1800.0,
                    help="most seconds per calibration size")  # fmt: skip
    ap.add_argument("--memory-gb", type=float, default=12.0,
                    help="address-space limit of each calibration process, GB")  # fmt: skip
    ap.add_argument("--no-diagnostics", action="store_true",
                    help="calibrate without the diagnostics")  # fmt: skip
    ap.add_argument("--no-warm", action="store_true", help="only the first calibration")
    ap.add_argument("--before", type=Path, help="scaling_calibration.json of another checkout")
    ap.add_argument("--out-dir", type=Path, default=Path(__file__).resolve().parent / "results")
    ap.add_argument(
        "--quick",
        action="store_true",
        help="tiny sizes, the calibration in this process: for the test suite",
    )
    ap.add_argument("--one-calibration", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one_calibration:
        cap = int(args.memory_gb * 2**30)  # before JAX allocates anything
        resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
        row = calibrate_once(args.one_calibration, args.quick, not args.no_diagnostics,
                             not args.no_warm)  # fmt: skip
        print(json.dumps(row))
        return
    if args.quick:
        args.populations, args.grid, args.landmark_population, args.reps = [50, 200], [3, 4], 50, 2
        args.calibration_landmarks = [9]

    print(f"# Scaling, {time.strftime('%Y-%m-%d')}")
    print(f"command: python benchmarks/{Path(__file__).name} {' '.join(sys.argv[1:])}")
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, jax {jax.__version__}; float64; "
          f"load average {os.getloadavg()[0]:.2f}")  # fmt: skip
    if "de" in args.sections:
        de_section(args)
    if "calibration" in args.sections:
        print(f"\ncalibrate, default settings{', no diagnostics' * args.no_diagnostics}; "
              f"each size in a fresh process limited to {args.memory_gb:g} GB and "
              f"{args.timeout:.0f} s")  # fmt: skip
        rows = calibration_section(args.calibration_landmarks, args.quick, args.timeout,
                                   args.memory_gb, not args.no_diagnostics,
                                   not args.no_warm)  # fmt: skip
        (args.out_dir / "scaling_calibration.json").write_text(json.dumps(rows, indent=1) + "\n")
        before = json.loads(args.before.read_text()) if args.before else None
        plot_calibration(rows, before, args.out_dir)
        print(f"\nload average at end {os.getloadavg()[0]:.2f}; "
              f"plot: {args.out_dir / 'scaling_calibration.png'}")  # fmt: skip


def de_section(args) -> None:
    with jax.enable_x64(True):
        paper = Stage1Objective(HTMModel, load_dataset(PAPER).observations())
        print("\n| population N | ms / generation | ns / member |\n|---|---|---|")
        pop_ms = []
        for n in args.populations:
            ms = de_generation_ms(paper, n, args.reps)[0]
            pop_ms.append(ms)
            print(f"| {n:,} | {ms:.3f} | {1e6 * ms / n:.0f} |", flush=True)
        n = args.landmark_population
        print(f"\n| landmarks (N = {n:,}) | ms / generation | ns / member / landmark |")
        print("|---|---|---|")
        landmarks, lm_ms = [], []
        for k in args.grid:
            ms = de_generation_ms(landmark_objective(k), n, args.reps)[0]
            landmarks.append(k * k)
            lm_ms.append(ms)
            print(f"| {k * k} | {ms:.3f} | {1e6 * ms / n / (k * k):.1f} |", flush=True)
    plot(args.populations, pop_ms, landmarks, lm_ms, args.landmark_population, args.out_dir)
    print(f"\nplot: {args.out_dir / 'scaling.png'}")


if __name__ == "__main__":
    main()
