"""Many calibrations at once: :func:`calibrate_batch` fits B datasets in one batch, each step
of both stages one compiled program for all of them, sharded over the devices, and under
``jax.distributed`` split over the processes. Each result is the one :func:`calibrate` gives
for its dataset alone, bit for bit, however the batch is made up or split: :func:`fit` is a
batch of one.

The batch runs in waves of at most ``wave`` problems per device (so memory stays bounded and
the progress bar moves). Problems of one structure (model, free and searched parameters,
prior, loss, captures, hand heights, centre landmark) and one padded size share a wave: a
problem's rows are padded with rows of weight 0 to a size that depends on it alone
(:func:`~._tasks.padded_rows`: its own up to 16 rows, then the next multiple of 8), alone as
in a batch. A wave is filled up to a size the devices share, with copies of its first problem
that LM skips.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import replace
from typing import Literal

import jax
import numpy as np
from jax.sharding import Mesh

from .._core import BATCH_WAVE, InputError, Stages, progress_bar
from .._jax import in_float64, padded_size, problem_mesh
from ..data import Dataset
from ..models import get_model
from ._plans import Plan, full_plan
from ._programs import rotation_centres, stage_keys
from ._result import CalibrationResult
from ._result_io import result_from_json, result_to_json
from ._search import fit_stages
from ._settings import Settings
from ._stage import with_prior
from ._stage_result import finished_stage
from ._tasks import (
    Job,
    Run,
    assemble,
    checked,
    likelihood,
    padded_obs,
    padded_rows,
    stage1_task,
    stage2_task,
)

#: Problems per device in one wave of a batch.
WAVE = BATCH_WAVE

#: Fields of :class:`Settings` every problem of a batch shares (the compiled programs' shapes
#: and the search): they may differ in ``seed`` only.
SHARED_SETTINGS = ("model", "population", "generations", "early_stop", "tol", "crossover",
                   "mutation", "polish", "restarts", "loss", "loss_scale_mm")  # fmt: skip


@in_float64
def calibrate_batch(
    datasets: Sequence[Dataset],
    settings: Settings | Sequence[Settings] = Settings(),
    *,
    progress: bool = False,
    wave: int = WAVE,
    errors: Literal["raise", "return"] = "raise",
    mesh: Mesh | None = None,
) -> list[CalibrationResult]:
    """:func:`~handeye_jax.calibrate` of every dataset, in one batch.

    Both stages run as in :func:`~handeye_jax.calibrate` (DE, the LM polish, the restarts and
    the refits), each step one compiled program for all the problems of a wave, each problem
    with its own convergence and early stop; result ``i`` is ``calibrate(datasets[i],
    settings[i])``'s, bit for bit. The batch is sharded over this process's devices; under
    ``jax.distributed`` each process fits a contiguous share and every process returns every
    result (another process's as read back from its JSON, without ``fits``).

    Args:
        datasets: the datasets (validated, see :func:`~handeye_jax.load_dataset`).
        settings: one for all, or one per dataset; they may differ in ``seed`` only.
        progress: a progress bar over the problems on stderr.
        wave: the most problems per device fitted at once.
        errors: ``"raise"`` the first dataset's error (as a loop of ``calibrate`` would), or
            ``"return"`` it in that dataset's place, so that the others' results still come.
        mesh: the devices (default: all of this process's).
    """
    if not datasets:
        return []
    each = _settings_of(datasets, settings)
    get_model(each[0].model)  # an unknown name fails here, before any work
    plans = [timed(full_plan, d, s) for d, s in zip(datasets, each, strict=True)]
    outcomes = fit_batch(datasets, [p for p, _ in plans], each, progress=progress, wave=wave,
                         mesh=mesh)  # fmt: skip
    if errors == "raise":
        for out in outcomes:
            if isinstance(out, Exception):
                raise out
    return [out if isinstance(out, Exception) else with_plan_time(out, plan_s)
            for out, (_, plan_s) in zip(outcomes, plans, strict=True)]  # fmt: skip


def with_plan_time(result: CalibrationResult, seconds: float) -> CalibrationResult:
    """``result`` with the seconds its plan took (the search's ranges, from the data) in its
    ``timings_s``, as ``plan`` and in ``total``."""
    t = result.timings_s
    return replace(result, timings_s={**t, "plan": seconds, "total": t["total"] + seconds})


def _settings_of(datasets: Sequence[Dataset], settings) -> list[Settings]:
    each = [settings] * len(datasets) if isinstance(settings, Settings) else list(settings)
    if len(each) != len(datasets):
        raise ValueError(f"{len(each)} settings for {len(datasets)} datasets")
    check_shared(each)
    return each


def check_shared(each: Sequence[Settings]) -> None:
    """Raise ``ValueError`` unless the settings of a batch differ in ``seed`` only."""
    for s in each[1:]:
        differ = [f for f in SHARED_SETTINGS if getattr(s, f) != getattr(each[0], f)]
        if differ:
            raise ValueError(f"the settings of a batch may differ in seed only (not {differ[0]})")


def fit_batch(
    datasets: Sequence[Dataset],
    plans: Sequence[Plan],
    settings: Sequence[Settings],
    *,
    progress: bool = False,
    wave: int = WAVE,
    mesh: Mesh | None = None,
    stage_progress: bool = False,
) -> list[CalibrationResult | InputError]:
    """:func:`~handeye_jax.fit` of every dataset with its plan and settings, in one batch:
    each result, or the :class:`InputError` its dataset raised.

    Args:
        datasets, plans, settings: one of each per problem (settings differing in seed only).
        progress: a progress bar over the problems on stderr.
        wave: the most problems per device fitted at once.
        mesh: the devices (default: all of this process's; under ``jax.distributed``, each
            process fits its share on its own).
        stage_progress: each stage's DE progress bar on stderr.
    """
    if jax.process_count() > 1 and mesh is None:
        return _distributed(datasets, plans, settings, progress, wave)
    mesh = problem_mesh() if mesh is None else mesh
    out: list[CalibrationResult | InputError | None] = [None] * len(datasets)
    runs: dict[int, Run] = {}
    for i, (d, p, s) in enumerate(zip(datasets, plans, settings, strict=True)):
        try:
            runs[i] = Run(checked(d, p, s), s, stage_progress, d.source)
        except InputError as e:
            out[i] = e
    per_wave = max(wave, 1) * mesh.devices.size
    with progress_bar(total=len(datasets), desc="calibrations", enabled=progress,
                      unit="problem") as bar:  # fmt: skip
        bar.update(len(datasets) - len(runs))
        for members in _groups(runs, plans).values():
            for start in range(0, len(members), per_wave):
                part = members[start : start + per_wave]
                problems = [Job(datasets[i], plans[i], runs[i]) for i in part]
                for i, result in zip(part, _wave(problems, mesh), strict=True):
                    out[i] = result
                bar.update(len(part))
    return out


def _groups(runs: dict[int, Run], plans: Sequence[Plan]) -> dict[tuple, list[int]]:
    """The problems that can share a wave, by their structure and padded size (see the module
    docstring)."""
    groups: dict[tuple, list[int]] = {}
    for i, run in runs.items():
        plan, obs = plans[i], run.obs
        space = plan.space1
        task = stage1_task(run, plan)
        objective = with_prior(task.build(space.template, space.free), space, obs.n_landmarks)
        rows = padded_rows(obs)
        prior2 = None if plan.space2.prior is None else plan.space2.prior.names
        key = (jax.tree.structure(objective), tuple(plan.search1), plan.space2.free,
               tuple(plan.search2), prior2, obs.n_landmarks if rows is None else rows)  # fmt: skip
        groups.setdefault(key, []).append(i)
    return groups


def _wave(problems: list[Job], mesh: Mesh) -> list[CalibrationResult | InputError]:
    """Both stages of one wave's problems (of one structure and padded size)."""
    t_start = time.perf_counter()
    real = len(problems)
    filled = problems + [problems[0]] * (padded_size(real, mesh) - real)
    live = np.arange(len(filled)) < real
    settings, progress = filled[0].run.settings, filled[0].run.progress
    keys = [stage_keys(np.int64(p.run.settings.seed)) for p in filled]
    pads = [padded_obs(p.run) for p in filled]
    mask = None if pads[0] is None else np.stack([m for _, m, _ in pads])
    tasks1 = [stage1_task(p.run, p.plan) for p in filled]
    padded1 = None if mask is None else [stage1_task(p.run, p.plan, o).build
                                         for p, (o, _, _) in zip(filled, pads, strict=True)]
    fits1 = fit_stages(tasks1, settings, [k[0] for k in keys], padded=padded1, mask=mask,
                       mesh=mesh, live=live, progress=progress)  # fmt: skip
    # Under the ml loss each problem's fit is refined to maximum likelihood on its own.
    ml1 = [timed(likelihood, f, p.run, p.plan.noise1, None, estimate=p.plan.previous is None)
           for f, p in zip(fits1[:real], problems, strict=True)]  # fmt: skip
    fits1 = [f for (f, _), _ in ml1] + list(fits1[real:])
    stages1 = [_finish(f, "stage 1", p, noise)
               for ((f, noise), _), p in zip(ml1, problems, strict=True)]  # fmt: skip
    # Stage 2 on each real problem's stage-1 model; the fillers copy the first one's.
    models = [f.model() for f in fits1[:real]] + [fits1[0].model()] * (len(filled) - real)
    tasks2, points, padded2 = [], [], []
    for p, model, pad in zip(filled, models, pads, strict=True):
        task, pts = stage2_task(p.run, model, p.plan.space2, p.plan.search2)
        tasks2.append(task)
        points.append(pts)
        if mask is not None:
            padded2.append(stage2_task(p.run, model, p.plan.space2, p.plan.search2,
                                       pad[2])[0].build)  # fmt: skip
    fits2 = fit_stages(tasks2, settings, [k[1] for k in keys],
                       padded=None if mask is None else padded2, mask=mask, mesh=mesh,
                       live=live, progress=progress)  # fmt: skip
    finished = []
    for j, p in enumerate(problems):
        (fit2, noise2), ml2_s = timed(likelihood, fits2[j], p.run, p.plan.noise2, models[j],
                                       estimate=p.plan.previous is None)  # fmt: skip
        stage2 = _finish(fit2, "stage 2", p, noise2)
        if isinstance(stages1[j], InputError) or isinstance(stage2, InputError):
            finished.append(stages1[j] if isinstance(stages1[j], InputError) else stage2)
            continue
        centres = np.asarray(rotation_centres(fit2.model(), points[j], p.run.obs.centre_index))
        # The maximum-likelihood refinement is the polish's last step: its seconds count there.
        fits = Stages(_polished_for(fits1[j], ml1[j][1]), _polished_for(fit2, ml2_s))
        finished.append((p, fits, Stages(stages1[j], stage2), centres))
    # Every step of the wave, both stages and their refinements, shared by its problems.
    share = (time.perf_counter() - t_start) / real
    return [f if isinstance(f, InputError) else
            assemble(f[0], f[1], f[2], centres=f[3], total_s=share)
            for f in finished]  # fmt: skip


def timed(fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` and the seconds it took."""
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def _polished_for(fit, seconds: float):
    """``fit`` with ``seconds`` more in its polish's time."""
    return replace(fit, timings={**fit.timings, "polish": fit.timings["polish"] + seconds})


def _finish(fit, name: str, problem: Job, noise):
    try:
        return replace(finished_stage(fit, name, problem.dataset.source), noise=noise)
    except InputError as e:
        return e


# -- several processes (jax.distributed) -------------------------------------------------------


def _distributed(datasets, plans, settings, progress: bool, wave: int):
    """Each process fits its contiguous share; every process gets every result."""
    from jax.experimental import multihost_utils

    count, me = jax.process_count(), jax.process_index()
    share = -(-len(datasets) // count)
    mine = range(me * share, min(len(datasets), (me + 1) * share))
    local = fit_batch([datasets[i] for i in mine], [plans[i] for i in mine],
                      [settings[i] for i in mine], progress=progress and me == 0, wave=wave,
                      mesh=problem_mesh())  # fmt: skip
    texts = [json.dumps({"error": [str(r.path), r.field, r.message]})
             if isinstance(r, InputError) else result_to_json(r) for r in local]  # fmt: skip
    blob = np.frombuffer(json.dumps(texts).encode(), np.uint8)
    sizes = multihost_utils.process_allgather(np.array([blob.size]))
    padded = np.zeros(int(sizes.max()), np.uint8)
    padded[: blob.size] = blob
    every = multihost_utils.process_allgather(padded)
    out: list = []
    for p in range(count):
        if p == me:
            out += local
            continue
        for text in json.loads(bytes(every[p, : int(sizes[p, 0])]).decode()):
            doc = json.loads(text)
            i = len(out)
            if "error" in doc and "format" not in doc:
                out.append(InputError(*doc["error"]))
            else:
                out.append(result_from_json(text, f"{datasets[i].name} (process {p})"))
    return out

