"""Differential evolution, DE/rand/1/bin, as a jitted ``lax.scan`` over a vmapped population.

It minimises any function ``fn: Float[Array, "d"] -> Float[Array, ""]`` inside a box; it knows
nothing about what ``fn`` computes. Choices, each documented where a user could doubt it:

* **Index draws in O(1) per member.** r1, r2, r3 are drawn from ``N − 1``, ``N − 2`` and
  ``N − 3`` values and shifted past the indices already taken (in ascending order), which gives
  three indices distinct from each other and from the target without an O(N) choice.
* **Random numbers.** Each generation needs ``N·(D + 4)`` uniforms (crossover, j_rand and the
  three indices). They come from a counter-based SplitMix64 stream (:mod:`._rng`) seeded from
  the caller's JAX key, because JAX's generators cost more than the objective at this size.
* **Bounds.** A trial component outside ``[lower, upper]`` is replaced by the midpoint between
  the base vector's component (``x_r1``, always inside) and the bound it crossed. This keeps
  the search direction, needs no extra random numbers, and never leaves the box.
* **Initial population.** Latin hypercube sampling of the box, as scipy does by default. Its
  fitness is computed in the loop's first pass (the objective then appears in one compiled
  program, not two): that pass evaluates the members themselves, keeps them, and counts as
  no generation, so the first chunk runs ``CHUNK_GENERATIONS − 1`` generations.
* **Determinism.** Generation ``g`` draws from stream ``g`` of the seed, so a key gives the same
  result bit for bit however the run is split into chunks.
* **History.** The best fitness is recorded every generation; the population's median is
  taken on the host after every chunk of ``CHUNK_GENERATIONS`` (a sort inside the loop would
  cost as much as the DE step itself).
* **No branch per generation.** Every step of the scan computes a generation and keeps it only
  while the run is active; a ``lax.cond`` instead costs more per generation at N = 10,000
  than the objective's evaluation saved (benchmarks/RESULTS.md, "Figures the code's comments
  point to"). After an early stop or at the generation limit, at most
  ``CHUNK_GENERATIONS − 1`` discarded generations are computed; they are not counted.
* **Early stop.** A generation whose fitness spread satisfies
  ``std(f) <= atol + tol·|mean(f)|`` (scipy's rule) ends the run; ``early_stop=False`` runs
  all generations.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray, UInt

from .._core import progress_bar
from .._jax import fast_compile, hot_loop, in_float64
from . import _rng
from ._solvers import AbstractSolver, DESolution

#: Generations run per jitted call; the progress bar advances once per chunk.
CHUNK_GENERATIONS = 64


class DEState(eqx.Module):
    seed: UInt[Array, ""]
    population: Float[Array, "n d"]
    fitness: Float[Array, " n"]
    generation: Int[Array, ""]
    converged: Bool[Array, ""]


def _safe(f: Float[Array, "*n"]) -> Float[Array, "*n"]:
    return jnp.where(jnp.isnan(f), jnp.inf, f)


def latin_hypercube(
    key: PRNGKeyArray, n: int, lower: Float[Array, " d"], upper: Float[Array, " d"]
) -> Float[Array, "n d"]:
    """``n`` points in the box, one per stratum in every dimension.

    Each dimension's strata are shuffled by sorting uniform draws (ties, at 32 random bits,
    are rare and harmless: a sort still gives a permutation). The draws come from the DE's own
    counter-based stream: ``jax.random.permutation`` does the same but takes about 1 s longer
    to compile, which the first calibration on a machine would pay in every stage.
    """
    d = lower.shape[0]
    u = _rng.uniforms(_rng.seed_from_key(key), 0, (n, 2 * d)).astype(lower.dtype)
    strata = jnp.argsort(u[:, :d], axis=0)
    return lower + (strata + u[:, d:]) / n * (upper - lower)


def distinct_indices(u: Float[Array, "3 n"]) -> Int[Array, "3 n"]:
    """For each member i, three indices distinct from each other and from i, in O(1) each.

    Args:
        u: three uniforms in [0, 1) per member.
    """
    n = u.shape[1]
    # int32 throughout (a population never nears 2^31): cheaper than int64 here.
    i = jnp.arange(n, dtype=jnp.int32)

    def below(v, m):  # floor(v·m) < m for every float64 v < 1 (round to nearest)
        return jnp.floor(v * m).astype(i.dtype)

    r1 = below(u[0], n - 1)
    r1 = r1 + (r1 >= i)
    lo, hi = jnp.minimum(i, r1), jnp.maximum(i, r1)
    r2 = below(u[1], n - 2)
    r2 = r2 + (r2 >= lo)
    r2 = r2 + (r2 >= hi)
    first = jnp.minimum(lo, r2)
    last = jnp.maximum(hi, r2)
    middle = i + r1 + r2 - first - last
    r3 = below(u[2], n - 3)
    for s in (first, middle, last):
        r3 = r3 + (r3 >= s)
    return jnp.stack([r1, r2, r3])


class _Step(eqx.Module):
    """What one generation needs besides the population: the box and DE's two rates."""

    lower: Float[Array, " d"]
    upper: Float[Array, " d"]
    crossover: Float[Array, ""]
    mutation: Float[Array, ""]


class _Stop(eqx.Module):
    """When a run stops: after ``generations``, or once the fitnesses' spread is at most
    ``atol + tol·|mean|`` if ``early``."""

    generations: Int[Array, ""]
    tol: Float[Array, ""]
    atol: Float[Array, ""]
    early: Bool[Array, ""]


def _trial(
    pop: Float[Array, "n d"],
    donors: Float[Array, "3 n d"],
    u: Float[Array, "n d+4"],
    step: _Step,
) -> Float[Array, "n d"]:
    """Mutation ``base + F·(b − c)``, binomial crossover and the bounds rule.

    Args:
        pop: the current members (targets).
        donors: each member's donors ``x_r1`` (the base), ``x_r2``, ``x_r3``.
        u: each member's uniforms; column 3 picks ``j_rand``, columns 4… the crossover tests.
    """
    base, b, c = donors
    d = pop.shape[1]
    mutant = base + step.mutation * (b - c)
    j_rand = jnp.floor(u[:, 3] * d).astype(jnp.int32)
    cross = (u[:, 4:] < step.crossover) | (jnp.arange(d)[None, :] == j_rand[:, None])
    trial = jnp.where(cross, mutant, pop)
    trial = jnp.where(trial < step.lower, 0.5 * (base + step.lower), trial)
    return jnp.where(trial > step.upper, 0.5 * (base + step.upper), trial)


def _select(
    fn: Callable, state: DEState, trial: Float[Array, "n d"], fresh: Bool[Array, ""]
) -> DEState:
    """Evaluate the trials and keep each one that is no worse than its target (``fresh``:
    the trials are the members themselves, not yet evaluated; all are kept, and no
    generation is counted)."""
    # The objective is mapped over the trials as columns of a (d, n) array: the same numbers
    # (populations bit-identical), but XLA then runs the objective's first loops, which pick
    # parameters out of every trial, on both cores (benchmarks/RESULTS.md, "DE throughput").
    f_trial = _safe(jax.vmap(fn, in_axes=1)(trial.T))
    better = fresh | (f_trial <= state.fitness)
    return DEState(
        seed=state.seed,
        population=jnp.where(better[:, None], trial, state.population),
        fitness=jnp.where(better, f_trial, state.fitness),
        generation=state.generation + jnp.where(fresh, 0, 1).astype(state.generation.dtype),
        converged=state.converged,
    )


def _generation(fn: Callable, state: DEState, step: _Step, fresh: Bool[Array, ""]) -> DEState:
    pop = state.population
    n, d = pop.shape
    u = _rng.uniforms(state.seed, state.generation, (n, d + 4))
    r1, r2, r3 = distinct_indices(u[:, :3].T)
    # One gather for all three donors. The indices are in [0, N) by construction (a property
    # test checks it), so the gather needs no bounds handling: about 5 % faster a generation
    # than "fill" mode at N = 10,000 (interleaved A/B, benchmarks/de_throughput.py's harness).
    donors = pop.at[jnp.concatenate([r1, r2, r3])].get(mode="promise_in_bounds")
    trial = _trial(pop, donors.reshape(3, n, d), u, step)
    return _select(fn, state, jnp.where(fresh, pop, trial), fresh)


def _spread_converged(f: Float[Array, " n"], tol: float, atol: float) -> Bool[Array, ""]:
    return jnp.std(f) <= atol + tol * jnp.abs(jnp.mean(f))


@fast_compile
def _init(key, lower, upper, n):
    """The Latin hypercube, not yet evaluated (fitness NaN: the loop's first pass does it)."""
    k_pop, k_seed = jax.random.split(key)
    pop = latin_hypercube(k_pop, n, lower, upper)
    return DEState(
        seed=_rng.seed_from_key(k_seed),
        population=pop,
        fitness=jnp.full(n, jnp.nan, pop.dtype),
        # Not weakly typed: the loop's carry makes it strong, so the chunks after the first
        # would otherwise compile the chunk program again.
        generation=jnp.asarray(0, dtype=int),
        converged=jnp.asarray(False),
    )


def _chunk_scan(fn: Callable, state: DEState, step: _Step, stop: _Stop):
    def one(state, _):
        fresh = jnp.isnan(state.fitness[0])  # evaluated fitness is never NaN (_safe)
        active = (~state.converged) & (state.generation < stop.generations) & ~fresh
        new = _generation(fn, state, step, fresh)
        state = jax.tree.map(lambda a, b: jnp.where(active | fresh, a, b), new, state)
        spread = _spread_converged(state.fitness, stop.tol, stop.atol)
        converged = state.converged | (stop.early & active & spread)
        state = eqx.tree_at(lambda s: s.converged, state, converged)
        return state, (jnp.min(state.fitness), active)

    return jax.lax.scan(one, state, None, length=CHUNK_GENERATIONS)


#: ``CHUNK_GENERATIONS`` generations in one compiled ``lax.scan``.
_chunk = hot_loop(_chunk_scan)


class DifferentialEvolution(AbstractSolver[DESolution]):
    """DE/rand/1/bin (see the module docstring) as a solver object: the one way to run it,
    ``minimise(fn, DifferentialEvolution(...), box, key=key)``.

    Attributes:
        population: N, the number of members (≥ 4).
        generations: G, the most generations to run.
        crossover: CR, the binomial crossover probability.
        mutation: F, the differential weight.
        tol, atol: the early-stop spread criterion ``std(f) <= atol + tol·|mean(f)|``.
        early_stop: stop when the spread criterion holds; False runs all G generations.
    """

    population: int = 500
    generations: int = 3000
    crossover: float = 0.9
    mutation: float = 0.5
    tol: float = 1e-3
    atol: float = 0.0
    early_stop: bool = True

    def __check_init__(self):
        if self.population < 4:
            raise ValueError(f"population must be at least 4 for DE/rand/1 (got {self.population})")

    @in_float64
    def run(self, fn, box, *, x0, key, progress) -> DESolution:
        """Minimise ``fn`` (a JAX-traceable function of one parameter vector; pass an equinox
        Module so repeated calls reuse the compiled code) over ``box``, from a Latin hypercube
        (``x0`` is not used). The same ``key`` gives the same run bit for bit; float64."""
        del x0
        if key is None:
            raise ValueError("differential evolution needs a PRNG key")
        lower = jnp.asarray(box.lower, dtype=float)
        upper = jnp.asarray(box.upper, dtype=float)
        state = _init(key, lower, upper, self.population)
        # Arrays, not Python numbers, so that new settings reuse the compiled program (NumPy's:
        # jnp.asarray would compile a small program for each).
        step = _Step(lower, upper, np.asarray(self.crossover), np.asarray(self.mutation))
        stop = _Stop(np.asarray(self.generations), np.asarray(self.tol), np.asarray(self.atol),
                     np.asarray(self.early_stop))  # fmt: skip
        state, best, median = _generations(fn, state, step, stop, (self.generations, progress))
        return _solution(state, best, median, self.population)


def bar_label(progress: bool | str) -> str:
    """A DE progress bar's label: ``progress`` when it is one, else ``"DE"``."""
    return progress if isinstance(progress, str) and progress else "DE"


def _generations(fn, state: DEState, step: _Step, stop: _Stop, bar: tuple):
    """Chunks of generations until the run converges or reaches its limit; the best value of
    every generation and the median after every chunk. ``bar``: (total, shown or its label)."""
    total, shown = bar
    best, median = [], []
    with progress_bar(total=total, desc=bar_label(shown), enabled=bool(shown),
                      unit="gen") as bar:  # fmt: skip
        while True:
            state, (b, active) = _chunk(fn, state, step, stop)
            active = np.asarray(active)
            best.append(np.asarray(b)[active])
            median.append((int(state.generation), float(np.median(np.asarray(state.fitness)))))
            bar.update(int(active.sum()))
            if bool(state.converged) or int(state.generation) >= total:
                return state, best, median


def _solution(state: DEState, best: list, median: list, population: int) -> DESolution:
    fitness = np.asarray(state.fitness)
    final = np.asarray(state.population)
    i_best = int(np.argmin(fitness))
    n_gen = int(state.generation)
    return DESolution(
        x=final[i_best],
        value=float(fitness[i_best]),
        population=final,
        fitness=fitness,
        steps=n_gen,
        evaluations=population * (n_gen + 1),
        converged=bool(state.converged),
        best_history=np.concatenate(best),
        median_history=np.array([m for _, m in median]),
        median_generations=np.array([g for g, _ in median]),
    )
