"""Many problems at once: :func:`minimise_many` runs a solver on a batch of problems in one
compiled program per step, each problem with its own box, start or key, and its own stopping
rule, and returns the solver's :class:`Solution` with a leading axis of problems.

Each problem's numbers are those of its own :func:`~handeye_jax.optim.minimise` run, bit for
bit, however the batch is made up or split:

* **DE** runs vmapped over the problems: a member's arithmetic is the same alone or among
  others (the population's axis stays the one XLA vectorises). Every problem stops on its own
  rule; the batch's chunks go on until the last has stopped, and a stopped problem's state
  is kept as it was.
* **Levenberg–Marquardt** (the polish and the multi-start search) runs problem after problem
  inside one program (``lax.map``): the same program as a single run's, without a trip to
  the host between problems. Vmapped, XLA contracts multiplies and adds into FMAs in other
  places, and LM's path from a start amplifies such last-bit differences. A problem not to
  be run costs nothing (``lax.cond``).

The batch is sharded over the devices of a mesh (:func:`handeye_jax._jax.problem_mesh`): each
device runs the same program on its block of problems, all at once. The solvers still know
nothing of what the problems compute.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh
from jaxtyping import ArrayLike, Bool, Float, PRNGKeyArray

from .._core import progress_bar
from .._jax import Blocks, fast_compile, hot_loop, in_float64, per_device, problem_mesh
from . import _de, _lm, _multistart
from ._box import Box
from ._de import DifferentialEvolution
from ._lm import LevenbergMarquardt
from ._solvers import AbstractSolver, BatchSolution, DESolution, LMSolution, Problem, Solution


def take(solution: Solution, i: int) -> Solution:
    """Problem ``i``'s :class:`Solution` out of a batch's (:func:`minimise_many`)."""
    out = {}
    for f in dataclasses.fields(solution):
        v = getattr(solution, f.name)
        if isinstance(v, np.ndarray) and v.ndim >= 1 or isinstance(v, tuple):
            v = v[i]
        if isinstance(v, np.generic):
            v = v.item()
        out[f.name] = v
    return type(solution)(**out)


# -- DE ----------------------------------------------------------------------------------


# The single run's programs, vmapped over a block of problems, with their own XLA options.
@fast_compile
def _de_init(block, n):
    keys, lower, upper = block
    init = _de._init.__wrapped__
    return jax.vmap(lambda k, lo, hi: init(k, lo, hi, n))(keys, lower, upper)


@hot_loop
def _de_chunk(block, stop):
    fns, state, step = block
    return jax.vmap(_de._chunk_scan, in_axes=(0, 0, 0, None))(fns, state, step, stop)


def _de_many(fns, de: DifferentialEvolution, box: Box, keys, *, mesh, progress: bool | str):
    lower, upper = _bounds(box)
    b = lower.shape[0]
    init = per_device(_de_init, Blocks.of((keys, lower, upper), mesh), de.population)
    step = _de._Step(lower, upper, np.full(b, de.crossover), np.full(b, de.mutation))
    problems = Blocks.of((fns, step), mesh)
    stop = _de._Stop(np.asarray(de.generations), np.asarray(de.tol), np.asarray(de.atol),
                     np.asarray(de.early_stop))  # fmt: skip
    states = init
    best: list[list[np.ndarray]] = [[] for _ in range(b)]
    median: list[list[tuple[int, float]]] = [[] for _ in range(b)]
    going = np.ones(b, bool)
    with progress_bar(total=de.generations, desc=_de.bar_label(progress), enabled=bool(progress),
                      unit="gen") as bar:  # fmt: skip
        while going.any():
            joined = Blocks(mesh, [(p[0], s, p[1]) for p, s in
                                   zip(problems.blocks, states.blocks, strict=True)])
            out = per_device(_de_chunk, joined, stop)
            states = Blocks(mesh, [o[0] for o in out.blocks])
            state, (chunk_best, active) = out.gather()
            generation = np.asarray(state.generation)
            medians = np.median(state.fitness, axis=1)
            for i in np.flatnonzero(going):
                best[i].append(chunk_best[i][active[i]])
                median[i].append((int(generation[i]), float(medians[i])))
            bar.update(int(active[going].sum(axis=1).max(initial=0)))
            going &= ~(np.asarray(state.converged) | (generation >= de.generations))
    return _de_solutions(state, best, median, de.population)


def _de_solutions(state, best, median, population: int) -> DESolution:
    fitness = np.asarray(state.fitness)
    final = np.asarray(state.population)
    i_best = np.argmin(fitness, axis=1)
    rows = np.arange(len(i_best))
    steps = np.asarray(state.generation).astype(int)
    return DESolution(
        x=final[rows, i_best], value=fitness[rows, i_best], steps=steps,
        evaluations=population * (steps + 1), converged=np.asarray(state.converged),
        population=final, fitness=fitness, best_history=tuple(np.concatenate(b) for b in best),
        median_history=tuple(np.array([m for _, m in med]) for med in median),
        median_generations=tuple(np.array([g for g, _ in med]) for med in median),
    )  # fmt: skip


# -- LM ----------------------------------------------------------------------------------

#: Problems per device, at least, in a program that runs them one after another: XLA takes a
#: loop of one trip out, and its body then compiles (and rounds) as another program would.
LOOPED = 2


def _padded_run(run: np.ndarray, mesh: Mesh) -> np.ndarray:
    """``run`` with False for the copies :meth:`Blocks.of` fills a batch with."""
    devices = mesh.devices.size
    size = max(-(-len(run) // devices), LOOPED) * devices
    return np.concatenate([np.asarray(run, bool), np.zeros(size - len(run), bool)])


@fast_compile
def _values(block):
    return jax.lax.map(lambda a: a[0](a[1]), block)


def values_many(fns: Problem, x: Float[ArrayLike, "b *s d"], mesh: Mesh | None = None):
    """Each problem's value at its points: ``fns[i](x[i])`` (``x`` ``(b, d)``) or at each of
    its points (``(b, s, d)``), as :func:`~handeye_jax.optim.minimise` evaluates it."""
    mesh = problem_mesh() if mesh is None else mesh
    x = np.asarray(x, float)
    problems = Blocks.of(fns, mesh, LOOPED)  # placed once for all the points
    if x.ndim == 3:  # the points of a problem one after another, as the single run does
        return np.stack([_values_at(problems, x[:, j]) for j in range(x.shape[1])], axis=1)
    return _values_at(problems, x)


def _values_at(problems: Blocks, x: np.ndarray) -> np.ndarray:
    points = Blocks.of(x, problems.mesh, LOOPED)
    blocks = [(f, p) for f, p in zip(problems.blocks, points.blocks, strict=True)]
    return per_device(_values, Blocks(problems.mesh, blocks, points.n)).gather()


@fast_compile
def _polish(block, lm):

    def one(args):
        fn, x, lo, hi, go = args

        def polish():
            return _lm._lm(fn, x, Box(lo, hi), lm)

        # optimistix counts steps in JAX's default integer (its ``jnp.array(0)``); a mismatch
        # fails loudly in lax.cond. Shapes by jax.eval_shape would trace the LM twice.
        skip = (x, jnp.zeros((), jnp.asarray(0).dtype), jnp.zeros((), bool))
        return jax.lax.cond(go, polish, lambda: skip)

    return jax.lax.map(one, block)


def _lm_many(fns, lm: LevenbergMarquardt, box: Box, x0, *, run, mesh) -> LMSolution:
    lower, upper = _bounds(box)
    x0 = np.clip(np.asarray(x0, float), lower, upper)
    block = Blocks.of((fns, x0, lower, upper, _padded_run(run, mesh)), mesh, LOOPED)
    x, steps, ok = per_device(_polish, block, lm).gather()
    steps = steps.astype(int)
    return LMSolution(
        x=x, value=values_many(fns, x, mesh), steps=steps, evaluations=steps + 1,
        converged=np.asarray(ok), start_value=values_many(fns, x0, mesh),
    )  # fmt: skip


@fast_compile(llvm_opt_level=1)
def _starts(block, lm):
    return jax.lax.map(lambda a: _multistart._starts_loop(*a[:4], lm, a[4]), block)


@in_float64
def minimise_starts_many(
    fns: Problem,
    solver: LevenbergMarquardt,
    box: Box,
    starts: Float[ArrayLike, "b s d"],
    *,
    run: Bool[ArrayLike, " b"] | None = None,
    mesh: Mesh | None = None,
) -> BatchSolution:
    """:func:`~handeye_jax.optim.minimise_starts` of ``b`` problems in one program, each with
    its own starts, box and stopping rule; each problem's numbers are its own run's.

    Args:
        fns: the problems stacked: one pytree whose array leaves have a leading axis ``b``.
        solver: the tolerances and the most iterations (shared).
        box: each problem's box, a batch of them (bounds ``(b, d)``).
        starts: each problem's starts ``(b, s, d)``.
        run: which problems to run (default: all); the others return their starts.
        mesh: the devices the problems are split over (default: this process's).

    Returns:
        ``x`` ``(b, s, d)``, ``value`` ``(b, s)``, ``steps`` ``(b,)``, ``evaluations``
        ``(b,)`` and ``converged`` ``(b,)``.
    """
    mesh = problem_mesh() if mesh is None else mesh
    x0 = np.asarray(starts, float)
    run = np.ones(x0.shape[0], bool) if run is None else np.asarray(run, bool)
    lower, upper = _bounds(box)
    block = Blocks.of((fns, x0, lower, upper, _padded_run(run, mesh)), mesh, LOOPED)
    x, cost, steps, ok = per_device(_starts, block, _multistart._config(solver)).gather()
    steps = steps.astype(int)
    return BatchSolution(x=x, value=cost, steps=steps, evaluations=steps + 1, converged=ok)


# -- the entry point -------------------------------------------------------------------------


def _bounds(box: Box) -> tuple[np.ndarray, np.ndarray]:
    """A batch of boxes' bounds, ``(b, d)`` each."""
    if np.ndim(box.lower) != 2:
        raise ValueError("a batch of problems needs a batch of boxes: bounds of shape (b, d)")
    return np.asarray(box.lower, float), np.asarray(box.upper, float)


@in_float64
def minimise_many(
    fns: Problem,
    solver: AbstractSolver,
    box: Box,
    *,
    x0: Float[ArrayLike, "b d"] | None = None,
    keys: PRNGKeyArray | None = None,
    run: Bool[ArrayLike, " b"] | None = None,
    mesh: Mesh | None = None,
    progress: bool | str = False,
) -> Solution:
    """Minimise ``b`` problems with ``solver``, each inside its own box: what ``b`` calls of
    :func:`~handeye_jax.optim.minimise` return, in one :class:`Solution` whose fields have a
    leading axis of problems (DE's histories: a tuple, one array per problem). Problem
    ``i``'s own is :func:`take` ``(solution, i)``.

    Args:
        fns: the problems stacked: one pytree whose array leaves have a leading axis ``b``
            (e.g. ``jax.tree.map(lambda *a: np.stack(a), *problems)``), all of one structure.
        solver: :class:`DifferentialEvolution` or :class:`LevenbergMarquardt`.
        box: each problem's box, a batch of them (bounds ``(b, d)``).
        x0: each problem's start (Levenberg–Marquardt).
        keys: each problem's PRNG key, stacked (DE).
        run: which problems LM runs (default: all); the others keep their start.
        mesh: the devices the problems are split over (default: this process's); ``b`` must
            be a multiple of its size.
        progress: a progress bar of DE's generations on stderr (a string: with that label).
    """
    mesh = problem_mesh() if mesh is None else mesh
    b = _bounds(box)[0].shape[0]
    if isinstance(solver, DifferentialEvolution):
        if keys is None:
            raise ValueError("differential evolution needs a PRNG key per problem")
        return _de_many(fns, solver, box, keys, mesh=mesh, progress=progress)
    if isinstance(solver, LevenbergMarquardt):
        if x0 is None:
            raise ValueError("Levenberg-Marquardt needs a start point per problem")
        run = np.ones(b, bool) if run is None else np.asarray(run, bool)
        return _lm_many(fns, solver, box, x0, run=run, mesh=mesh)
    raise TypeError(f"no batched run for {type(solver).__name__}")
