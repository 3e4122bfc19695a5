"""DE throughput on the paper's stage-1 objective: ours against scipy's and evosax's DE.

    python benchmarks/de_throughput.py            # N = 10,000, D = 12, the full comparison
    python benchmarks/de_throughput.py --quick    # tiny sizes, for the test suite

All three minimise the same F1st (data/paper2023.toml, HTM model, float64), evaluated by the
same jitted, vmapped JAX objective, with the same N and D, in one run:

* ours: ``handeye_jax.optim.DifferentialEvolution`` (DE/rand/1/bin, CR 0.9, F 0.5);
* scipy: ``differential_evolution(strategy="rand1bin", mutation=0.5, recombination=0.9,
  updating="deferred", vectorized=True, tol=0, polish=False)`` with an N-member initial
  population; its objective is the jitted JAX one, called on the (D, N) array scipy passes;
* evosax: ``DifferentialEvolution`` with elitism off and F = 0.5 (min = max, no dither).

All objectives are compiled with the XLA options our DE uses (``handeye_jax._jax._xla``), so
every DE gets the same fast objective; the objective with JAX's default options is reported too.

Times are medians per generation after compilation. The slow ones run only a few generations
(``--slow-generations``), as the output says. "Objective alone" evaluates the same population
in the same kind of jitted ``lax.scan`` as our DE, so the DE's own cost is the difference;
the two are timed alternately, chunk by chunk, so the ratio is not skewed by the machine
getting faster or slower between them. It is timed three ways (:data:`LAYOUTS`): mapped over
the population's rows; over the columns of its transpose, as the DE maps its trials; and over
the columns of a transposed copy, a layout the DE's population never has, which XLA reads
fastest.
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from handeye_jax import HTMModel, Stage1Objective, load_dataset
from handeye_jax._jax import loop_compiler_options
from handeye_jax.optim import Box, DifferentialEvolution, minimise
from handeye_jax.optim import _de as de

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import PAPER, de_start, interleaved_ms  # noqa: E402

#: How "objective alone" lays out and maps the population: over the rows of the (N, D) array;
#: over the columns of its transpose, a view of the same array, as the DE maps its trials; and
#: over the columns of a (D, N) copy, a layout the DE's population never has.
LAYOUTS = ("rows", "columns", "transposed copy")


def _objective_scan(objective, pop, steps: int, layout: str = "rows"):
    """``steps`` evaluations of the population's objective in a ``lax.scan``, laid out and
    mapped as ``layout`` says (one of :data:`LAYOUTS`)."""
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS} (got {layout!r})")
    copy = layout == "transposed copy"

    def step(p, _):
        x = p.T if layout == "columns" else p
        f = jax.vmap(objective, in_axes=0 if layout == "rows" else 1)(x)
        # A data dependence between steps, so XLA cannot hoist the evaluation out of the loop.
        return p + jnp.where(jnp.sum(f) > jnp.inf, 1.0, 0.0), f[0]

    return jax.lax.scan(step, pop.T if copy else pop, None, length=steps)


def ours(objective, n: int, reps: int) -> tuple[float, dict[str, float], float]:
    """ms per DE generation; ms per objective evaluation of the same population with the DE's
    XLA options, for each of :data:`LAYOUTS`; and ms per evaluation over rows with JAX's
    default options. All five are timed in turn, round after round, so that the ratios hold
    while the machine's speed drifts."""
    state, lower, upper, settings = de_start(objective, n)
    k = de.CHUNK_GENERATIONS
    fns = {"de": lambda: de._chunk(objective, state, *settings)}
    scans = {
        options_name: eqx.filter_jit(_objective_scan, compiler_options=options)
        for options_name, options in (("ours", loop_compiler_options()), ("default", None))
    }
    for layout in LAYOUTS:
        fns[layout] = lambda s=scans["ours"], lay=layout: s(objective, state.population, k, lay)
    fns["default"] = lambda: scans["default"](objective, state.population, k, "rows")
    ms = {name: float(np.median(t)) / k for name, t in interleaved_ms(fns, reps).items()}
    return ms["de"], {layout: ms[layout] for layout in LAYOUTS}, ms["default"]


def scipy_de(objective, lower, upper, n: int, generations: int) -> float:
    from scipy.optimize import differential_evolution as scipy_differential_evolution

    batched = jax.jit(jax.vmap(objective), compiler_options=loop_compiler_options())

    def f(x):  # scipy passes (D, S)
        return np.asarray(batched(jnp.asarray(x.T)))

    init = np.asarray(de.latin_hypercube(jax.random.PRNGKey(1), n, lower, upper))
    f(init.T)  # compile once, outside the timing
    stamps = []
    scipy_differential_evolution(
        f, list(zip(lower, upper, strict=True)), strategy="rand1bin", mutation=0.5,
        recombination=0.9, updating="deferred", vectorized=True, tol=0, polish=False,
        maxiter=generations, init=init, seed=1,
        callback=lambda *a, **k: stamps.append(time.perf_counter()),
    )  # fmt: skip
    return float(np.median(np.diff(stamps))) * 1e3


def evosax_de(objective, lower, upper, n: int, generations: int) -> float:
    from evosax.algorithms import DifferentialEvolution

    d = len(lower)
    es = DifferentialEvolution(population_size=n, solution=jnp.zeros(d))
    params = es.default_params.replace(
        elitism=False, crossover_rate=0.9, differential_weight=0.5,
        differential_weight_min=0.5, differential_weight_max=0.5,
    )  # fmt: skip
    pop = de.latin_hypercube(jax.random.PRNGKey(2), n, jnp.asarray(lower), jnp.asarray(upper))
    batched = jax.vmap(objective)
    state = es.init(jax.random.PRNGKey(3), pop, batched(pop), params)

    @functools.partial(jax.jit, compiler_options=loop_compiler_options())
    def step(key, state):
        x, state = es.ask(key, state, params)
        state, _ = es.tell(key, x, batched(x), state, params)
        return state

    key = jax.random.PRNGKey(4)
    for _ in range(3):  # the first calls compile more than once while the state types settle
        state = jax.block_until_ready(step(key, state))
    times = []
    for g in range(generations):
        t0 = time.perf_counter()
        state = jax.block_until_ready(step(jax.random.fold_in(key, g), state))
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) * 1e3


def full_budget(objective, lower, upper, n: int, generations: int) -> float:
    """Seconds for a complete DE run with early stop off, after compilation."""
    box = Box(lower, upper)
    de = DifferentialEvolution(population=n, generations=1, early_stop=False)
    minimise(objective, de, box, key=jax.random.PRNGKey(5))
    t0 = time.perf_counter()
    de = DifferentialEvolution(population=n, generations=generations, early_stop=False)
    minimise(objective, de, box, key=jax.random.PRNGKey(6))
    return time.perf_counter() - t0


MEMORY_PROBE = textwrap.dedent(
    """
    import sys, jax
    from handeye_jax import HTMModel, load_dataset
    from handeye_jax import Stage1Objective
    from handeye_jax.optim import Box, DifferentialEvolution, minimise
    with jax.enable_x64(True):
        obj = Stage1Objective(HTMModel, load_dataset(sys.argv[1]).observations())
        de = DifferentialEvolution(population=int(sys.argv[2]), generations=int(sys.argv[3]),
                                   early_stop=False)
        minimise(obj, de, Box(*HTMModel.search_bounds()), key=jax.random.PRNGKey(0))
    # VmHWM belongs to this process's own address space; ru_maxrss would carry the parent's
    # high-water mark across fork and exec.
    status = open("/proc/self/status").read().split("VmHWM:")[1]
    print(int(status.split()[0]))
    """
)


def peak_memory_mib(n: int, generations: int) -> float:
    """Peak resident memory of a fresh process that runs DE at population n, MiB."""
    p = subprocess.run(
        [sys.executable, "-c", MEMORY_PROBE, str(PAPER), str(n), str(generations)],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    return int(p.stdout.strip().splitlines()[-1]) / 1024  # VmHWM is in KiB


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--population", type=int, default=10_000)
    ap.add_argument("--reps", type=int, default=15,
                    help="timed rounds of 64 generations of each")  # fmt: skip
    ap.add_argument("--slow-generations", type=int, default=3,
                    help="generations timed for scipy and evosax")  # fmt: skip
    ap.add_argument("--budget-generations", type=int, default=10_000,
                    help="generations of the full-budget run (paper: 10,000)")  # fmt: skip
    ap.add_argument("--memory-population", type=int, default=100_000)
    ap.add_argument("--quick", action="store_true", help="tiny sizes, for the tests")
    args = ap.parse_args(argv)
    if args.quick:
        args.population, args.reps, args.slow_generations = 64, 2, 5
        args.budget_generations, args.memory_population = 70, 1_000

    with jax.enable_x64(True):
        objective = Stage1Objective(HTMModel, load_dataset(PAPER).observations())
        lower, upper = HTMModel.search_bounds()
        n, d = args.population, len(lower)
        print(f"# DE throughput, {time.strftime('%Y-%m-%d')}")
        print(f"command: python benchmarks/{Path(__file__).name} {' '.join(sys.argv[1:])}")
        print(f"machine: {platform.machine()} {platform.processor() or ''}, "
              f"{os.cpu_count()} cores, jax {jax.__version__}; float64")  # fmt: skip
        print(f"problem: paper stage 1 (HTM), N = {n:,}, D = {d}\n")

        gen_ms, alone_ms, obj_default_ms = ours(objective, n, args.reps)
        scipy_ms = scipy_de(objective, lower, upper, n, args.slow_generations)
        evosax_ms = evosax_de(objective, lower, upper, n, args.slow_generations)
        print("| DE | ms per generation | × ours | generations timed |")
        print("|---|---|---|---|")
        print(f"| handeye-jax | {gen_ms:.3f} | 1 | {args.reps} × {de.CHUNK_GENERATIONS} |")
        print(f"| scipy (rand1bin, deferred, vectorized) | {scipy_ms:.1f} | "
              f"{scipy_ms / gen_ms:.0f} | {args.slow_generations} |")  # fmt: skip
        print(f"| evosax DifferentialEvolution | {evosax_ms:.1f} | {evosax_ms / gen_ms:.0f} | "
              f"{args.slow_generations} |")  # fmt: skip
        print("\n| objective alone (same population, same scan harness, same XLA options) "
              "| ms | DE's own work adds |")  # fmt: skip
        print("|---|---|---|")
        for layout, ms in alone_ms.items():
            print(f"| {layout} | {ms:.3f} | {100 * (gen_ms - ms) / ms:.0f} % |")
        print(f"objective alone with JAX's default XLA options: {obj_default_ms:.3f} ms "
              f"(options: {loop_compiler_options() or 'none'})")  # fmt: skip

        seconds = full_budget(objective, lower, upper, n, args.budget_generations)
        evals = n * (args.budget_generations + 1)
        print(
            f"full budget: N = {n:,}, G = {args.budget_generations:,} ({evals:.3g} "
            f"evaluations), early stop off: {seconds:.1f} s after compilation"
        )
    mib = peak_memory_mib(args.memory_population, 2 * de.CHUNK_GENERATIONS)
    print(f"peak memory at N = {args.memory_population:,} (whole process, {2 * 64} generations): "
          f"{mib:.0f} MiB")  # fmt: skip


if __name__ == "__main__":
    main()
