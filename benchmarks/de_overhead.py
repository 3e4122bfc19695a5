"""Where the DE's own time goes: its generation with parts removed, against the objective alone.

    python benchmarks/de_overhead.py              # N = 10,000, the paper's stage 1
    python benchmarks/de_overhead.py --vectors    # also: which XLA fusions are vectorised
    python benchmarks/de_overhead.py --quick      # tiny sizes, for the test suite

Every variant runs inside the DE's own compiled loop (``optim._de._chunk_scan``, with the same
bookkeeping, selection and XLA options); only the way a generation makes its trial vectors
changes. The variants are ablations for measurement, not alternative algorithms:

* ``as shipped``: DE/rand/1/bin as ``DifferentialEvolution`` runs it;
* ``x·(1+ε) trial``: the trial is the member itself, scaled; no draws, no donors, no bounds;
* ``fixed donors``: the shipped mutation and bounds, but the donors are fixed neighbours
  (rows i−1, i−2, i−3) and the crossover mask is fixed (components above the box's centre),
  so nothing is drawn and nothing gathered;
* ``crossover draws only``: the shipped random numbers and crossover test, no donors;
* ``no random gather``: the shipped step with fixed neighbours as donors instead of the
  three random rows (the draws, crossover, mutation and bounds are kept).

All variants and the objective alone are timed in turn, round after round, so the machine's
slow phases hit each alike; the table gives the median and the 10th percentile.
"""

from __future__ import annotations

import argparse
import atexit
import functools
import glob
import os
import re
import shutil
import sys
import tempfile
import time
import types
from pathlib import Path

# XLA reads its dump flags once, at start-up, so --vectors must set them before JAX loads.
if "--vectors" in sys.argv:
    _DUMP = tempfile.mkdtemp(prefix="handeye-xla-")
    atexit.register(shutil.rmtree, _DUMP, ignore_errors=True)
    _FLAGS = f" --xla_dump_to={_DUMP} --xla_dump_hlo_module_re=.*_chunk_scan.*"
    os.environ["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "") + _FLAGS

import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from handeye_jax import (  # noqa: E402
    HTMModel,
    Stage1Objective,  # noqa: E402
    load_dataset,
)
from handeye_jax._jax import loop_compiler_options  # noqa: E402
from handeye_jax.optim import _de as de  # noqa: E402
from handeye_jax.optim import _rng  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import PAPER, de_start, interleaved_ms  # noqa: E402
from de_throughput import _objective_scan  # noqa: E402


def _kept(fn, state, trial, fresh):
    """The shipped generation's end: the members themselves in a fresh state's first pass."""
    return de._select(fn, state, jnp.where(fresh, state.population, trial), fresh)


def _scaled(fn, state, step, fresh):
    return _kept(fn, state, state.population * (1.0 + 1e-12 * step.mutation), fresh)


def _fixed_donors(fn, state, step, fresh):
    pop, lower, upper = state.population, step.lower, step.upper
    base, b, c = (jnp.roll(pop, k, axis=0) for k in (1, 2, 3))
    trial = jnp.where(pop > 0.5 * (lower + upper), base + step.mutation * (b - c), pop)
    trial = jnp.where(trial < lower, 0.5 * (base + lower), trial)
    trial = jnp.where(trial > upper, 0.5 * (base + upper), trial)
    return _kept(fn, state, trial, fresh)


def _draws_only(fn, state, step, fresh):
    pop = state.population
    n, d = pop.shape
    u = _rng.uniforms(state.seed, state.generation, (n, d + 4))
    j_rand = jnp.floor(u[:, 3] * d).astype(jnp.int32)
    cross = (u[:, 4:] < step.crossover) | (jnp.arange(d)[None, :] == j_rand[:, None])
    return _kept(fn, state, jnp.where(cross, pop * (1.0 + 1e-12 * step.mutation), pop), fresh)


def _no_random_gather(fn, state, step, fresh):
    pop = state.population
    n, d = pop.shape
    u = _rng.uniforms(state.seed, state.generation, (n, d + 4))
    donors = jnp.stack([jnp.roll(pop, k, axis=0) for k in (1, 2, 3)])
    return _kept(fn, state, de._trial(pop, donors, u, step), fresh)


def _loop_with(generation, name: str):
    """The DE's compiled loop with its generation step replaced (same code, other global)."""
    scan = types.FunctionType(
        de._chunk_scan.__code__, {**vars(de), "_generation": generation}, name
    )
    return eqx.filter_jit(scan, compiler_options=loop_compiler_options())


def vector_report(dump_dir: str, n: int) -> list[tuple[str, str, int]]:
    """(fusion, output shape, vector instructions) of the shipped DE loop's XLA fusions with at
    least ``n`` output elements (one or more per member), read from the optimised LLVM IR
    that XLA dumped; 0 vector instructions means the fusion runs as scalar code."""
    hlo = sorted(glob.glob(f"{dump_dir}/*_chunk_scan.cpu_after_optimizations.txt"))
    shapes = dict(re.findall(r"%(\S+) = (\S+) fusion\(", Path(hlo[0]).read_text())) if hlo else {}
    rows = []
    for f in sorted(glob.glob(f"{dump_dir}/*_chunk_scan.*_kernel_module.ir-with-opt.ll")):
        name = re.search(r"_chunk_scan\.(.+)_kernel_module", f).group(1)
        ir = Path(f).read_text()
        vectors = len(re.findall(r"<\d+ x (?:double|float|i64|i32|i1)>", ir))
        shape = shapes.get(name, "?")
        dims = re.search(r"\[([\d,]*)\]", shape)
        size = int(np.prod([int(x) for x in dims.group(1).split(",") if x])) if dims else 0
        if size >= n:
            rows.append((name, shape, vectors))
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--population", type=int, default=10_000)
    ap.add_argument("--rounds", type=int, default=20, help="timed rounds of every variant")
    ap.add_argument("--vectors", action="store_true", help="report vectorised XLA fusions")
    ap.add_argument("--quick", action="store_true", help="tiny sizes, for the tests")
    args = ap.parse_args(argv)
    if args.quick:
        args.population, args.rounds = 64, 2

    with jax.enable_x64(True):
        objective = Stage1Objective(HTMModel, load_dataset(PAPER).observations())
        n = args.population
        state, lower, upper, settings = de_start(objective, n)
        k = de.CHUNK_GENERATIONS
        loops = {
            "as shipped": de._chunk,
            "x·(1+ε) trial": _loop_with(_scaled, "_chunk_scaled"),
            "fixed donors": _loop_with(_fixed_donors, "_chunk_fixed_donors"),
            "crossover draws only": _loop_with(_draws_only, "_chunk_draws_only"),
            "no random gather": _loop_with(_no_random_gather, "_chunk_no_random_gather"),
        }
        calls = {name: functools.partial(f, objective, state, *settings)
                 for name, f in loops.items()}  # fmt: skip
        alone = eqx.filter_jit(_objective_scan, compiler_options=loop_compiler_options())
        # Over columns, as the DE maps its objective over the trials.
        calls["objective alone"] = lambda: alone(objective, state.population, k, "columns")
        ms = {name: [t / k for t in ts] for name, ts in interleaved_ms(calls, args.rounds).items()}

    print(f"# DE overhead by ablation, {time.strftime('%Y-%m-%d')}")
    print(f"command: python benchmarks/{Path(__file__).name} {' '.join(sys.argv[1:])}")
    print(f"{os.cpu_count()} cores, jax {jax.__version__}, float64; paper stage 1 (HTM), "
          f"N = {n:,}; {args.rounds} rounds of {k} generations each\n")  # fmt: skip
    ref_med = float(np.median(ms["objective alone"]))
    ref_p10 = float(np.percentile(ms["objective alone"], 10))
    print("| generation | median ms | p10 ms | over the objective alone (median, p10) |")
    print("|---|---|---|---|")
    for name, t in ms.items():
        med, p10 = float(np.median(t)), float(np.percentile(t, 10))
        over = f"{100 * (med / ref_med - 1):+.0f} %, {100 * (p10 / ref_p10 - 1):+.0f} %"
        print(f"| {name} | {med:.3f} | {p10:.3f} | {over} |")

    if args.vectors:
        rows = vector_report(_DUMP, n)
        print("\nThe shipped DE loop's XLA fusions over the population (optimised LLVM IR):")
        print("| fusion | output | vector instructions |")
        print("|---|---|---|")
        for name, shape, vectors in rows:
            print(f"| {name} | {shape} | {vectors} |")
        print(f"\n{sum(v == 0 for *_, v in rows)} of these {len(rows)} fusions are scalar code")


if __name__ == "__main__":
    main()
