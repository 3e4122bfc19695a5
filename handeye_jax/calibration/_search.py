"""One stage's search, for one problem (:func:`fit_stage`) or a batch (:func:`fit_stages`):
DE over the searched parameters, then LM over every free parameter from DE's best member,
from restarts (the final population's other optima, then Latin-hypercube points) and, in
stage 1, from the multi-start refits; the lowest value any of them reaches is the stage's
optimum.

Each step is one compiled program for the whole batch (:func:`~handeye_jax.optim.minimise_many`)
and every decision is taken for each problem on its own numbers, so a problem's
:class:`StageFit` is the same bit for bit alone or in any batch: :func:`fit_stage` is a batch
of one.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import jax
import numpy as np
from jax.sharding import Mesh

from .._jax import single_device_mesh
from ..optim import (
    MAX_MODES,
    Box,
    LevenbergMarquardt,
    minimise_many,
    minimise_starts_many,
    mode_leaders,
    take,
    values_many,
)
from ..problem import AbstractObjective, MaskedObjective
from ._payloads import PolishSummary, RestartSummary
from ._programs import lhs_many
from ._settings import Settings
from ._stage import (
    BETTER_BY_MM,
    MODE_PARAM_FRACTION,
    POLISH,
    RESTART_STEPS,
    DESearch,
    Population,
    StageFit,
    StageTask,
    de_summary,
    with_prior,
)
from ._starts import REFIT_STARTS

#: The refits' starts per problem: the uniform ones, up to two from the closed-form estimate
#: and the fit's own (a problem with more is run as wide as it needs).
REFIT_WIDTH = REFIT_STARTS + 3


def fit_stage(
    task: StageTask, settings: Settings, keys: tuple[jax.Array, jax.Array], *,
    progress: bool = False,
) -> StageFit:  # fmt: skip
    """Fit one stage: DE over the task's search, then LM over every free parameter from DE's
    best member, from restarts and from the task's refit starts; the lowest value wins.

    Args:
        task: the stage's objective, parameters and search.
        settings: DE, LM and restart settings.
        keys: the DE's key and the restarts' key.
        progress: show DE's progress bar.
    """
    return fit_stages([task], settings, [keys], mesh=single_device_mesh(),
                      progress=progress)[0]  # fmt: skip


def stack(trees: Sequence) -> object:
    """Pytrees of one structure as one, each array leaf with a leading axis of problems."""
    structure = jax.tree.structure(trees[0])
    for t in trees[1:]:
        if jax.tree.structure(t) != structure:
            raise ValueError("the problems of a batch must have one structure")
    return jax.tree.map(lambda *a: np.stack([np.asarray(x) for x in a]), *trees)


@dataclass
class _Best:
    """Each problem's lowest point so far, its value and which search reached it."""

    x: np.ndarray
    value: np.ndarray
    found_by: list[str]


@dataclass(frozen=True)
class _Batch:
    """A stage's problems as the search sees them.

    Attributes:
        tasks: each problem's task.
        mask: each problem's row weights (``None``: one shape, nothing padded).
        objective: each problem's objective (prior included) on its free parameters, as the
            search evaluates it (padded rows weighed 0).
        mesh: the devices.
        live: which problems are real (the others fill the batch to its size: LM skips them).
    """

    tasks: list[StageTask]
    mask: np.ndarray | None
    objective: list[AbstractObjective]
    mesh: Mesh | None
    live: np.ndarray

    def searched(self, objective: AbstractObjective, i: int) -> AbstractObjective:
        """Problem ``i``'s objective as the batch evaluates it (its padding weighed 0)."""
        return objective if self.mask is None else MaskedObjective(objective, self.mask[i])


def fit_stages(
    tasks: Sequence[StageTask],
    settings: Settings,
    keys: Sequence[tuple[jax.Array, jax.Array]],
    *,
    padded: Sequence[Callable] | None = None,
    mask: np.ndarray | None = None,
    mesh: Mesh | None = None,
    live: np.ndarray | None = None,
    progress: bool = False,
) -> list[StageFit]:
    """:func:`fit_stage` of every task, in one batch: each problem's :class:`StageFit` is its
    own run's.

    Args:
        tasks: the problems' stage tasks, of one structure (model, free and searched
            parameters, prior, loss, restart landmarks).
        settings: DE, LM and restart settings (shared).
        keys: each problem's DE key and restarts' key.
        padded: each problem's ``build`` on its observations padded to the batch's rows
            (``None``: the tasks' own, all of one shape).
        mask: each problem's row weights ``(b, n)`` for ``padded``.
        mesh: the devices the batch is split over.
        live: which problems are real (default: all); LM skips the others, which fill the
            batch to a size the devices share.
        progress: show DE's progress bar.
    """
    tasks = list(tasks)
    builds = padded if padded is not None else [t.build for t in tasks]
    space0 = tasks[0].space
    search = space0.free if tasks[0].search is None else tuple(tasks[0].search)
    live = np.ones(len(tasks), bool) if live is None else np.asarray(live, bool)
    batch = _Batch(tasks, None if padded is None else np.asarray(mask), [], mesh, live)
    objective = [batch.searched(with_prior(b(t.space.template, t.space.free), t.space,
                                           t.n_landmarks), i)
                 for i, (t, b) in enumerate(zip(tasks, builds, strict=True))]  # fmt: skip
    batch = replace(batch, objective=objective)
    if space0.d == 0:
        settings = replace(settings, polish=False)
    t0 = time.perf_counter()
    found = _de_searches(batch, builds, search, settings, [k[0] for k in keys], progress)
    bases = np.array([t.space.clip(t.space.theta()) for t in tasks])
    if found is None:
        x, label = bases, "the previous result"
    else:
        x = np.array([t.space.embed(search, f.de.x, b) for t, f, b in zip(tasks, found, bases,
                                                                            strict=True)])
        label = "DE"
    # The values come from the program the LM polish compiles for its own (no other program).
    best = _Best(x, values_many(stack(objective), x, mesh), [label] * len(tasks))
    summaries = [de_summary(search, None if found is None else found[i], float(best.value[i]))
                 for i in range(len(tasks))]  # fmt: skip
    t1 = time.perf_counter()
    polish = [PolishSummary(ran=settings.polish, accepted=False, F_before_mm=float(v))
              for v in best.value]  # fmt: skip
    if settings.polish:
        best, polish = _lm_searches(batch, found, [k[1] for k in keys], settings, best)
    t2 = time.perf_counter()
    share = {"de": (t1 - t0) / len(tasks), "polish": (t2 - t1) / len(tasks)}
    out = []
    for i, t in enumerate(tasks):
        space = t.space
        population = None if found is None else Population(found[i].de.population,
                                                           found[i].de.fitness, search)
        out.append(StageFit(
            space=space, objective=with_prior(t.build(space.template, space.free), space,
                                              t.n_landmarks),
            data=t.build(space.template, space.free), x=np.asarray(best.x[i], dtype=float),
            de=summaries[i][0], polish=replace(polish[i], found_by=best.found_by[i]),
            convergence=summaries[i][1], timings=dict(share), population=population,
        ))  # fmt: skip
    return out


def _de_searches(batch: _Batch, builds, search, settings: Settings, keys,
                 progress: bool) -> list[DESearch] | None:  # fmt: skip
    """Each problem's DE search, all in one DE run: over the parameters ``search`` names (the
    rest held at the space's clipped start), with the space's prior. ``None`` when the stage
    searches nothing."""
    if not search:
        return None
    subs, objectives, bases = [], [], []
    for i, (t, build) in enumerate(zip(batch.tasks, builds, strict=True)):
        space = t.space
        base = space.clip(space.theta())
        sub = space if search == space.free else space.subspace(search, base)
        objective = with_prior(build(sub.template, sub.free), sub, t.n_landmarks)
        subs.append(sub)
        objectives.append(batch.searched(objective, i))
        bases.append(base)
    de = minimise_many(
        stack(objectives), settings.de(), _boxes(subs),
        keys=np.stack([np.asarray(k) for k in keys]), mesh=batch.mesh,
        progress=batch.tasks[0].label if progress else False,
    )  # fmt: skip
    return [DESearch(s, o, b, take(de, i)) for i, (s, o, b) in
            enumerate(zip(subs, objectives, bases, strict=True))]  # fmt: skip


def _lm_searches(batch: _Batch, found, keys, settings: Settings,
                 best: _Best) -> tuple[_Best, list[PolishSummary]]:  # fmt: skip
    """Each problem's LM search from its best point so far: the polish, then the restarts
    (from the DE population's other optima and Latin-hypercube points) and the multi-start
    refits; each replaces the best only where it is lower. Returns the new bests and what
    each problem's LM search did."""
    F_before = best.value.copy()
    lm = _polish(batch, batch.objective, best.x, batch.live)
    better = np.isfinite(lm.value) & (lm.value < best.value)
    best = _Best(np.where(better[:, None], lm.x, best.x), np.where(better, lm.value, best.value),
                 [f"{f} + LM" if b else f for f, b in zip(best.found_by, better, strict=True)])
    restarts = [None] * len(batch.tasks)
    replaced = [()] * len(batch.tasks)
    search = settings.restarts > 0 and found is not None
    refit = settings.restarts > 0 and batch.tasks[0].refit_starts is not None
    whole = search and all(f.space is t.space for f, t in zip(found, batch.tasks, strict=True))
    if refit and whole:
        best, restarts, replaced = _restarts_and_refits(batch, found, keys, settings, best)
    else:
        if search:
            best, restarts = _restarts(batch, found, keys, settings, best)
        if refit:
            best, replaced = _refits(batch, best, settings.restarts)
    out = [PolishSummary(
        ran=True, accepted=bool(best.value[i] < F_before[i]), F_before_mm=float(F_before[i]),
        steps=int(lm.steps[i]), solver_converged=bool(lm.converged[i]), restarts=restarts[i],
        F_after_mm=float(best.value[i]), replaced_F_mm=replaced[i],
    ) for i in range(len(batch.tasks))]  # fmt: skip
    return best, out


def _boxes(spaces) -> Box:
    """The spaces' boxes, one row each: a batch of boxes."""
    return Box(np.array([s.lower for s in spaces]), np.array([s.upper for s in spaces]))


def _polish(batch: _Batch, objectives, x0: np.ndarray, run: np.ndarray):
    """The polish (:data:`POLISH`) of each problem that ``run`` marks, from ``x0``."""
    return minimise_many(stack(objectives), POLISH, _boxes([t.space for t in batch.tasks]),
                         x0=x0, run=run, mesh=batch.mesh)  # fmt: skip


def _restarts(batch: _Batch, found: list[DESearch], keys, settings: Settings,
              best: _Best) -> tuple[_Best, list[RestartSummary]]:  # fmt: skip
    """Each problem's restarts: LM from ``settings.restarts`` starts in its DE search's
    space; the lowest end replaces the best where it is lower."""
    points, labels, ks = _restart_starts(batch, found, keys, settings)
    # As wide as the refits' (the last start repeated): one LM program and one program for
    # the ends' values serve both.
    ends = _multistart(batch, [f.objective for f in found], _boxes([f.space for f in found]),
                       points, max(settings.restarts, REFIT_WIDTH))  # fmt: skip
    return _restarts_adopted(batch, found, ends, labels, ks, settings, best)


def _refits(batch: _Batch, best: _Best,
            size: int) -> tuple[_Best, list[tuple[float, ...]]]:  # fmt: skip
    """Each problem's multi-start refits: LM from its own refit starts and from its fit; the
    lowest end replaces the fit where it is lower."""
    starts, labels = _refit_starts(batch.tasks, best)
    # All the padded ends, as wide as the restarts': their values are then one program.
    ends = _multistart(batch, batch.objective, _boxes([t.space for t in batch.tasks]), starts,
                       max(size, REFIT_WIDTH))  # fmt: skip
    return _refits_adopted(batch, best, ends, labels)


def _restarts_and_refits(batch: _Batch, found: list[DESearch], keys, settings: Settings,
                         best: _Best) -> tuple[_Best, list[RestartSummary], list[tuple]]:
    """:func:`_restarts`, then :func:`_refits`, with their LM runs in one program call: the
    restarts search every free parameter, so both run on the problem's own objective and
    box. The refit from the fit starts where the fit was before the restarts; a problem whose
    restarts moved its fit runs its refits again, from there, as they run apart.

    Apart, the refits' call was mostly copies of its last start, as wide as the restarts' (so
    that the two share a program); together, the program is as wide as both: stage 1's
    multi-start work falls by about a third (``benchmarks/RESULTS.md``)."""
    points, r_labels, ks = _restart_starts(batch, found, keys, settings)
    refit_starts, f_labels = _refit_starts(batch.tasks, best)
    r, width = points.shape[1], points.shape[1] + refit_starts.shape[1]
    box = _boxes([t.space for t in batch.tasks])
    ends = _multistart(batch, batch.objective, box, np.concatenate([points, refit_starts], 1),
                       width)  # fmt: skip
    size = max(settings.restarts, REFIT_WIDTH)
    before = best
    best, info = _restarts_adopted(batch, found, _widened(ends[:, :r], size), r_labels, ks,
                                   settings, best)  # fmt: skip
    refit_ends = ends[:, r:]
    moved = batch.live & np.any(best.x != before.x, axis=1)
    if moved.any():  # their refits, as apart: from the moved fit, stopping when they do
        refit_starts, f_labels = _refit_starts(batch.tasks, best)
        again = _multistart(replace(batch, live=moved), batch.objective, box, refit_starts,
                            width)  # fmt: skip
        refit_ends = np.where(moved[:, None, None], again[:, : refit_starts.shape[1]], refit_ends)
    best, replaced = _refits_adopted(batch, best, _widened(refit_ends, size), f_labels)
    return best, info, replaced


def _widened(rows: np.ndarray, size: int) -> np.ndarray:
    """``rows`` ``(b, k, d)`` (starts or ends) with the last column repeated up to ``size``."""
    return np.concatenate([rows, np.repeat(rows[:, -1:], max(size - rows.shape[1], 0), 1)], 1)


def _restart_starts(batch: _Batch, found: list[DESearch], keys,
                    settings: Settings) -> tuple[np.ndarray, list[list[str]], list[int]]:
    """The restarts' starts ``(b, restarts, d)`` in each DE search's space: the final
    population's other optima, then Latin-hypercube points; their labels; how many came from
    the population."""
    restarts = settings.restarts
    subs = [f.space for f in found]
    box = _boxes(subs)
    points = lhs_many(np.stack([np.asarray(k) for k in keys]), restarts, box.lower, box.upper,
                      batch.mesh)  # fmt: skip
    labels, ks = [], []
    for i, f in enumerate(found):
        leaders = mode_leaders(f.de.population, f.de.fitness, subs[i].lower,
                               subs[i].upper)[0][1:MAX_MODES]  # fmt: skip
        k = min(len(leaders), restarts)
        points[i, :k] = leaders[:k]
        ks.append(k)
        labels.append([f"LM from another optimum of the final DE population (restart {j + 1} "
                       f"of {restarts})" if j < k else f"LM from a Latin-hypercube start "
                       f"(restart {j + 1} of {restarts})" for j in range(restarts)])  # fmt: skip
    return points, labels, ks


def _restarts_adopted(batch: _Batch, found: list[DESearch], ends: np.ndarray,
                      labels: list[list[str]], ks: list[int], settings: Settings,
                      best: _Best) -> tuple[_Best, list[RestartSummary]]:  # fmt: skip
    """The restarts' LM ends ``ends`` (in each DE search's space, the last repeated up to the
    program's width) taken: the new bests, and what the restarts found."""
    restarts = settings.restarts
    subs = [f.space for f in found]
    landmarks = batch.tasks[0].restart_landmarks
    labels = [own + [own[-1]] * (ends.shape[1] - restarts) for own in labels]
    full = np.array([[t.space.embed(subs[i].free, e, found[i].base) for e in ends[i]]
                     for i, t in enumerate(batch.tasks)])  # fmt: skip
    narrowed = landmarks is not None or subs[0] is not batch.tasks[0].space
    out, values, best_F = _best_end(batch, full, labels, best, narrowed)
    values = values[:, :restarts]  # the repeated ends are not counted
    info = [RestartSummary(
        starts=restarts, from_population=int(ks[i]), best_F_mm=float(best_F[i]),
        reached_result=int(np.sum(values[i] <= out.value[i] + 1e-4)),
        landmarks=None if landmarks is None else len(landmarks),
    ) for i in range(len(batch.tasks))]  # fmt: skip
    return out, info


def _refit_starts(tasks: Sequence[StageTask], best: _Best) -> tuple[np.ndarray, list[list[str]]]:
    """The refits' starts ``(b, width, d)``: each problem's own (its count: the closed-form
    estimate adds one or two), then its fit; repeated to a width that does not depend on the
    batch, so that a problem's program is the same alone and in any batch (a repeated start
    ends where it did, and the lowest end's first occurrence wins). And their labels."""
    width = max(REFIT_WIDTH, *(len(t.refit_starts) + 1 for t in tasks))
    starts, labels = [], []
    for i, t in enumerate(tasks):
        k = len(t.refit_starts)
        own = list(t.refit_labels or [f"LM from a uniform start (refit {j + 1} of {k})"
                                      for j in range(k)])  # fmt: skip
        own.append(f"{best.found_by[i].split(', refined')[0]}, refined by a refit from it")
        rows = np.concatenate([t.refit_starts, best.x[i][None]])
        starts.append(np.concatenate([rows, np.repeat(rows[-1:], width - k - 1, axis=0)]))
        labels.append(own + [own[-1]] * (width - k - 1))
    return np.array(starts), labels


def _refits_adopted(batch: _Batch, best: _Best, ends: np.ndarray,
                    labels: list[list[str]]) -> tuple[_Best, list[tuple[float, ...]]]:
    """The refits' LM ends ``ends`` (the last repeated up to the program's width) taken: the
    new bests, and the value each replaced (none where the fit stood)."""
    tasks = batch.tasks
    box = _boxes([t.space for t in tasks])
    landmarks = tasks[0].restart_landmarks
    labels = [own + [own[-1]] * (ends.shape[1] - len(own)) for own in labels]
    out, _, _ = _best_end(batch, ends, labels, best, landmarks is not None)
    changed = out.value != best.value
    found_by = list(out.found_by)
    for i in np.flatnonzero(changed):
        width = box.upper[i] - box.lower[i]
        if np.all(np.abs(out.x[i] - best.x[i]) <= MODE_PARAM_FRACTION * width):
            found_by[i] = labels[i][-1]  # the fit's own optimum, further down
    replaced = [(float(best.value[i]),) if changed[i] else () for i in range(len(tasks))]
    return _Best(out.x, out.value, found_by), replaced


def _multistart(batch: _Batch, objectives, box: Box, starts: np.ndarray, size: int):
    """LM from each problem's ``k`` starts (on the restarts' landmarks, where a problem has
    them): the end points ``(b, max(k, size), d)``, the last start's end repeated up to
    ``size``."""
    landmarks = batch.tasks[0].restart_landmarks
    searched = objectives if landmarks is None else [o.on_landmarks(landmarks)
                                                     for o in objectives]  # fmt: skip
    wide = _widened(starts, size)
    lm = LevenbergMarquardt(rtol=1e-10, atol=0.0, max_steps=RESTART_STEPS)
    return minimise_starts_many(stack(searched), lm, box, wide, run=batch.live,
                                mesh=batch.mesh).x  # fmt: skip


def _best_end(batch: _Batch, ends: np.ndarray, labels: list[list[str]], best: _Best,
              narrowed: bool) -> tuple[_Best, np.ndarray, np.ndarray]:  # fmt: skip
    """Each problem's lowest end point among ``ends``, polished when it may beat the best
    (or, after a search narrowed to fewer landmarks or parameters, may match it), and taken
    where it is lower by :data:`BETTER_BY_MM`. Returns the new bests, every end point's value
    and the lowest one's value after its polish."""
    values = values_many(stack(batch.objective), ends, batch.mesh)
    values = np.where(np.isfinite(values), values, np.inf)
    i = np.argmin(values, axis=1)
    rows = np.arange(len(i))
    x_i, f_i = ends[rows, i], values[rows, i]
    run = batch.live & ((narrowed & (f_i < best.value + 1e-4)) | (f_i < best.value - BETTER_BY_MM))
    if run.any():
        lm = _polish(batch, batch.objective, x_i, run)
        take_lm = run & np.isfinite(lm.value) & (lm.value < f_i)
        x_i = np.where(take_lm[:, None], lm.x, x_i)
        f_i = np.where(take_lm, lm.value, f_i)
    lower = f_i < best.value - BETTER_BY_MM
    out = _Best(np.where(lower[:, None], x_i, best.x), np.where(lower, f_i, best.value),
                [labels[r][i[r]] if lower[r] else best.found_by[r] for r in rows])
    return out, values, f_i
