"""Fits the data cannot tell from a result's: what each is, how far its hand commands are from
the result's elsewhere, and what would tell them apart.

The candidates, each refined by LM from where it is built and then judged by how much worse
it fits under the noise model (a −2 log-likelihood within :data:`SEPARATE_CHI2`, with at least
the preset's noise, is a fit the data cannot exclude):

* **the tablet's sign twin**: both tablet tilts flipped mirror the tablet through its plane
  (x-y sees only their cosines); the hand command never reads the tablet, so it costs nothing;
* **the mirror camera mount**: one picture of a plane, compared in x-y only, is explained as
  well by the camera mirrored through the landmarks' plane and then through a horizontal
  plane: a proper rotation ``M`` that keeps every point of the plane's x-y, so every view's
  ``x_bi`` keeps its x-y and the fit its F. Points off that plane, or seen from another
  height or hand angle, move: commands from there differ;
* **directions the data do not determine** (the DH model's θc1 + γc): exact, continuous;
* **weak directions** (one picture at one depth: a camera shift against a tilt): the far end
  of the valley, walked on its profile as far as the data cannot exclude (``Ambiguity.edge``).

Commands are compared for the calibration's own views and for the same points seen from a
pose :data:`ELSEWHERE_RISE_MM` higher with the hand turned by :data:`ELSEWHERE_TURN_DEG`.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import geometry as geo
from .._jax import fast_compile
from ..calibration import Ambiguity, FittedStage, StageDiagnostics, polish
from ..data import Observations
from ..models import AbstractModel, Targets, hand_command
from ..optim import Box
from ..problem import (
    NULL_RATIO,
    AbstractObjective,
    NoiseModel,
    SquaresBlock,
    data_objective,
    errors_of,
    fitness,
    noise_objective,
    put,
    whitened_jacobian,
)

#: A fit whose −2 log-likelihood is within this of the result's is one the data cannot
#: exclude (about 2 σ for one parameter).
SEPARATE_CHI2 = 4.0
#: Where commands are compared besides the calibration's own views.
ELSEWHERE_RISE_MM = 60.0
ELSEWHERE_TURN_DEG = 30.0
#: An alternative whose parameters all lie within this fraction of their ranges of the fit's
#: is the fit itself.
SAME_FRACTION = 1e-3
ELSEWHERE = (f"the same points seen from a pose {ELSEWHERE_RISE_MM:g} mm higher with the hand "
             f"turned {ELSEWHERE_TURN_DEG:g} deg")  # fmt: skip
SEPARATE_MIRROR = ("a second picture from another height (e.g. 40 mm higher) with the hand "
                   "turned, or the hand's heights at the touches (hand_z)")  # fmt: skip
SEPARATE_TWIN = ("the hand's heights at the touches (hand_z), which pin the tablet's tilt; "
                 "hand commands do not depend on it")  # fmt: skip
#: How far a weak direction's valley is walked, in steps of its quadratic's reach.
VALLEY_REACH = 128.0
#: The half-width of the box that holds a coordinate while the valley is walked.
HELD = 1e-9
SEPARATE_WEAK = ("pictures from other heights and hand angles (handeye-jax plan adds them), "
                 "or landmarks at other depths")  # fmt: skip


@dataclasses.dataclass(frozen=True)
class _Context:
    """What every candidate is judged with: the stage's objective (as fitted) and a noise
    objective for the −2 log-likelihood, its free parameters and box, and the data."""

    objective: AbstractObjective
    chi2_objective: AbstractObjective
    space: object
    obs: Observations
    x: np.ndarray


def _chi2(ctx: _Context, x) -> float:
    r = np.asarray(whitened_jacobian(ctx.chi2_objective, jnp.asarray(x))[0])
    return float(np.sum(r**2))  # in NumPy: JAX would compile the sum for each shape


def _F(ctx: _Context, x) -> float:
    return float(_paper_F(data_objective(ctx.objective), jnp.asarray(x)))


@fast_compile
def _paper_F(objective, x):
    return fitness(errors_of(objective, x))[0]


def _floored(noise: NoiseModel) -> NoiseModel:
    """``noise`` with at least its preset's variances (noise-free data would tell apart fits
    no real rig can)."""
    depth = None if noise.depth_scale is None else max(noise.depth_scale, 1.0)
    return dataclasses.replace(noise, view_scale=max(noise.view_scale, 1.0), depth_scale=depth,
                               touch_scale=max(noise.touch_scale, 1.0))  # fmt: skip


def ambiguities(stage: FittedStage, diag: StageDiagnostics, noise: NoiseModel,
                obs: Observations) -> tuple[Ambiguity, ...]:  # fmt: skip
    """The fits stage 1's data cannot tell from the result's (see the module)."""
    space = stage.space
    data = data_objective(stage.objective)
    model = put(space.template, space.free, jnp.asarray(stage.x))
    chi2_objective = noise_objective(data, _floored(noise), model)
    ctx = _Context(stage.objective, chi2_objective, space, obs, np.asarray(stage.x, float))
    found = []
    twin = _sign_twin(ctx)
    if twin is not None:
        found.append(twin)
    mirror = _mirror_mount(ctx, model)
    if mirror is not None:
        found.append(mirror)
    for w in diag.weak_directions:
        found.append(_along(ctx, w))
    return tuple(a for a in found if a is not None)


def _judged(ctx: _Context, kind: str, x_alt: np.ndarray, separate_by: str,
            refine: bool = True) -> Ambiguity | None:  # fmt: skip
    """The alternative at ``x_alt`` (refined by LM when ``refine``), if it is not the fit
    itself and the data cannot exclude it."""
    space = ctx.space
    if refine:
        x_alt = polish(ctx.objective, space.box, x_alt)
    width = space.upper - space.lower
    if np.all(np.abs(x_alt - ctx.x) <= SAME_FRACTION * width):
        return None
    d_chi2 = _chi2(ctx, x_alt) - _chi2(ctx, ctx.x)
    if not d_chi2 < SEPARATE_CHI2:
        return None
    here, elsewhere = _command_shift(ctx, x_alt)
    differs = {n: float(x_alt[i] - ctx.x[i]) for i, n in enumerate(space.free)
               if abs(x_alt[i] - ctx.x[i]) > SAME_FRACTION * width[i]}  # fmt: skip
    return Ambiguity(kind=kind, differs=differs, delta_F_mm=_F(ctx, x_alt) - _F(ctx, ctx.x),
                     here_mm=here, elsewhere_mm=elsewhere, elsewhere=ELSEWHERE,
                     separate_by=separate_by, delta_chi2=float(d_chi2))  # fmt: skip


def _sign_twin(ctx: _Context) -> Ambiguity | None:
    cls = type(ctx.space.template)
    names = [n for n in cls.sign_twin if n in ctx.space.free]
    if not names or len(names) != len(cls.sign_twin):
        return None
    idx = [ctx.space.free.index(n) for n in names]
    x_alt = ctx.x.copy()
    x_alt[idx] *= -1.0
    x_alt = np.clip(x_alt, ctx.space.lower, ctx.space.upper)
    width = ctx.space.upper - ctx.space.lower
    if np.all(np.abs(x_alt - ctx.x) <= SAME_FRACTION * width) and _flip_is_exact(ctx, idx):
        # The fit sits where the twins meet (both tilts ≈ 0): the objective is even in the
        # tilts there, so their size and sign are not what its curvature says.
        return Ambiguity(kind="tablet sign twin, at its fold (both tilts 0, where the two "
                         "fits meet)", differs={n: 0.0 for n in names}, delta_F_mm=0.0,
                         here_mm=0.0, elsewhere_mm=(0.0, 0.0), elsewhere=ELSEWHERE,
                         separate_by=SEPARATE_TWIN, delta_chi2=0.0, fold=True)  # fmt: skip
    return _judged(ctx, "tablet sign twin", x_alt, SEPARATE_TWIN)


#: The tilts' probe, deg: the flip is exact for these data when it leaves −2 log L unchanged.
FLIP_PROBE_DEG = 1.0


def _flip_is_exact(ctx: _Context, idx: list[int]) -> bool:
    """Whether flipping the tilts' signs leaves −2 log L unchanged away from the fold (the
    data see the tilts through their cosines only, no hand heights)."""
    up, down = ctx.x.copy(), ctx.x.copy()
    up[idx], down[idx] = FLIP_PROBE_DEG, -FLIP_PROBE_DEG
    a, b = _chi2(ctx, up), _chi2(ctx, down)
    return abs(a - b) <= 1e-9 * max(abs(a), abs(b), 1.0)


def _along(ctx: _Context, w) -> Ambiguity | None:
    """A weak or undetermined direction, as far along as the data cannot exclude (an
    undetermined one: one unit of its largest component)."""
    step = np.array([w.step.get(n, 0.0) for n in ctx.space.free])
    J = np.asarray(whitened_jacobian(ctx.chi2_objective, jnp.asarray(ctx.x))[1])
    curvature = float(np.sum((J @ step) ** 2))
    if w.relative_singular_value <= NULL_RATIO or curvature <= 0:
        kind, scale = f"{' + '.join(w.params)}: only a combination is determined", 1.0
        return _judged(ctx, w.determined or kind, ctx.x + step,
                       "nothing: commands do not depend on it", refine=False)  # fmt: skip
    scale = float(np.sqrt(SEPARATE_CHI2 / curvature))
    x_alt = _valley_end(ctx, step, scale)
    if x_alt is None:  # the valley is steeper than its quadratic: the linear end
        x_alt = np.clip(ctx.x + 0.999 * scale * step, ctx.space.lower, ctx.space.upper)
    found = _judged(ctx, f"{' and '.join(w.params)} trade off", x_alt, SEPARATE_WEAK,
                    refine=False)  # fmt: skip
    return None if found is None else dataclasses.replace(found, edge=True)


def _valley_end(ctx: _Context, step: np.ndarray, scale: float) -> np.ndarray | None:
    """The farthest point along a weak direction that the data cannot exclude, walked on the
    valley's profile: the direction's largest component is held and the others refitted by LM,
    starting at the quadratic's end (``scale`` steps) and doubling out to
    :data:`VALLEY_REACH` of it on each side, while −2 log L stays within
    :data:`SEPARATE_CHI2` of the result's. ``None`` if even the first point is excluded.

    One picture's valleys are far flatter than their quadratic (on the one-capture coverage
    twins the walk reaches a median 16 times its reach: benchmarks/RESULTS.md), so the
    quadratic's end would understate what the data allow."""
    i = int(np.argmax(np.abs(step)))
    chi2_0 = _chi2(ctx, ctx.x)
    end, reach = None, 0.0
    for sign in (1.0, -1.0):
        t, last = 1.0, None
        while t <= VALLEY_REACH:
            start = np.clip(ctx.x + sign * t * scale * step, ctx.space.lower, ctx.space.upper)
            if last is not None and np.array_equal(start, last):
                break  # the box stops the walk: LM from the same start ends where it did
            last = start
            lower, upper = ctx.space.lower.copy(), ctx.space.upper.copy()
            lower[i], upper[i] = start[i] - HELD, start[i] + HELD
            x = polish(ctx.objective, Box(lower, upper), start)
            if not _chi2(ctx, x) - chi2_0 < SEPARATE_CHI2:
                break
            if t > reach:
                end, reach = x, t
            t *= 2.0
    return end


# -- the mirror camera mount -------------------------------------------------------------------


class _MountTarget(AbstractObjective):
    """The camera-mount parameters that give a target rotation and x-y translation."""

    template: AbstractModel
    free: tuple[str, ...] = eqx.field(static=True)
    R: jax.Array
    t: jax.Array

    def blocks(self, theta):
        R, t = put(self.template, self.free, theta).camera_mount()
        # Rotation entries weighed as 100 mm lever arms: mm and deg then compare.
        return {"mount": SquaresBlock(jnp.concatenate([100.0 * (R - self.R).reshape(-1),
                                                       t[:2] - self.t[:2]]))}  # fmt: skip

    def on_landmarks(self, idx):
        return self


def _first_capture(obs: Observations) -> tuple[np.ndarray, tuple]:
    """The rows of the first capture and its pose (hand position mm, φc deg)."""
    if obs.capture_position_mm is None:
        rows = np.arange(obs.n_landmarks)
        return rows, (np.asarray(obs.rig.capture_position_mm, float),
                      float(obs.rig.capture_phi_deg()))  # fmt: skip
    rows = np.flatnonzero(np.asarray(obs.capture_index) == int(np.asarray(obs.capture_index)[0]))
    return rows, (np.asarray(obs.capture_position_mm)[rows[0]],
                  float(np.asarray(obs.capture_phi_deg())[rows[0]]))  # fmt: skip


@fast_compile  # one program, not some forty eager operations compiled one by one
def _image_to_base(model: AbstractModel, image_px, depth_mm, rig, position, phi):
    return model.image_to_base(image_px, depth_mm, rig, position, phi)


@fast_compile
def _hand_and_mount(model: AbstractModel, phi):
    """The hand's rotation in the base at ``phi`` (deg), and the camera mount."""
    R_hc, t_hc = model.camera_mount()
    return geo.matmul3(geo.R_base_hand_down(), geo.rot_z(phi)), R_hc, t_hc


def _mirror_mount(ctx: _Context, model: AbstractModel) -> Ambiguity | None:
    """The camera mirrored through the first capture's landmark plane and a horizontal plane
    (see the module), refined by LM; ``None`` if the data exclude it or it is the fit."""
    cls = type(ctx.space.template)
    camera = [n for n in cls.groups.get("camera", ()) if n in ctx.space.free]
    if len(camera) < len(cls.groups.get("camera", ())):
        return None
    rows, (position, phi) = _first_capture(ctx.obs)
    obs = ctx.obs
    # The rows taken in NumPy: JAX's indexing would compile a program per shape.
    pos = None if obs.capture_position_mm is None else np.asarray(obs.capture_position_mm)[rows]
    phis = None if obs.capture_position_mm is None else np.asarray(obs.capture_phi_deg())[rows]
    x_bi = np.asarray(
        _image_to_base(
            model,
            np.asarray(obs.image_px)[rows],
            np.asarray(obs.depth_mm)[rows],
            obs.rig,
            pos,
            phis,
        )
    )
    if len(x_bi) < 3:
        return None
    c0 = x_bi.mean(axis=0)
    n = np.linalg.svd(x_bi - c0)[2][-1]
    n = n if n[2] >= 0 else -n
    D = np.diag([1.0, 1.0, -1.0])
    M = D @ (np.eye(3) - 2.0 * np.outer(n, n))
    R_bh, R_hc, t_hc = (np.asarray(a) for a in _hand_and_mount(model, jnp.asarray(phi)))
    v = R_bh @ t_hc + position
    v_mirror = D @ (v - 2.0 * n * (n @ (v - c0)))
    v_mirror[2] = position[2]  # the horizontal plane's height keeps the camera's z on the hand
    R_target = R_bh.T @ M @ R_bh @ R_hc
    t_target = R_bh.T @ (v_mirror - position)
    idx = [ctx.space.free.index(p) for p in camera]
    target = _MountTarget(model, tuple(camera), jnp.asarray(R_target), jnp.asarray(t_target))
    lo, hi = ctx.space.lower[idx], ctx.space.upper[idx]
    fit = _solve_mount(target, Box(lo, hi), ctx.x[idx])
    x_alt = ctx.x.copy()
    x_alt[idx] = np.clip(fit, lo, hi)
    return _judged(ctx, "mirror camera mount", x_alt, SEPARATE_MIRROR)


def _solve_mount(target: _MountTarget, box: Box, x0: np.ndarray) -> np.ndarray:
    return polish(target, box, x0)


# -- what the commands do ----------------------------------------------------------------------


def _command_shift(ctx: _Context, x_alt: np.ndarray) -> tuple[float, tuple[float, float]]:
    """The largest change of the hand commands (eq. 8) for the calibration's views, and the
    mean and largest for the first capture's landmarks seen from :data:`ELSEWHERE`, mm."""
    space, obs = ctx.space, ctx.obs
    a = put(space.template, space.free, jnp.asarray(ctx.x))
    b = put(space.template, space.free, jnp.asarray(x_alt))
    rows, (position, phi) = _first_capture(obs)
    here, there = _shifts(a, b, obs, jnp.asarray(rows), jnp.asarray(position), jnp.asarray(phi))
    there = np.asarray(there)
    return float(here), (float(there.mean()), float(there.max()))


@fast_compile
def _shifts(a: AbstractModel, b: AbstractModel, obs: Observations, rows, position, phi):
    angles = jnp.linspace(jnp.min(obs.hand_angle_deg), jnp.max(obs.hand_angle_deg), 5)
    rig = obs.rig
    n = obs.n_landmarks
    pos = rig.capture_position_mm if obs.capture_position_mm is None else obs.capture_position_mm
    cap = (jnp.full(n, rig.capture_phi_deg()) if obs.capture_position_mm is None
           else obs.capture_phi_deg())  # fmt: skip
    theta_c = (cap - rig.angle_zero_deg) / rig.angle_sign  # the controller's angle at each view

    def commands(model, uv, depth, where, turn, angle):
        k = uv.shape[0]
        targets = Targets(uv, depth, jnp.full(k, angle), jnp.broadcast_to(where, (k, 3)),
                          jnp.broadcast_to(turn, (k,)))
        return hand_command(model, rig, targets)

    def here(angle):
        ca = commands(a, obs.image_px, obs.depth_mm, pos, theta_c, angle)
        cb = commands(b, obs.image_px, obs.depth_mm, pos, theta_c, angle)
        return jnp.max(jnp.linalg.norm(ca - cb, axis=1))

    # The first capture's points (as model a puts them) seen from the other pose by model a.
    x_bi = a.image_to_base(obs.image_px[rows], obs.depth_mm[rows], rig,
                           jnp.broadcast_to(position, (rows.shape[0], 3)),
                           jnp.broadcast_to(phi, rows.shape))  # fmt: skip
    new_position = position + jnp.array([0.0, 0.0, ELSEWHERE_RISE_MM])
    new_phi = phi + ELSEWHERE_TURN_DEG
    R_bh = geo.matmul3(geo.R_base_hand_down(), geo.rot_z(new_phi))
    R_hc, t_hc = a.camera_mount()
    p_cam = ((x_bi - new_position) @ R_bh - t_hc) @ R_hc
    uv, depth = geo.project(p_cam, rig.fx_px, rig.fy_px, rig.cx_px, rig.cy_px)
    turn = (new_phi - rig.angle_zero_deg) / rig.angle_sign

    def there(angle):
        ca = commands(a, uv, depth, new_position, turn, angle)
        cb = commands(b, uv, depth, new_position, turn, angle)
        return jnp.linalg.norm(ca - cb, axis=1)

    return jnp.max(jax.vmap(here)(angles)), jax.vmap(there)(angles).reshape(-1)
