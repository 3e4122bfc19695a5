"""How one DE generation's time grows with the population and with the number of landmarks.

    python benchmarks/scaling.py            # N = 10^2 … 10^5; 9 … 900 landmarks
    python benchmarks/scaling.py --quick    # tiny sizes, for the test suite

Stage-1 HTM objective, float64, after compilation, median over chunks of 64 generations.
Landmark counts above 9 use exact synthetic data (a k×k snake grid on the tablet), so the
objective's work per member grows with the landmarks. Prints Markdown tables with the time
per member (ns), whose flatness shows where the cost is linear, and saves scaling.png/.svg.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import jax
import numpy as np

from handeye_jax import HTMModel, Rig, load_dataset
from handeye_jax.objective import Stage1Objective
from handeye_jax.synthetic import snake_grid_px, synthesize_dataset

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import PAPER, de_generation_ms  # noqa: E402

TRUTH = dict(xc=-2.0, yc=34.0, alpha_c=-0.5, beta_c=0.5, gamma_c=0.7, xt=193.3, yt=31.6,
             alpha_t=1.5, beta_t=-11.9, gamma_t=-1.3, xp=-0.5, yp=-22.3)  # fmt: skip


def landmark_objective(k: int) -> Stage1Objective:
    """Exact synthetic data on a k×k grid spanning the paper's landmark area."""
    rig = Rig(617.7, 617.7, 316.5, 242.3, [320.0, -70.0, 290.0], 90.0, -1.0)
    grid = snake_grid_px(tuple(np.linspace(400, 1040, k)), tuple(np.linspace(150, 550, k)))
    angles = np.linspace(0.0, 180.0, k * k)
    ds = synthesize_dataset(HTMModel.from_dict(TRUTH), rig, grid, angles)
    return Stage1Objective(HTMModel, ds.observations())


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
    ap.add_argument("--populations", type=int, nargs="+",
                    default=[100, 300, 1_000, 3_000, 10_000, 30_000, 100_000])  # fmt: skip
    ap.add_argument("--grid", type=int, nargs="+", default=[3, 6, 10, 20, 30],
                    help="k for k×k landmark grids (k=30: 900 landmarks)")  # fmt: skip
    ap.add_argument("--landmark-population", type=int, default=1_000)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--out-dir", type=Path, default=Path(__file__).resolve().parent)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    if args.quick:
        args.populations, args.grid, args.landmark_population, args.reps = [50, 200], [3, 4], 50, 2

    print(f"# DE scaling, {time.strftime('%Y-%m-%d')}")
    print(f"command: python benchmarks/{Path(__file__).name} {' '.join(sys.argv[1:])}")
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, jax {jax.__version__}; float64")
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
