"""Convergence on the paper's F1st: DE alone, DE then LM, multi-start LM and multi-start BFGS.

    python benchmarks/convergence.py                  # 5 seeds, N = 500, k = 25 50 100 200, M = 256
    python benchmarks/convergence.py --quick          # tiny sizes, for the test suite

All methods minimise the same stage-1 HTM objective F1st (data/paper2023.toml, float64, the
Table 5 box, D = 12). A run succeeds when it reaches F1st <= 1.675 mm (the optimum is
1.67386 mm). For each method the script prints one Markdown row: seeds that succeeded, the
per-start success fraction (multi-starts), the median objective evaluations and wall time to
reach the target, and the best F1st found; then one row per seed with details. It saves
``convergence.png`` and ``convergence.svg`` (best F1st against evaluations) in ``--out-dir``.

Methods and accounting:

* **DE alone**: ``DifferentialEvolution`` with ``calibrate``'s defaults (N = 500, G <= 3000,
  early stop at ``std(F) <= 1e-3·|mean(F)|``). Evaluations to success are ``N·(g + 1)``, ``g``
  the first generation whose best F is at the target (+1 for the initial population). Its wall
  time to success is measured by running the same DE (same key, so the same trajectory) again
  with ``generations=g``; DE runs in jitted chunks of 64 generations, so that time includes
  up to 63 computed and discarded generations.
  The same DE without the early stop is shown as well; with the same key it is the same run
  continued, since generation ``g`` always draws from random stream ``g``.
* **DE for k generations, then LM**: DE with ``early_stop=False``, ``generations=k``, then
  ``LevenbergMarquardt`` from the best member inside the box. Evaluations are
  ``N·(k + 1) + steps·(1 + D)``.
* **Multi-start LM / BFGS**: M starts uniform in the box (the same starts for both), solved in
  one ``jax.vmap``-ed call of ``optimistix.least_squares`` (LevenbergMarquardt on F1st's
  residuals) or ``optimistix.minimise`` (BFGS on F1st itself), both in the sine-transformed
  box coordinates of ``handeye_jax.optim._box``. The expected evaluations to a first success
  are (mean cost per start) / (success fraction), and the expected wall time likewise
  (batch wall time / M) / (success fraction).

Cost convention: one LM or BFGS step counts as ``1 + D`` objective evaluations (one residual
or F evaluation plus a D-column Jacobian or gradient), D = 12. Wall times exclude JIT
compilation: every configuration is run once first on a seed not in the table.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from handeye_jax import HTMModel, Settings, Stage1Objective, load_dataset, vectorise_small_loops
from handeye_jax.optim import Box, DifferentialEvolution, LevenbergMarquardt, minimise

PAPER = Path(__file__).resolve().parents[1] / "data" / "paper2023.toml"
TARGET = 1.675  # mm, success threshold on F1st
F_OPT = 1.67386  # mm, the known optimum of F1st on the paper's data
D = len(HTMModel.param_names)
STEP_COST = 1 + D  # objective-evaluation equivalents per LM / BFGS step
WARMUP_SEED = 10_000  # compiles every configuration; never in the table
TWIN = [HTMModel.param_names.index(n) for n in HTMModel.sign_twin]  # alpha_t, beta_t
RTOL = ATOL = 1e-12  # LM and BFGS tolerances, as LevenbergMarquardt's defaults
MAX_STEPS = 1000


@dataclass
class Run:
    """One method on one seed. ``evals``/``wall``: to the target, NaN if it was not reached."""

    method: str
    seed: int
    f: float
    evals_used: float
    wall_used: float
    evals: float = float("nan")
    wall: float = float("nan")
    success_fraction: float = float("nan")  # multi-starts only
    twin: str = ""
    note: str = ""
    curve: tuple[np.ndarray, np.ndarray] | None = None  # (evaluations, best F) for the plot
    extra: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.f <= TARGET


def _twin(x: np.ndarray) -> str:
    a, b = (float(x[i]) for i in TWIN)
    return f"({a:+.1f}, {b:+.1f})"


def _timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args, **kwargs))
    return out, time.perf_counter() - t0


# ---------------------------------------------------------------- DE alone, DE + LM


def _de(obj, lo, hi, *, key, **config):
    return minimise(obj, DifferentialEvolution(**config), Box(lo, hi), key=key)


def de_alone(obj, lo, hi, seed, n, g_max, tol, early_stop, label) -> Run:
    key = jax.random.PRNGKey(seed)
    de, wall = _timed(_de, obj, lo, hi, key=key, population=n, generations=g_max, tol=tol,
                      early_stop=early_stop)  # fmt: skip
    hist = de.best_history
    gens = np.arange(1, len(hist) + 1)
    run = Run(label, seed, de.value, de.evaluations, wall, twin=_twin(de.x),
              curve=(n * (gens + 1), hist), extra={"generations": de.steps})  # fmt: skip
    hit = np.nonzero(hist <= TARGET)[0]
    if hit.size:
        g = int(hit[0]) + 1
        run.evals = n * (g + 1)
        # The same run stopped at generation g (same key: the same trajectory), timed.
        _, run.wall = _timed(_de, obj, lo, hi, key=key, population=n, generations=g, tol=tol,
                             early_stop=early_stop)  # fmt: skip
    run.note = f"{de.steps} generations" + (", early stop" if de.converged else "")
    return run


def de_then_lm(obj, lo, hi, seed, n, k) -> Run:
    de, t_de = _timed(_de, obj, lo, hi, key=jax.random.PRNGKey(seed), population=n,
                      generations=k, early_stop=False)  # fmt: skip
    t0 = time.perf_counter()
    lm = minimise(obj, LevenbergMarquardt(rtol=RTOL, atol=ATOL), Box(lo, hi), x0=de.x)
    f_lm = lm.value
    t_lm = time.perf_counter() - t0
    x, f = (lm.x, f_lm) if f_lm < de.value else (de.x, de.value)
    evals = n * (k + 1) + lm.steps * STEP_COST
    run = Run(f"DE {k} gen + LM", seed, f, evals, t_de + t_lm, twin=_twin(x),
              note=f"DE F {de.value:.4f}, LM {lm.steps} steps")  # fmt: skip
    if run.ok:
        run.evals, run.wall = evals, t_de + t_lm
    return run


# ---------------------------------------------------------------- multi-starts


def _finish(box, obj, sol):
    x = box.to_x(sol.value)
    return x, obj(x), sol.stats["num_steps"], sol.result == optx.RESULTS.successful


@eqx.filter_jit
def multistart_lm(obj, x0s, box, jac: str):
    """LM from every row of ``x0s`` at once, on the sine-transformed box as in polish.py."""

    def one(x0):
        sol = optx.least_squares(
            lambda z, _: obj.residuals(box.to_x(z)), optx.LevenbergMarquardt(rtol=RTOL, atol=ATOL),
            box.to_z(x0), max_steps=MAX_STEPS, throw=False, options={"jac": jac},
        )  # fmt: skip
        return _finish(box, obj, sol)

    return jax.vmap(one)(x0s)


@eqx.filter_jit
def multistart_bfgs(obj, x0s, box):
    """BFGS on F1st itself from every row of ``x0s`` at once, in the same box coordinates."""

    def one(x0):
        sol = optx.minimise(
            lambda z, _: obj(box.to_x(z)), optx.BFGS(rtol=RTOL, atol=ATOL), box.to_z(x0),
            max_steps=MAX_STEPS, throw=False,
        )  # fmt: skip
        return _finish(box, obj, sol)

    return jax.vmap(one)(x0s)


def starts(seed: int, m: int, lo, hi):
    return jax.random.uniform(jax.random.PRNGKey(seed), (m, D), minval=lo, maxval=hi)


def multistart(label, solve, obj, lo, hi, seed, m) -> Run:
    x0s = starts(seed, m, lo, hi)
    (x, f, steps, solver_ok), wall = _timed(solve, x0s)
    x, f, steps = np.asarray(x), np.asarray(f), np.asarray(steps)
    f = np.where(np.isfinite(f), f, np.inf)
    cost = steps * STEP_COST
    ok = f <= TARGET
    p = float(ok.mean())
    i = int(np.argmin(f))
    plus = int(np.sum(x[ok, TWIN[1]] > 0))
    # Best final F so far over the starts in their order, at the cumulative cost.
    curve = (np.cumsum(cost), np.minimum.accumulate(f))
    run = Run(label, seed, float(f[i]), float(cost.sum()), wall, success_fraction=p,
              twin=_twin(x[i]), curve=curve)  # fmt: skip
    if p > 0:
        run.evals = float(cost.mean()) / p
        run.wall = wall / m / p
    run.note = (
        f"{ok.sum()}/{m} starts at target (βt > 0: {plus}, βt < 0: {ok.sum() - plus}); "
        f"mean {steps.mean():.0f} steps; {np.mean(steps >= MAX_STEPS):.0%} stopped at "
        f"max_steps, {np.mean(~np.asarray(solver_ok)):.0%} not converged"
    )
    return run


# ---------------------------------------------------------------- report


def _fmt_evals(v: float) -> str:
    return f"{v:,.0f}"


def summary_row(label: str, runs: list[Run], multistart: bool) -> str:
    won = [r for r in runs if r.ok]
    seeds = f"{len(won)}/{len(runs)}"
    if multistart:
        fr = [r.success_fraction for r in runs]
        per_start = f"{np.mean(fr):.1%} ({min(fr):.0%}–{max(fr):.0%})"
    else:
        per_start = "—"
    if won:
        evals = _fmt_evals(np.median([r.evals for r in won]))
        wall = f"{np.median([r.wall for r in won]):.3g}"
    else:
        evals = f"not reached (used {_fmt_evals(np.median([r.evals_used for r in runs]))})"
        wall = f"not reached (ran {np.median([r.wall_used for r in runs]):.3g})"
    best = min(r.f for r in runs)
    return f"| {label} | {seeds} | {per_start} | {evals} | {wall} | {best:.6f} |"


def seed_row(r: Run) -> str:
    return (
        f"| {r.method} | {r.seed} | {r.f:.6f} | {'yes' if r.ok else 'no'} | "
        f"{_fmt_evals(r.evals_used)} | {r.wall_used:.3g} | {r.twin} | {r.note} |"
    )


# ---------------------------------------------------------------- plot


def plot(groups: dict[str, list[Run]], de_stop: str, de_full: str, lm_labels: list[str],
         out_dir: Path) -> None:  # fmt: skip
    """Best F1st − optimum against evaluations, log-log. The early-stopped DE is a prefix of
    the full one (same key, same random stream per generation): its curve is the full one's,
    and a cross marks where the early stop ends it."""
    # Distances are taken from the best F1st that any run found (F_OPT is rounded), and drawn
    # at the floor when a run reached it.
    floor = 1e-9
    f_best = min(r.f for runs in groups.values() for r in runs)

    def gap(f):
        return np.maximum(np.asarray(f, dtype=float) - f_best, floor)

    fig = Figure(figsize=(11, 7.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for i, r in enumerate(groups[de_full]):
        ev, f = r.curve
        ax.plot(ev, gap(f), color="C0", lw=0.9, alpha=0.8,
                label="DE alone, one line per seed" if i == 0 else None)  # fmt: skip
    for i, r in enumerate(groups[de_stop]):
        stop = "DE alone: where the default early stop ends it"
        ax.plot(r.evals_used, gap(r.f), "x", color="C0", ms=9, mew=2,
                label=stop if i == 0 else None)  # fmt: skip
    markers = "os^Dv<>p"
    for j, label in enumerate(lm_labels):
        runs = groups[label]
        ax.plot([r.evals_used for r in runs], gap([r.f for r in runs]), markers[j % 8],
                color="C1", ms=7, mew=1.5, alpha=0.8, linestyle="none",
                label=f"{label} (final point per seed)")  # fmt: skip
    for label, color, ls, lw, mk in (("multi-start LM", "C2", "-", 2.2, "v"),
                                     ("multi-start BFGS", "C3", "--", 1.2, "^")):  # fmt: skip
        firsts = []
        for i, r in enumerate(groups[label]):
            ev, f = r.curve
            ax.step(ev, gap(f), where="post", color=color, ls=ls, lw=lw, alpha=0.85,
                    label=f"{label}: best so far over the starts" if i == 0 else None)  # fmt: skip
            hit = np.nonzero(f <= TARGET)[0]
            if hit.size:
                firsts.append((ev[hit[0]], f[hit[0]]))
        if firsts:
            ev, f = np.array(firsts).T
            ax.plot(ev, gap(f), mk, color=color, mec="k", mew=0.6, ms=10, ls="none", zorder=5,
                    label=f"{label}: first start at the target")  # fmt: skip
    ax.axhline(TARGET - f_best, color="0.3", ls="--", lw=1.2,
               label=f"target: F1st = {TARGET} mm")  # fmt: skip
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("objective evaluations (LM / BFGS step = 1 + D = 13 evaluations)")
    ax.set_ylabel(f"best F1st − {f_best:.7f} mm (mm; {floor:g} = reached it)")
    n_seeds = len(groups[de_full])
    ax.set_title(
        f"Stage-1 F1st on the paper's data (HTM, D = 12, {n_seeds} seeds): best F1st against "
        f"cost\ny axis: distance above the best F1st any run found, {f_best:.7f} mm"
    )
    ax.grid(True, which="major", alpha=0.35)
    fig.legend(loc="outside lower center", ncols=3, fontsize=9)
    out_dir.mkdir(parents=True, exist_ok=True)
    for ext in ("png", "svg"):
        fig.savefig(out_dir / f"convergence.{ext}", dpi=130)


# ---------------------------------------------------------------- main


def main() -> None:
    vectorise_small_loops()  # as the command line does
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="number of seeds S (seeds 1..S)")
    ap.add_argument("--population", type=int, default=Settings.population)
    ap.add_argument("--generations", type=int, default=Settings.generations)
    ap.add_argument("--tol", type=float, default=Settings.tol)
    ap.add_argument("--k", type=int, nargs="+", default=[25, 50, 100, 200],
                    help="DE generations before LM")  # fmt: skip
    ap.add_argument("--starts", type=int, default=256, help="multi-start count M")
    ap.add_argument("--jac", choices=("bwd", "fwd"), default="bwd",
                    help="Jacobian mode of multi-start LM")  # fmt: skip
    ap.add_argument("--out-dir", type=Path, default=Path(__file__).resolve().parent / "results")
    ap.add_argument("--quick", action="store_true", help="N 40, G 60, k 5, M 8, one seed")
    args = ap.parse_args()
    if args.quick:
        args.seeds, args.population, args.generations, args.k, args.starts = 1, 40, 60, [5], 8
    n, g_max, m = args.population, args.generations, args.starts
    seeds = list(range(1, args.seeds + 1))
    t_start = time.perf_counter()

    print(f"# convergence to F1st <= {TARGET} mm on paper2023 (HTM, D = {D}; optimum {F_OPT})")
    print(f"\ncommand: python benchmarks/convergence.py {' '.join(sys.argv[1:])}".rstrip())
    print(f"date: {datetime.datetime.now().isoformat(timespec='seconds')}")
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"jax {jax.__version__} on {jax.default_backend()}")  # fmt: skip
    print(f"seeds: {seeds}; DE N = {n}, G <= {g_max}, tol = {args.tol:g}; k = {args.k}; "
          f"M = {m} starts; LM / BFGS rtol = atol = {RTOL:g}, max {MAX_STEPS} steps, "
          f"LM Jacobian {args.jac}")  # fmt: skip
    sys.stdout.flush()

    ds = load_dataset(PAPER)
    with jax.enable_x64(True):
        obj = Stage1Objective(HTMModel, ds.observations())
        lo, hi = HTMModel.search_bounds(ds.search)
        box = Box(jnp.asarray(lo), jnp.asarray(hi))

        de_label = f"DE alone, calibrate defaults (N {n}, G ≤ {g_max}, tol {args.tol:g})"
        de_full = f"DE alone, early stop off (N {n}, G = {g_max})"
        lm_labels = [f"DE {k} gen + LM" for k in args.k]
        configs = [
            (de_label, False, lambda s: de_alone(obj, lo, hi, s, n, g_max, args.tol, True,
                                                 de_label)),
            (de_full, False, lambda s: de_alone(obj, lo, hi, s, n, g_max, args.tol, False,
                                                de_full)),
            *[(lab, False, lambda s, k=k: de_then_lm(obj, lo, hi, s, n, k))
              for lab, k in zip(lm_labels, args.k, strict=True)],
            ("multi-start LM", True, lambda s: multistart(
                "multi-start LM", lambda x0s: multistart_lm(obj, x0s, box, args.jac),
                obj, lo, hi, s, m)),
            ("multi-start BFGS", True, lambda s: multistart(
                "multi-start BFGS", lambda x0s: multistart_bfgs(obj, x0s, box),
                obj, lo, hi, s, m)),
        ]  # fmt: skip
        groups: dict[str, list[Run]] = {}
        for label, _, run in configs:
            run(WARMUP_SEED)  # compile; not timed, not reported
            groups[label] = [run(s) for s in seeds]

    print(
        "\n| method | seeds reaching target | per-start success (mean, min–max) "
        f"| median evaluations to F1st ≤ {TARGET} | median wall time to target (s) "
        "| best F1st (mm) |\n|---|---|---|---|---|---|"
    )
    for label, is_multi, _ in configs:
        print(summary_row(label, groups[label], is_multi))
    print(
        "\nNotes. Medians are over the seeds that reached the target. LM / BFGS steps count "
        f"as 1 + D = {STEP_COST} objective evaluations each (one residual or F evaluation "
        "plus a D-column Jacobian or gradient). DE alone: evaluations N·(g + 1) at the first "
        "generation g at the target; wall time: the same run re-timed with G = g (chunks of 64 "
        "generations, so up to 63 discarded ones included). DE + LM: "
        "N·(k + 1) + LM steps·13, wall = DE + LM. Multi-starts: expected evaluations to a "
        "first success = (mean cost per start) / (success fraction); expected wall time = "
        "(batch wall time / M) / (success fraction), the M starts solved in one vmapped "
        "call. Wall times exclude JIT compilation (each configuration warmed up on seed "
        f"{WARMUP_SEED})."
    )
    print(
        "\n## per seed\n\n| method | seed | best F1st (mm) | at target | evaluations used "
        "| wall s | (αt, βt) deg of best | notes |\n|---|---|---|---|---|---|---|---|"
    )
    for label, _, _ in configs:
        for r in groups[label]:
            print(seed_row(r))

    plot(groups, de_label, de_full, lm_labels, args.out_dir)
    print(f"\nplot: {args.out_dir / 'convergence.png'} (and .svg)")
    print(f"total runtime: {time.perf_counter() - t_start:.0f} s (including compilation)")


if __name__ == "__main__":
    main()
