"""Repeatability: a result refitted on B resamples of its own data, all in one batch
(:func:`~handeye_jax.calibrate_batch`), and how far the hand commands of the stage to deploy
move from one refit to the next.

**What a resample draws.** A calibration measures two kinds of things, each with its own
noise: touches (the hand's position and angle, the tablet's touch error) and views (a
picture's image point and depth of a landmark). The capture poses and the landmarks drawn are
the design, not draws, and stay. A resample draws the touches with replacement, as many as
there were; each drawn touch brings the rows that pair it with its landmark's views, and a
touch drawn twice is two touches (two rows of weight one each: the fit sees it twice). With
several captures the pictures are resampled too: each capture's views are drawn with
replacement, as many as it has; a view drawn twice is the same picture taken twice (a copy of
the capture holding the repeated views), so a resample is again a :class:`Dataset`, which the
batch fits as any other. With one capture a landmark's view goes with its touches (the
paper's case: a landmark's view and its touch are one case).

**The spread.** For each target (the calibration's own views, touched at hand angles over the
touches' range: the verdict's targets, :func:`~handeye_jax.problem.workspace_targets`), the
distance of each refit's hand command from the refits' mean command; its mean and 95th
percentile over refits and targets, mm. The fit's covariance predicts the same two numbers
(:func:`~handeye_jax.problem.uncertainty` with the targets measured exactly: the fit's part of
the command error alone), and with each target's own measurement added, the expected touching
error the spread is compared with.

Read-only: the result's parameters are not changed; :func:`with_bootstrap` adds the report to
its diagnostics.
"""

from __future__ import annotations

import time
from dataclasses import replace

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import geometry as geo
from .._core import MAX_BOOTSTRAP, InputError
from .._jax import fast_compile, in_float64
from ..calibration import (
    WAVE,
    Bootstrap,
    CalibrationResult,
    Diagnostics,
    ErrorMap,
    Settings,
    calibrate_batch,
    fitted_stages,
    is_ml,
    noise_part,
    prior_information,
)
from ..data import Capture, Dataset, centre_landmark
from ..models import hand_command
from ..problem import (
    StagePoint,
    Targets,
    error_statistics,
    get_noise_model,
    uncertainty,
    workspace_targets,
)
from ._verdict import VERDICT_ANGLES, stage_noise

#: Grid points along each side of the workspace error map.
MAP_POINTS = 21
#: The map covers the landmarks' extent widened by this fraction of it on each side.
MAP_MARGIN = 0.15
#: Capture heights above the first capture at which the spread is given, mm.
RISES_MM = tuple(float(r) for r in range(-100, 151, 25))
#: The quantile of the spread reported beside its mean.
QUANTILE = 95.0


def resample(dataset: Dataset, rng: np.random.Generator) -> Dataset:
    """One bootstrap resample of a dataset (see the module): its touches drawn with
    replacement, and with several captures each capture's views too; a valid dataset of the
    same landmarks, camera and capture poses (version 2)."""
    draw = np.sort(rng.integers(0, dataset.n_touches, dataset.n_touches))
    # The touches nearest the centre landmark first: the centre of rotation's row (the first
    # row of the landmark drawn nearest it) is then the first, in every resample, so they
    # share the batch's compiled programs (the row is part of a program's structure).
    tablet = dataset.tablet_px
    near = np.linalg.norm(tablet[dataset.touch_landmark[draw]]
                          - tablet[centre_landmark(tablet)], axis=1)  # fmt: skip
    draw = draw[np.lexsort((draw, near))]
    captures = list(dataset.captures)
    if len(captures) > 1:
        captures = []
        for cap in dataset.captures:
            k = len(cap.landmarks)
            times = np.bincount(rng.integers(0, k, k), minlength=k) if k else np.ones(0, int)
            # Layer j holds the views drawn at least j times: the picture taken j times.
            for layer in range(1, max(int(times.max(initial=1)), 1) + 1):
                keep = times >= layer
                captures.append(Capture(cap.hand_position_mm, cap.hand_angle_deg,
                                        cap.landmarks[keep], cap.image_px[keep],
                                        cap.depth_mm[keep]))  # fmt: skip
    return dataset.replace(
        captures=captures, touch_landmark=dataset.touch_landmark[draw],
        hand_xy_mm=dataset.hand_xy_mm[draw], hand_z_mm=dataset.hand_z_mm[draw],
        hand_angle_deg=dataset.hand_angle_deg[draw],
        touch_error_px=dataset.touch_error_px[draw], version=2,
    )  # fmt: skip


def resamples_of(dataset: Dataset, count: int, seed: int) -> list[Dataset]:
    """``count`` resamples of ``dataset`` (:func:`resample`), drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    return [resample(dataset, rng) for _ in range(count)]


def _resampled_words(dataset: Dataset) -> str:
    t, caps = dataset.n_touches, len(dataset.captures)
    if caps == 1:
        return f"the {t} touches, each with its view"
    return f"the {t} touches and each of the {caps} pictures' views, capture poses kept"


@in_float64
def bootstrap(
    result: CalibrationResult,
    resamples: int,
    *,
    seed: int | None = None,
    settings: Settings | None = None,
    progress: bool = False,
    wave: int = WAVE,
) -> Bootstrap:
    """How far the hand commands of ``result``'s stage to deploy move between refits on
    resamples of its data: every resample fitted in one batch, both stages, as ``calibrate``
    fits (see the module for what a resample draws and what the spread is).

    Args:
        result: a calibration carrying its data (read from a file or just computed), not a
            recalibration (a prior is not resampled).
        resamples: B, how many resamples to refit, 1 to 10,000.
        seed: the resampling's seed (default: the result's); the same seed gives the same
            report bit for bit.
        settings: how each resample is fitted (default: the result's own settings, seed
            included).
        progress: a progress bar over the refits on stderr.
        wave: the most refits per device fitted at once.

    Returns:
        The spread (mm) over the landmarks' area, the covariance's prediction of it and the
        expected touching error (``ml`` loss only), the spread over the tablet area and over
        capture heights (:class:`ErrorMap`) and the wall time (s).
    """
    t0 = time.perf_counter()
    data = result.data
    if data is None:
        raise InputError(None, "data", "the result does not carry its data: it cannot be "
                         "resampled; calibrate again")  # fmt: skip
    if result.recalibration is not None:
        raise InputError(data.source, "bootstrap", "not for a recalibration (--prior): its "
                         "prior is not resampled; bootstrap the calibration it came from")
    if not 1 <= resamples <= MAX_BOOTSTRAP:
        raise ValueError(f"resamples must be 1 to {MAX_BOOTSTRAP:,} (got {resamples})")
    seed = result.settings.seed if seed is None else int(seed)
    settings = result.settings if settings is None else settings
    drawn = resamples_of(data, resamples, seed)
    usable = [d for d in drawn if d.n_rows > 0]  # a touch no picture sees brings no row
    fits = calibrate_batch(usable, settings, progress=progress, wave=wave, errors="return")
    ok = [r for r in fits if isinstance(r, CalibrationResult)]
    if len(ok) < 2:
        raise InputError(data.source, "bootstrap", f"only {len(ok)} of {resamples} resamples "
                         "could be fitted: too few touches to resample")  # fmt: skip
    stage = result.deploy_stage
    obs = data.observations()
    main = workspace_targets(obs, VERDICT_ANGLES)
    angles = np.unique(np.asarray(main.hand_angle_deg))
    grid = _grid(result, angles)
    rises = _rises(result, angles)
    parts = [main] + ([] if grid is None else [grid[0]]) + [t for _, t in rises]
    commands = np.asarray(_commands(*_stacked(ok), obs.rig, _joined(parts), stage))
    spread = np.linalg.norm(commands - commands.mean(axis=0), axis=2)  # (refits, targets)
    pieces = np.split(spread, np.cumsum([p.k for p in parts])[:-1], axis=1)
    predicted = _predicted(result, [main] + [t for _, t in rises], stage)
    height_predicted = None if predicted is None else tuple(m for m, _ in predicted[2:])
    error_map = None if grid is None else _error_map(
        data, grid, rises, pieces, len(angles), height_predicted
    )
    return Bootstrap(
        resamples=resamples, fitted=len(ok), seed=seed, stage=stage,
        resampled=_resampled_words(data), spread_mean_mm=float(pieces[0].mean()),
        spread_p95_mm=float(np.percentile(pieces[0], QUANTILE)), targets=int(main.k),
        predicted_mean_mm=None if predicted is None else predicted[0][0],
        predicted_p95_mm=None if predicted is None else predicted[0][1],
        touching_mean_mm=None if predicted is None else predicted[1][0],
        seconds=time.perf_counter() - t0, map=error_map,
    )  # fmt: skip


def _error_map(data, grid, rises, pieces, n_angles: int, height_predicted) -> ErrorMap:
    """The map of the spread: over the tablet grid (``pieces[1]``, averaged over the refits
    and the hand angles) and over the capture heights (the last ``len(rises)`` pieces)."""
    per_point = pieces[1].mean(axis=0).reshape(MAP_POINTS, MAP_POINTS, n_angles)
    rise_pieces = pieces[-len(rises):]
    mm = data.mm_per_tablet_px
    return ErrorMap(
        grid_x_mm=tuple(grid[1].tolist()), grid_y_mm=tuple(grid[2].tolist()),
        spread_mm=tuple(tuple(r) for r in per_point.mean(axis=2).tolist()),
        landmarks_mm=tuple((float(x), float(y)) for x, y in data.tablet_px * mm),
        capture_z_mm=float(data.captures[0].hand_position_mm[2]),
        rises_mm=tuple(r for r, _ in rises),
        height_mean_mm=tuple(float(p.mean()) for p in rise_pieces),
        height_p95_mm=tuple(float(np.percentile(p, QUANTILE)) for p in rise_pieces),
        height_predicted_mm=height_predicted,
    )  # fmt: skip


def with_bootstrap(result: CalibrationResult, report: Bootstrap) -> CalibrationResult:
    """``result`` with the bootstrap in its diagnostics (its parameters untouched) and its
    time in ``timings_s["bootstrap"]``."""
    diagnostics = replace(result.diagnostics or Diagnostics(), bootstrap=report)
    timings = {**result.timings_s, "bootstrap": report.seconds}
    return replace(result, diagnostics=diagnostics, timings_s=timings)


# -- the targets -------------------------------------------------------------------------


def _first_views(result: CalibrationResult) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first capture's views of the landmarks: tablet mm ``(m, 2)``, camera-frame points
    mm ``(m, 3)`` (undistorted, back-projected) and the landmarks' indices."""
    data = result.data
    cap = data.captures[0]
    uv = data.camera.undistort(cap.image_px)
    rig = result.rig
    p = np.asarray(geo.backproject(jnp.asarray(uv), jnp.asarray(cap.depth_mm), rig.fx_px,
                                   rig.fy_px, rig.cx_px, rig.cy_px))  # fmt: skip
    return data.tablet_px[cap.landmarks] * data.mm_per_tablet_px, p, cap.landmarks


def _targets(result: CalibrationResult, p_camera: np.ndarray, angles: np.ndarray,
             rise_mm: float = 0.0) -> Targets:  # fmt: skip
    """Targets at camera-frame points ``p_camera`` (mm) seen from the first capture moved up
    by ``rise_mm``, each touched at every one of ``angles`` (deg)."""
    rig, cap = result.rig, result.data.captures[0]
    uv, depth = geo.project(jnp.asarray(p_camera), rig.fx_px, rig.fy_px, rig.cx_px, rig.cy_px)
    m, a = p_camera.shape[0], len(angles)
    position = cap.hand_position_mm + np.array([0.0, 0.0, rise_mm])
    rep = lambda x: jnp.repeat(jnp.asarray(x), a, axis=0)  # noqa: E731
    return Targets(rep(uv), rep(depth), jnp.asarray(np.tile(angles, m)),
                   jnp.asarray(np.tile(position, (m * a, 1))),
                   jnp.full(m * a, float(cap.hand_angle_deg)))  # fmt: skip


def _grid(result: CalibrationResult, angles: np.ndarray):
    """The map's targets over the tablet area seen from the first capture, and its axes
    (tablet mm); ``None`` when that picture shows fewer than three landmarks off one line.

    The display is a plane: its points map to the camera frame by an affine map, fitted to
    the picture's own landmarks (back-projected), so the map needs no model of the rig."""
    tablet, p, _ = _first_views(result)
    A = np.column_stack([tablet, np.ones(len(tablet))])
    if len(tablet) < 3 or np.linalg.matrix_rank(A) < 3:
        return None
    M = np.linalg.lstsq(A, p, rcond=None)[0]
    lo, hi = tablet.min(axis=0), tablet.max(axis=0)
    pad = MAP_MARGIN * (hi - lo)
    xs = np.linspace(lo[0] - pad[0], hi[0] + pad[0], MAP_POINTS)
    ys = np.linspace(lo[1] - pad[1], hi[1] + pad[1], MAP_POINTS)
    gx, gy = np.meshgrid(xs, ys)  # rows by y
    points = np.column_stack([gx.ravel(), gy.ravel(), np.ones(gx.size)]) @ M
    return _targets(result, points, angles), xs, ys


def _rises(result: CalibrationResult, angles: np.ndarray) -> list[tuple[float, Targets]]:
    """The first capture's views seen from captures :data:`RISES_MM` higher: the hand moves
    up, so in the camera frame (the fitted mount's) the points move along the hand's z."""
    _, p, _ = _first_views(result)
    R_hand_camera, _ = result.model.camera_mount()
    up = np.asarray(R_hand_camera).T @ np.array([0.0, 0.0, 1.0])
    return [(r, _targets(result, p + r * up, angles, r)) for r in RISES_MM]


def _joined(parts: list[Targets]) -> Targets:
    return jax.tree.map(lambda *a: jnp.concatenate(a), *parts)


# -- the commands and the prediction ------------------------------------------------------


def _stacked(results: list[CalibrationResult]):
    """The refits' models, corrections and centres, stacked along a leading axis."""
    stack = lambda *a: jnp.stack([jnp.asarray(x, dtype=float) for x in a])  # noqa: E731
    models = jax.tree.map(stack, *[r.model for r in results])
    corrections = jax.tree.map(stack, *[r.correction for r in results])
    return models, corrections, jnp.asarray(np.stack([r.centres_mm for r in results]))


@fast_compile
def _commands(models, corrections, centres, rig, targets: Targets, stage: int):
    """Every refit's hand commands ``(x, y)`` for the targets, mm: ``(refits, k, 2)``."""

    def one(model, correction, c):
        out = hand_command(model, rig, targets, correction=correction if stage == 2 else None,
                           centres_mm=c)
        return out[:, :2]

    return eqx.filter_vmap(one)(models, corrections, centres)


def _predicted(result: CalibrationResult, parts: list[Targets], stage: int):
    """Per part of the targets, the covariance's ``(mean, p95)`` of the fit's command error
    (mm); and for the first part, the expected touching error (with the target's own
    measurement) as its second entry; ``None`` unless both stages are maximum-likelihood fits."""
    stages = fitted_stages(result, result.data.search)
    one, two = stages.stage1, stages.stage2
    if not (is_ml(one.objective) and is_ml(two.objective)):
        return None
    noise = stage_noise(result.stage1) or get_noise_model(result.settings.noise)
    P1, P2 = prior_information(one.space), prior_information(two.space)
    j = lambda P: None if P is None else jnp.asarray(P)  # noqa: E731
    point1 = StagePoint(noise_part(one.objective), jnp.asarray(one.x), j(P1))
    args = dict(stage2=StagePoint(noise_part(two.objective), jnp.asarray(two.x), j(P2)),
                stage=stage)  # fmt: skip
    targets = _joined(parts)
    # Targets measured exactly (no picture noise): the fit's part of the error alone.
    exact = replace(noise, view_scale=0.0, depth_scale=0.0)
    fit_part = np.asarray(uncertainty(point1, targets, exact, **args)[2].covariance_mm2)
    # All targets again (one compiled program for both calls); the first part's kept.
    touching = np.asarray(uncertainty(point1, targets, noise, **args)[2].covariance_mm2)
    touching = touching[: parts[0].k]
    out = []
    for piece in [touching] + np.split(fit_part, np.cumsum([p.k for p in parts])[:-1]):
        mean, p95, _ = _statistics(jnp.asarray(piece))
        out.append((float(mean), float(p95)))
    return [out[1], out[0], *out[2:]]


_statistics = fast_compile(error_statistics)
