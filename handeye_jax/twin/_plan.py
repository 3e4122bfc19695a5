"""The error of an acquisition before it is taken: linearised, Monte Carlo, and optimised.

An *acquisition* is what the user will do at the rig: where the landmarks are drawn (tablet
px), the hand angle of each touch (deg) and the capture poses the pictures are taken from.
Its *expected error* is the held-out touching error of the hand commands a calibration of it
gives, over a :class:`Workspace` of targets (tablet px, hand angles, capture heights), in mm,
for each stage. It is computed two ways on a rig taken as the truth (:func:`planning_truth`:
from a dataset, a result or a twin's truth):

* **linearised** (:func:`predict_acquisition`): the maximum-likelihood fit's covariance from
  the whitened Jacobian of the noise-free acquisition and the noise model, propagated to the
  hand commands with each target's own measurement noise
  (:func:`~handeye_jax.problem.predict_command_error`); fast and differentiable;
* **Monte Carlo** (:func:`monte_carlo_acquisition`): ``K`` noisy copies of the acquisition
  drawn from the same noise model, calibrated together (:func:`~handeye_jax.calibrate_batch`)
  and evaluated on the workspace's targets with the twin's own evaluation
  (:func:`~handeye_jax.twin.evaluate_points`).

:func:`optimise_layout` moves the landmarks and hand angles by projected gradient descent on
the linearised stage-1 mean error, within the display and the picture.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._jax import in_float64
from ..calibration import CalibrationResult, Settings, calibrate_batch
from ..data import Capture, Dataset, snake_grid_px
from ..models import HTMModel, Rig
from ..problem import (
    NoiseModel,
    Stage1Objective,
    StagePoint,
    Targets,
    closed_form_estimate,
    command_error,
    get_noise_model,
    noise_objective,
    predict_command_error,
    traced_command_error,
)
from ._evaluate import Heldout, evaluate_points
from ._simulate import draw_capture_poses
from ._synthetic import capture_rig, synthesize_dataset
from ._truth import TwinTruth

#: The paper's hand angles span this, deg (``22.5·m`` for its nine touches).
ANGLE_SPAN_DEG = 180.0
#: The operator's touch error in the Monte Carlo twins, σ per axis, mm (the ``paper`` twin's);
#: the tablet reports it (rounded), so only its rounding enters the fit.
OPERATOR_SIGMA_MM = 0.45
#: How far inside every picture :func:`optimise_layout` keeps the landmarks, image px.
LAYOUT_MARGIN_PX = 64.0
#: How far :func:`optimise_layout` may move a picture from the first: sideways (x and y) and
#: up, mm (the twin's pictures rise to 90 mm; a robot reaches this much about the tablet).
CAPTURE_REACH_MM = (50.0, 150.0)
#: How far :func:`optimise_layout` may turn a picture's hand angle from the first's, deg.
CAPTURE_TURN_DEG = 45.0
#: The quantile reported beside the mean.
QUANTILE = 0.95


@dataclass(frozen=True)
class Acquisition:
    """What will be taken at the rig.

    Attributes:
        name: a label for tables.
        tablet_px: where the landmarks are drawn, tablet px, ``(n, 2)``, in touch order.
        hand_angle_deg: the hand angle θh of each touch, deg, ``(n,)``.
        capture_poses: each picture's hand position (mm, ``(3,)``) and hand angle θc (deg);
            the first is the rig's capture. Every picture sees every landmark.
    """

    name: str
    tablet_px: np.ndarray = field(repr=False)
    hand_angle_deg: np.ndarray = field(repr=False)
    capture_poses: tuple[tuple[np.ndarray, float], ...] = field(repr=False)

    @property
    def touches(self) -> int:
        return int(len(self.tablet_px))

    @property
    def pictures(self) -> int:
        return len(self.capture_poses)


@dataclass(frozen=True)
class Workspace:
    """Where the hand commands will be used: targets on the display, touched at hand angles,
    each seen from a capture pose ``rise_mm`` above the rig's (same x-y and hand angle).

    Attributes:
        tablet_px: the targets, tablet px, ``(k, 2)``.
        hand_angle_deg: the hand angle to touch each with, deg, ``(k,)``.
        rise_mm: how far above the rig's capture each target is seen from, mm, ``(k,)``.
    """

    tablet_px: np.ndarray = field(repr=False)
    hand_angle_deg: np.ndarray = field(repr=False)
    rise_mm: np.ndarray = field(repr=False)

    @property
    def k(self) -> int:
        return int(len(self.tablet_px))


@dataclass(frozen=True)
class StageError:
    """A stage's expected held-out touching error over a workspace, mm.

    Attributes:
        mean_mm: the mean error length (hand command x-y minus the true one), mm.
        p95_mm: its 95th percentile over targets (and twins), mm.
    """

    mean_mm: float
    p95_mm: float


@dataclass(frozen=True)
class AcquisitionError:
    """An acquisition's expected error, each stage, by one method.

    Attributes:
        name: the acquisition's name.
        touches, pictures: how many touches and pictures it takes.
        method: ``"linearised"`` or ``"monte carlo"``.
        stage1, stage2: each stage's expected error (mm).
        twins: the Monte Carlo twins calibrated (0 for the linearised prediction).
        stage1_spread_mm: the standard error of the Monte Carlo stage-1 mean (over twins), mm;
            ``None`` for the linearised prediction.
    """

    name: str
    touches: int
    pictures: int
    method: str
    stage1: StageError
    stage2: StageError
    twins: int = 0
    stage1_spread_mm: float | None = None

    def stage(self, k: int) -> StageError:
        return self.stage1 if k == 1 else self.stage2


# -- the rig -----------------------------------------------------------------------------
@in_float64
def planning_truth(
    source: Dataset | CalibrationResult | TwinTruth,
    *,
    display_px: tuple[float, float] = (1280.0, 800.0),
) -> TwinTruth:
    """The rig a plan takes as the truth: a twin's truth as it is; a result's fitted HTM
    model (or, for another model, the closed-form estimate of its data) on its dataset's
    camera and tablet; a dataset's closed-form estimate (:func:`~handeye_jax.problem.
    closed_form_estimate`). The tablet's height is where the views put the landmarks (mm, the
    camera's offset along the hand's z taken as 0); the picture's size is twice the principal
    point (px); the landmarks and hand angles are the data's (they set the workspace's area).

    Raises:
        ValueError: the data do not determine the rig (see ``closed_form_estimate``), or a
            result carries no dataset.
    """
    if isinstance(source, TwinTruth):
        return source
    if isinstance(source, CalibrationResult):
        if source.data is None:
            raise ValueError("the result carries no dataset: plan from the dataset instead")
        dataset = source.data
        obs = dataset.observations()
        model = source.model if isinstance(source.model, HTMModel) else None
    else:
        dataset, model = source, None
        obs = dataset.observations()
    if model is None:
        est = closed_form_estimate(obs).candidates[0]
        model = HTMModel.from_dict(est.params(HTMModel))
    c = dataset.camera
    first = dataset.captures[0]
    rig = dataset.rig()
    z = _view_heights(model, capture_rig(rig, first.hand_position_mm, first.hand_angle_deg),
                      c.undistort(first.image_px), first.depth_mm,
                      dataset.tablet_px[first.landmarks] * dataset.mm_per_tablet_px)  # fmt: skip
    angle = (float(first.hand_angle_deg) if rig.capture_hand_angle_deg is not None
             else None)  # fmt: skip
    return TwinTruth(
        image_size_px=(int(round(2 * c.cx_px + 1)), int(round(2 * c.cy_px + 1))),
        camera_px={"fx": c.fx_px, "fy": c.fy_px, "cx": c.cx_px, "cy": c.cy_px},
        lens_blur_px=0.5, model={n: float(getattr(model, n)) for n in HTMModel.param_names},
        camera_z_mm=0.0, tablet_height_mm=float(np.mean(z)),
        capture_position_mm=tuple(float(v) for v in first.hand_position_mm),
        ppi=float(dataset.tablet_ppi), scale=float(dataset.tablet_scale),
        display_px=(float(display_px[0]), float(display_px[1])), dot_px=1.0,
        hand_angle_zero_deg=float(dataset.hand_angle_zero_deg),
        hand_angle_sign=int(dataset.hand_angle_sign),
        landmarks_tablet_px=np.asarray(dataset.tablet_px, float),
        landmarks_hand_angle_deg=np.asarray(dataset.hand_angle_deg, float),
        capture_hand_angle_deg=angle,
    )  # fmt: skip


def _view_heights(model: HTMModel, rig, image_px, depth_mm, tablet_mm) -> np.ndarray:
    """The display's height in the base frame from each view, mm: the view's base-frame z
    (the camera at ``z_c = 0``) less its landmark's through the tablet chain (at ``z_t = 0``)."""
    R_bh, t_bh = rig.T_base_hand_capture()
    R_hc, t_hc = model.camera_mount()
    p = jnp.asarray(rig.p_camera(jnp.asarray(image_px), jnp.asarray(depth_mm)))
    base = (p @ R_hc.T + t_hc) @ R_bh.T + t_bh
    return np.asarray(base[:, 2] - model.tablet_to_base(jnp.asarray(tablet_mm))[:, 2])


# -- candidates and the workspace ----------------------------------------------------------
def grid_acquisition(
    truth: TwinTruth, per_side: int, captures: int = 1, *, seed: int = 0, name: str | None = None
) -> Acquisition:
    """A ``per_side × per_side`` snake grid over the truth's landmark area, touched at hand
    angles evenly over [0, 180] deg (the paper's 3×3 grid and ``22.5·m`` for ``per_side`` 3),
    with ``captures`` pictures: the truth's own capture and others rising to 90 mm above it at
    other hand angles (drawn by ``seed`` as the twin draws them, each seeing every landmark).
    """
    if per_side < 2:
        raise ValueError(f"a grid needs at least 2 landmarks per side (got {per_side})")
    lo, hi = truth.landmark_area_px()
    layout = snake_grid_px(tuple(np.linspace(lo[0], hi[0], per_side)),
                           tuple(np.linspace(lo[1], hi[1], per_side)))  # fmt: skip
    angles = np.linspace(0.0, ANGLE_SPAN_DEG, len(layout))
    return layout_acquisition(truth, layout, angles, captures, seed=seed,
                              name=name or f"{per_side}x{per_side}, {captures} capture"
                              + ("s" if captures > 1 else ""))  # fmt: skip


def layout_acquisition(
    truth: TwinTruth,
    tablet_px: np.ndarray,
    hand_angle_deg: np.ndarray,
    captures: int = 1,
    *,
    seed: int = 0,
    name: str = "layout",
) -> Acquisition:
    """An acquisition of these landmarks (tablet px) and hand angles (deg), with ``captures``
    pictures (see :func:`grid_acquisition`)."""
    tablet_px = np.asarray(tablet_px, float)
    seen = replace(truth, landmarks_tablet_px=tablet_px,
                   landmarks_hand_angle_deg=np.asarray(hand_angle_deg, float))  # fmt: skip
    poses = draw_capture_poses(seen, captures, np.random.default_rng(seed))
    return Acquisition(name, tablet_px, np.asarray(hand_angle_deg, float),
                       tuple((np.asarray(p, float), float(a)) for p, a in poses))  # fmt: skip


def default_workspace(
    truth: TwinTruth, per_side: int = 5, angles: int = 8, rises_mm: Sequence[float] = (0.0,)
) -> Workspace:
    """Targets on a ``per_side × per_side`` grid over the truth's landmark area (tablet px),
    each touched at ``angles`` hand angles evenly over [0, 180) deg, seen from the rig's
    capture and from each of ``rises_mm`` above it (mm)."""
    lo, hi = truth.landmark_area_px()
    g = np.stack(np.meshgrid(np.linspace(lo[0], hi[0], per_side),
                             np.linspace(lo[1], hi[1], per_side)), -1).reshape(-1, 2)  # fmt: skip
    turns = np.arange(angles) * (ANGLE_SPAN_DEG / angles)
    rises = np.asarray(rises_mm, float)
    tab = np.tile(np.repeat(g, angles, axis=0), (len(rises), 1))
    ang = np.tile(turns, len(g) * len(rises))
    rise = np.repeat(rises, len(g) * angles)
    return Workspace(tab, ang, rise)


def _target_poses(truth: TwinTruth, workspace: Workspace) -> tuple[np.ndarray, np.ndarray]:
    position = np.tile(np.asarray(truth.capture_position_mm, float), (workspace.k, 1))
    position[:, 2] += workspace.rise_mm
    return position, np.full(workspace.k, truth.capture_angle_deg)


@in_float64
def workspace_as_targets(truth: TwinTruth, workspace: Workspace) -> Targets:
    """The workspace as the camera sees it (exact image points px and depths mm) from each
    target's capture pose, for :func:`~handeye_jax.problem.predict_command_error`."""
    position, angle = _target_poses(truth, workspace)
    uv, depth = _seen(truth, workspace.tablet_px, position, angle)
    return Targets(jnp.asarray(uv), jnp.asarray(depth), jnp.asarray(workspace.hand_angle_deg),
                   jnp.asarray(position), jnp.asarray(angle))  # fmt: skip


def _seen(truth: TwinTruth, tablet_px, position, angle) -> tuple[np.ndarray, np.ndarray]:
    """Image points (px) and depths (mm) of display points seen from per-point poses."""
    uv, depth = np.zeros((len(tablet_px), 2)), np.zeros(len(tablet_px))
    keys = np.column_stack([position, angle])
    for key in np.unique(keys, axis=0):
        m = np.all(keys == key, axis=1)
        uv[m], depth[m] = truth.at_capture(key[:3], float(key[3])).project(tablet_px[m])
    return uv, depth


# -- the acquisition's data ----------------------------------------------------------------
def _single(truth: TwinTruth, acq: Acquisition) -> bool:
    """One picture from the rig's own capture pose: the paper's simple dataset."""
    p, a = acq.capture_poses[0]
    return (acq.pictures == 1 and np.allclose(p, truth.capture_position_mm)
            and abs(a - truth.capture_angle_deg) < 1e-9)  # fmt: skip


def exact_dataset(truth: TwinTruth, acq: Acquisition, touch_error_px=None,
                  name: str = "plan") -> Dataset:  # fmt: skip
    """The noise-free dataset of ``acq`` on ``truth`` (``touch_error_px``: where the pen
    touched off each landmark, tablet px, recorded exactly)."""
    captures = None if _single(truth, acq) else list(acq.capture_poses)
    ds = synthesize_dataset(truth.htm(), truth.rig(), acq.tablet_px, acq.hand_angle_deg,
                            captures=captures, scene=truth.scene(),
                            touch_error_px=touch_error_px)  # fmt: skip
    return ds.replace(name=name)


# -- linearised ----------------------------------------------------------------------------
@in_float64
def predict_acquisition(
    truth: TwinTruth,
    acquisition: Acquisition,
    noise: NoiseModel | None = None,
    workspace: Workspace | None = None,
) -> AcquisitionError:
    """The linearised expected held-out error of ``acquisition`` on the rig ``truth``.

    Args:
        truth: the rig (see :func:`planning_truth`).
        acquisition: what will be taken.
        noise: the noise model (default: the ``paper`` preset).
        workspace: the targets (default: :func:`default_workspace`).
    """
    noise = noise or get_noise_model("paper")
    workspace = workspace or default_workspace(truth)
    obs = exact_dataset(truth, acquisition).observations()
    targets = workspace_as_targets(truth, workspace)
    model = truth.htm()
    stages = [predict_command_error(model, HTMModel.param_names, obs, noise, targets, stage=k)
              for k in (1, 2)]  # fmt: skip
    s1, s2 = (StageError(float(e.mean_mm), float(e.p95_mm)) for e in stages)
    return AcquisitionError(acquisition.name, acquisition.touches, acquisition.pictures,
                            "linearised", s1, s2)  # fmt: skip


# -- Monte Carlo ---------------------------------------------------------------------------
def noisy_dataset(truth: TwinTruth, acq: Acquisition, noise: NoiseModel,
                  rng: np.random.Generator, name: str = "plan") -> Dataset:  # fmt: skip
    """``acq`` as the noise model says the rig records it: image points and depths with
    their σ, the operator's touch error (:data:`OPERATOR_SIGMA_MM`) reported in whole tablet
    px, what the tablet does not see (``touch_sigma_mm``), hand positions rounded."""
    mm = truth.mm_per_tablet_px
    n = acq.touches
    touch_px = rng.normal(0.0, OPERATOR_SIGMA_MM, (n, 2)) / mm
    ds = exact_dataset(truth, acq, touch_px, name)
    hand = ds.hand_xy_mm + rng.normal(0.0, 1.0, (n, 2)) * noise.touch_sigma_mm
    if noise.hand_resolution_mm:
        hand = np.round(hand / noise.hand_resolution_mm) * noise.hand_resolution_mm
    res = noise.tablet_resolution_px
    reported = np.round(touch_px / res) * res if res else touch_px

    def shot(uv, depth):
        return (uv + rng.normal(0.0, noise.image_sigma_px, uv.shape),
                depth + rng.normal(0.0, noise.depth_sigma_mm, depth.shape))

    if ds.is_simple():
        uv, depth = shot(ds.image_px, ds.depth_mm)
        return ds.replace(image_px=uv, depth_mm=depth, hand_xy_mm=hand, touch_error_px=reported)
    caps = [Capture(c.hand_position_mm, c.hand_angle_deg, c.landmarks,
                    *shot(c.image_px, c.depth_mm)) for c in ds.captures]  # fmt: skip
    return ds.replace(captures=caps, hand_xy_mm=hand, touch_error_px=reported)


def workspace_heldout(truth: TwinTruth, workspace: Workspace, noise: NoiseModel,
             rng: np.random.Generator) -> Heldout:  # fmt: skip
    """The workspace's targets as the user measures them (``noise``'s target σ px and depth
    σ mm), with their true positions, for :func:`evaluate_points`."""
    position, angle = _target_poses(truth, workspace)
    uv, depth = _seen(truth, workspace.tablet_px, position, angle)
    s = noise.image_sigma_px if noise.target_sigma_px is None else noise.target_sigma_px
    return Heldout(uv + rng.normal(0.0, s, uv.shape),
                   depth + rng.normal(0.0, noise.depth_sigma_mm, depth.shape),
                   workspace.hand_angle_deg, workspace.tablet_px, position, angle,
                   truth.surface_points(workspace.tablet_px), np.zeros(workspace.k))  # fmt: skip


def errors_on_workspace(results: Sequence[CalibrationResult], truth: TwinTruth,
                        heldouts: Sequence[Heldout]) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Each result's held-out x-y command error on its targets, mm: ``(stage 1, stage 2)``,
    each ``(twins, k)``."""
    rows = [{r.label: r.xy_mm for r in evaluate_points(res, truth, h)}
            for res, h in zip(results, heldouts, strict=True)]  # fmt: skip
    return (np.array([r["stage 1"] for r in rows]), np.array([r["stage 2"] for r in rows]))


def summarise(name: str, acq: Acquisition, e1: np.ndarray, e2: np.ndarray,
              method: str = "monte carlo") -> AcquisitionError:  # fmt: skip
    """Errors ``(twins, k)`` of each stage, mm, as an :class:`AcquisitionError`: the mean,
    the 95th percentile of all, and the standard error of stage 1's mean over the twins."""
    twins = len(e1)
    per = e1.mean(axis=1)
    se = float(per.std(ddof=1) / math.sqrt(twins)) if twins > 1 else math.inf
    stat = lambda e: StageError(float(e.mean()), float(np.quantile(e, QUANTILE)))  # noqa: E731
    return AcquisitionError(name, acq.touches, acq.pictures, method, stat(e1), stat(e2),
                            twins, se)  # fmt: skip


def monte_carlo_acquisition(
    truth: TwinTruth,
    acquisition: Acquisition,
    twins: int,
    noise: NoiseModel | None = None,
    workspace: Workspace | None = None,
    settings: Settings | None = None,
    *,
    seed: int = 0,
    progress: bool = False,
) -> AcquisitionError:
    """The Monte Carlo expected held-out error of ``acquisition`` on the rig ``truth``.

    ``twins`` noisy copies (:func:`noisy_dataset`, seeds from ``seed``) are calibrated in one
    batch (:func:`~handeye_jax.calibrate_batch`, ``settings``, each twin's own seed) and each
    result sends the hand to the workspace's targets as measured (:func:`evaluate_points`).

    Args:
        truth, acquisition, noise, workspace: as for :func:`predict_acquisition`.
        twins: how many noisy copies, at least 2.
        settings: how to calibrate (default: :class:`~handeye_jax.Settings`'s defaults).
        seed: seeds every draw.
        progress: a progress bar over the twins.
    """
    if twins < 2:
        raise ValueError(f"Monte Carlo needs at least 2 twins (got {twins})")
    noise = noise or get_noise_model("paper")
    workspace = workspace or default_workspace(truth)
    settings = settings or Settings()
    rngs = np.random.default_rng(seed).spawn(twins)
    data = [noisy_dataset(truth, acquisition, noise, r, name=f"plan-{i}")
            for i, r in enumerate(rngs)]  # fmt: skip
    held = [workspace_heldout(truth, workspace, noise, r) for r in rngs]
    each = [replace(settings, seed=int(seed) + i) for i in range(twins)]
    results = calibrate_batch(data, each, progress=progress)
    e1, e2 = errors_on_workspace(results, truth, held)
    return summarise(acquisition.name, acquisition, e1, e2)


def recommend(errors: Sequence[AcquisitionError], target_mm: float,
              stage: int = 1) -> AcquisitionError | None:  # fmt: skip
    """The candidate with the fewest touches, then pictures, whose ``stage`` mean error is at
    most ``target_mm`` (mm); ``None`` when none is."""
    meets = [e for e in errors if e.stage(stage).mean_mm <= target_mm]
    if not meets:
        return None
    return min(meets, key=lambda e: (e.touches, e.pictures, e.stage(stage).mean_mm))


# -- design by gradient --------------------------------------------------------------------
class _Design(eqx.Module):
    tablet_px: Float[Array, "n 2"]
    hand_angle_deg: Float[Array, " n"]
    capture_position_mm: Float[Array, "c 3"]
    capture_angle_deg: Float[Array, " c"]


def _design(acq: Acquisition) -> _Design:
    return _Design(jnp.asarray(acq.tablet_px), jnp.asarray(acq.hand_angle_deg),
                   jnp.asarray(np.stack([p for p, _ in acq.capture_poses])),
                   jnp.asarray([a for _, a in acq.capture_poses]))  # fmt: skip


@dataclass(frozen=True)
class OptimisedLayout:
    """What :func:`optimise_layout` found.

    Attributes:
        acquisition: the optimised acquisition (as many touches and pictures; the first
            picture where it was).
        history_mm: the linearised stage-1 mean error at each step, mm.
    """

    acquisition: Acquisition
    history_mm: tuple[float, ...]


@dataclass(frozen=True)
class LayoutSearch:
    """How :func:`optimise_layout` moves a design, and where it keeps it.

    Attributes:
        steps: the most gradient steps.
        step_px: the largest move of a landmark per step, tablet px.
        step_deg: the largest turn of a hand angle (touches' and pictures') per step, deg.
        step_mm: the largest move of a picture's hand position per step, mm.
        margin_px: how far inside every picture the landmarks stay, image px (the detector
            loses one-pixel dots in a vignetted corner).
        reach_mm: how far a picture may move from the first (sideways, up), mm.
        turn_deg: how far a picture's hand angle may turn from the first's, deg.
    """

    steps: int = 40
    step_px: float = 40.0
    step_deg: float = 10.0
    step_mm: float = 10.0
    margin_px: float = LAYOUT_MARGIN_PX
    reach_mm: tuple[float, float] = CAPTURE_REACH_MM
    turn_deg: float = CAPTURE_TURN_DEG


@in_float64
def optimise_layout(
    truth: TwinTruth,
    acquisition: Acquisition,
    noise: NoiseModel | None = None,
    workspace: Workspace | None = None,
    search: LayoutSearch = LayoutSearch(),
) -> OptimisedLayout:
    """Landmark positions (tablet px), hand angles (deg) and the pictures after the first
    (hand position mm, hand angle deg) that lower the linearised stage-1 mean error of
    ``acquisition``, by projected gradient descent.

    Each step moves the landmarks, the angles (touches' and pictures') and the pictures'
    positions by at most ``search``'s steps along the normalised gradient (halving all when a
    step does not lower the error), then projects: the landmarks onto the display's whole px
    and ``search.margin_px`` inside every picture (a landmark that would leave one stays),
    the touches' angles into [0, 180]; a picture stays within ``search.reach_mm`` (sideways,
    up) of the first (never below it) and ``search.turn_deg`` of its hand angle, and where it
    was if it would lose a landmark.

    The gradient flows through the views' image points, depths, the tablet points and the
    hand angles of the noise-free acquisition; the noise model's weights (which depend on
    where the views fall only through the camera's orientation) are those of each step's
    start.
    """
    noise = noise or get_noise_model("paper")
    workspace = workspace or default_workspace(truth)
    targets = workspace_as_targets(truth, workspace)
    model = truth.htm()
    free = HTMModel.param_names
    x1 = jnp.stack([jnp.asarray(getattr(model, n), dtype=float) for n in free])

    def objective_at(acq: Acquisition):
        obs = exact_dataset(truth, acq).observations()
        return noise_objective(Stage1Objective(model, obs, free), noise, model), obs

    nobj, obs0 = objective_at(acquisition)
    rows = _row_map(obs0)

    def loss(design: _Design, nobj):
        obs = _traced_observations(truth, rows, nobj.base.obs, design)
        o = eqx.tree_at(lambda t: t.base.obs, nobj, obs)
        return traced_command_error(StagePoint(o, x1), targets, noise).mean_mm

    grad = eqx.filter_jit(jax.value_and_grad(loss))
    acq = acquisition
    history = [float(grad(_design(acq), nobj)[0])]
    scale = 1.0
    for _ in range(search.steps):
        design = _design(acq)
        _, g = grad(design, nobj)
        trial = _layout_step(truth, acq, design, g, scale, search)
        tobj, _ = objective_at(trial)
        tv = float(command_error(StagePoint(tobj, x1), targets, noise).mean_mm)
        if tv < history[-1]:
            acq, nobj = trial, tobj
            history.append(tv)
        else:
            scale /= 2
            if scale * search.step_px < 0.5:
                break
    return OptimisedLayout(replace(acq, name=f"{acquisition.name}, optimised"), tuple(history))


def _layout_step(truth: TwinTruth, acq: Acquisition, design: _Design, g: _Design,
                 scale: float, search: LayoutSearch) -> Acquisition:  # fmt: skip
    """``acq`` (its ``design``) moved ``scale`` times :func:`optimise_layout`'s steps down the
    gradient ``g``, then projected where a design may be."""

    def moved(x, gx, step):
        x, gx = np.asarray(x), np.asarray(gx)
        return x - scale * step * gx / (np.abs(gx).max() or 1.0)

    tab = moved(design.tablet_px, g.tablet_px, search.step_px)
    ang = np.clip(moved(design.hand_angle_deg, g.hand_angle_deg, search.step_deg), 0.0,
                  ANGLE_SPAN_DEG)  # fmt: skip
    poses = acq.capture_poses
    if acq.pictures > 1:  # the first picture stays: the rig's capture
        pos = moved(design.capture_position_mm[1:], g.capture_position_mm[1:], search.step_mm)
        turn = moved(design.capture_angle_deg[1:], g.capture_angle_deg[1:], search.step_deg)
        poses = _reachable(truth, acq, pos, turn, reach_mm=search.reach_mm,
                           turn_deg=search.turn_deg, margin_px=search.margin_px)  # fmt: skip
    tab = _project(truth, replace(acq, capture_poses=poses), tab, acq.tablet_px,
                   search.margin_px)  # fmt: skip
    return replace(acq, tablet_px=tab, hand_angle_deg=ang, capture_poses=poses)


def _project(truth: TwinTruth, acq: Acquisition, tab: np.ndarray, old: np.ndarray,
             margin_px: float) -> np.ndarray:  # fmt: skip
    """``tab`` (tablet px) inside the display and ``margin_px`` inside every picture; a
    landmark that would leave a picture stays where it was (``old``)."""
    w, h = truth.display_px
    tab = np.clip(np.round(tab), [0.0, 0.0], [w - 1.0, h - 1.0])  # the display's whole px
    iw, ih = truth.image_size_px
    inside = np.ones(len(tab), dtype=bool)
    for p, a in acq.capture_poses:
        uv, z = truth.at_capture(p, a).project(tab)
        inside &= ((uv >= margin_px).all(axis=1) & (uv[:, 0] <= iw - 1 - margin_px)
                   & (uv[:, 1] <= ih - 1 - margin_px) & (z > 0))  # fmt: skip
    return np.where(inside[:, None], tab, old)


def _row_map(obs) -> tuple[np.ndarray, np.ndarray]:
    """Each observation row's capture and landmark (one touch per landmark, in order)."""
    if obs.capture_index is None:
        n = obs.n_landmarks
        return np.zeros(n, dtype=int), np.arange(n)
    return np.asarray(obs.capture_index), np.asarray(obs.touch_index)


def _reachable(truth: TwinTruth, acq: Acquisition, pos, turn, *, reach_mm, turn_deg,
               margin_px) -> tuple:  # fmt: skip
    """The pictures after the first moved to ``pos`` (mm) and ``turn`` (deg), within reach of
    the first and seeing every landmark ``margin_px`` inside; one that would not stays."""
    first = acq.capture_poses[0]
    p0, a0 = np.asarray(first[0]), float(first[1])
    side, up = reach_mm
    poses = [first]
    for (old_p, old_a), p, a in zip(acq.capture_poses[1:], pos, turn, strict=True):
        p = np.concatenate([np.clip(p[:2], p0[:2] - side, p0[:2] + side),
                            np.clip(p[2:], p0[2], p0[2] + up)])  # fmt: skip
        a = float(np.clip(a, a0 - turn_deg, a0 + turn_deg))
        uv, z = truth.at_capture(p, a).project(acq.tablet_px)
        iw, ih = truth.image_size_px
        sees = ((uv >= margin_px).all() and (uv[:, 0] <= iw - 1 - margin_px).all()
                and (uv[:, 1] <= ih - 1 - margin_px).all() and (z > 0).all())  # fmt: skip
        poses.append((p, a) if sees else (old_p, old_a))
    return tuple(poses)


def _traced_observations(truth: TwinTruth, rows, obs, design: _Design):
    """``obs`` (the noise-free observations of an acquisition; ``rows``: :func:`_row_map`'s)
    with its rows' image points, depths, tablet points, hand positions and angles and capture
    poses recomputed from ``design`` in JAX, so that gradients flow."""
    from .. import geometry as geo
    from ._synthetic import tablet_to_camera

    mm = truth.mm_per_tablet_px
    model, rig = truth.htm(), truth.rig()
    cap_of_row, landmark = rows
    uv = jnp.zeros((len(cap_of_row), 2))
    depth = jnp.zeros(len(cap_of_row))
    tablet_mm = design.tablet_px * mm
    for c in range(design.capture_angle_deg.shape[0]):
        sel = np.flatnonzero(cap_of_row == c)
        rig_c = rig if obs.capture_index is None else Rig(
            rig.fx_px, rig.fy_px, rig.cx_px, rig.cy_px, design.capture_position_mm[c],
            rig.angle_zero_deg, rig.angle_sign, design.capture_angle_deg[c])  # fmt: skip
        pc = tablet_to_camera(model, rig_c, tablet_mm[landmark[sel]],
                              tablet_height_mm=truth.tablet_height_mm,
                              camera_z_mm=truth.camera_z_mm)  # fmt: skip
        u, d = geo.project(pc, rig.fx_px, rig.fy_px, rig.cx_px, rig.cy_px)
        uv, depth = uv.at[sel].set(u), depth.at[sel].set(d)
    touched = model.tablet_to_base(tablet_mm[landmark])[:, :2]
    angle = design.hand_angle_deg[landmark]
    hand = touched - model.pen_offset(rig.phi_deg(angle))[:, :2]
    obs = eqx.tree_at(
        lambda o: (o.image_px, o.depth_mm, o.tablet_mm, o.hand_xy_mm, o.hand_angle_deg),
        obs, (uv, depth, tablet_mm[landmark], hand, angle),
    )  # fmt: skip
    if obs.capture_index is None:
        return obs
    return eqx.tree_at(lambda o: (o.capture_position_mm, o.capture_hand_angle_deg), obs,
                       (design.capture_position_mm[cap_of_row],
                        design.capture_angle_deg[cap_of_row]))  # fmt: skip
