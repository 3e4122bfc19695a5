"""The calibration result: the fitted model and correction, the data, and how they were found.

A result is self-contained: with the rig it was fitted on (intrinsics, capture pose, hand-angle
convention) it predicts hand commands without the dataset. Its file format,
``handeye-jax.result/1`` (JSON), is read and written by :func:`~handeye_jax.load_result` and
:func:`~handeye_jax.save_result`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core import InputError, Stages, bounded, each, length, spec
from .._jax import fast_compile, in_float64
from ..data import Dataset
from ..models import AbstractCorrection, AbstractModel, Rig, Targets, hand_command
from ..problem import (
    FIXED,
    FREE,
    Heights,
    NoiseFit,
    Prior,
    Stage1Objective,
    Stage2Objective,
    analyse_jacobian,
    chain_points,
    error_jacobian,
)
from ..robot import Frames
from ._payloads import (
    Convergence,
    Deployment,
    DESummary,
    Diagnostics,
    FitWarning,
    PolishSummary,
    PriorReport,
    Recalibration,
    Residual,
    SignTwin,
)
from ._ranges import SearchReport
from ._result_frames import compute_frames
from ._settings import Settings

#: The stage a result that records no choice deploys: every tool's default before the choice.
LEGACY_DEPLOY_STAGE = 2

#: Largest magnitude of a fitted parameter: the widest search range a dataset admits (DE and
#: the LM polish stay inside their range).
MAX_PARAM = 1e6


#: One program per shape of the targets (eager, each operation compiles on its own).
_hand_command = fast_compile(hand_command)


@dataclass(frozen=True)
class StageResult:
    """One stage's optimum, in numbers.

    Attributes:
        F, f1, f2: the data's fitness and its two terms, mm (the paper's F, whatever loss or
            prior the fit used).
        params: every parameter's value, name → value (mm, deg or 1, as the model's
            ``param_units`` say), free or not.
        residuals_mm: per landmark, the error vectors and lengths of both terms, mm.
        de: what DE did (names searched, generations, evaluations, converged, its best value).
        polish: what LM did (accepted, values before and after, steps, restarts, refits, and
            ``found_by``: which search found the optimum).
        convergence: best and median F after each DE generation, mm.
        status: each parameter's role: ``"free"``, ``"prior"`` (free, with a prior) or
            ``"fixed"`` (held at the template's value).
        fixed_source: where each fixed parameter's value came from (a result file).
        prior: the prior (its source, mean, precision, data scale) and each of its parameters'
            pull, or ``None``.

    Its JSON form (``stage1``, ``stage2`` of a result file) is its fields'.
        prior_F: the prior block's value at the optimum, mm (the MAP objective is ``F`` plus
            it), or ``None``.
        noise: the noise model of the maximum-likelihood fit (``ml`` loss), its scales
            estimated from the residuals, and their redundancies; ``None`` for another loss.
    """

    F: float = spec(check=length)
    f1: float = spec(check=length)
    f2: float = spec(check=length)
    params: dict[str, float] = spec(check=each(bounded(MAX_PARAM)))
    residuals_mm: tuple[Residual, ...] = ()
    de: DESummary = field(default_factory=DESummary)
    polish: PolishSummary = field(default_factory=PolishSummary)
    convergence: Convergence = field(default_factory=Convergence)
    status: dict[str, Literal["free", "prior", "fixed"]] = field(default_factory=dict)
    fixed_source: dict[str, str] = spec(omit="empty", default_factory=dict)
    prior: PriorReport | None = spec(omit="none", default=None)
    prior_F: float | None = spec(check=length, omit="none", default=None)
    noise: NoiseFit | None = spec(omit="none", default=None)

    def __post_init__(self):
        if not self.status:  # every parameter free: the paper's fit, and every older result
            object.__setattr__(self, "status", dict.fromkeys(self.params, FREE))

    def free(self) -> tuple[str, ...]:
        """The parameters the fit moved (free or with a prior), in ``params`` order."""
        return tuple(n for n in self.params if self.status.get(n, "free") != FIXED)


@dataclass(frozen=True, eq=False)
class CalibrationResult:
    """Everything a calibration produced, and what is needed to use it.

    Attributes:
        model: the fitted stage-1 model (a JAX pytree).
        correction: the fitted stage-2 correction (a JAX pytree).
        rig: the rig it was fitted on (intrinsics, capture pose, hand-angle convention).
        centres_mm: the correction's centres of rotation (rows: A1, A2), mm, base frame.
        centre_index: the landmark whose mapped points are the centres.
        stage1, stage2: each stage's numbers and which parameters were free, fixed or prior.
        settings: how it was calibrated.
        data: the dataset it was fitted on (``None`` for results that did not record it).
        dataset_name: the dataset's name.
        timings_s: seconds of each step.
        sign_twin: the sign twin found and the F of its mirror, or ``None``.
        warnings: what the user should know, one line each.
        diagnostics: what the result can and cannot tell (:func:`~handeye_jax.diagnose`), or
            ``None``.
        recalibration: the previous result it started from, what was refitted, and how the
            others entered, or ``None``.
        fits: the stages' fits in memory (objectives, final DE populations), for the
            diagnostics of a result just computed; not written to the file.
        heights: when the touches recorded the hand's heights, what they determine (the
            ``z_p − z_c`` a height command needs, and how well); else ``None``.
        search: where each stage searched (the preset, the ranges and where they came from,
            the closed-form estimate), or ``None`` (older results).
        deploy: which stage to deploy and the evidence for it (:func:`~handeye_jax.diagnose`
            chooses by leave-one-out; without it, stage 1); ``None`` in results written
            before the choice was recorded (:attr:`deploy_stage` is then 2, as it was).
    """

    model: AbstractModel
    correction: AbstractCorrection
    rig: Rig
    centres_mm: np.ndarray
    centre_index: int
    stage1: StageResult
    stage2: StageResult
    settings: Settings
    data: Dataset | None = None
    dataset_name: str = ""
    timings_s: dict[str, float] = field(default_factory=dict)
    sign_twin: SignTwin | None = None
    warnings: tuple[FitWarning, ...] = ()
    diagnostics: Diagnostics | None = None
    recalibration: Recalibration | None = None
    fits: Stages[Any] | None = field(default=None, repr=False)
    heights: Heights | None = None
    search: SearchReport | None = None
    deploy: Deployment | None = None

    def __post_init__(self):
        object.__setattr__(self, "centres_mm", np.asarray(self.centres_mm, dtype=float))
        object.__setattr__(self, "warnings", tuple(self.warnings))

    @property
    def model_name(self) -> str:
        """The stage-1 model's name (``"htm"``, ``"dh"``…)."""
        return type(self.model).name

    @property
    def seed(self) -> int:
        return self.settings.seed

    @property
    def deploy_stage(self) -> int:
        """The stage :meth:`predict`, the :class:`~handeye_jax.Predictor` and every export use
        by default: :attr:`deploy`'s, or 2 for a result that records none (written before
        the choice was made, when stage 2 was every tool's default)."""
        return LEGACY_DEPLOY_STAGE if self.deploy is None else int(self.deploy.stage)

    # -- use -----------------------------------------------------------------------------
    @in_float64
    def predict(
        self,
        image_px: Float[Array, "n 2"],
        depth_mm: Float[Array, " n"],
        hand_angle_deg: Float[Array, " n"],
        stage: int | None = None,
        capture_position_mm: Float[Array, "n 3"] | None = None,
        capture_hand_angle_deg: Float[Array, " n"] | None = None,
        axes: str = "xy",
    ) -> np.ndarray:
        """Hand commands ``(x, y)`` in mm for image points, eq. (25) (stage 2) or (8) (stage 1).

        Args:
            image_px, depth_mm: each target in its picture, px, and its depth, mm: any point
                seen at any depth, on the tablet or not.
            hand_angle_deg: the hand angle θh to touch each with, deg.
            stage: 2 (with the affine correction, a planar map) or 1; default: the stage to
                deploy (:attr:`deploy_stage`).
            capture_position_mm: the hand position each picture was taken from, mm, ``(3,)``
                or ``(n, 3)``; default: the calibration's first capture.
            capture_hand_angle_deg: the hand angle θc then, deg, scalar or ``(n,)``; default:
                the first capture's. ``R_base_hand = Ry(-180)·Rz(zero + sign·θc)``.
            axes: ``"xy"``, or ``"xyz"`` for ``(x, y, z)`` when the touches recorded the
                hand's heights (:attr:`heights`).
        """
        stage = self.deploy_stage if stage is None else stage
        if stage not in (1, 2):
            raise ValueError(f"stage must be 1 or 2 (got {stage})")
        if axes not in ("xy", "xyz"):
            raise ValueError(f"axes must be 'xy' or 'xyz' (got {axes!r})")
        if axes == "xyz" and not self.heights:
            raise ValueError("axes must be 'xy': the touches recorded no hand height, so the "
                             "calibration does not determine z_pen − z_camera")  # fmt: skip
        f = lambda a: None if a is None else jnp.asarray(a, dtype=float)  # noqa: E731
        if self.distortion is not None:  # the chain back-projects through a pinhole
            image_px = self.data.camera.undistort(image_px)
        targets = Targets(f(image_px), f(depth_mm), f(hand_angle_deg), f(capture_position_mm),
                          f(capture_hand_angle_deg))  # fmt: skip
        out = _hand_command(
            self.model,
            self.rig,
            targets,
            correction=self.correction if stage == 2 else None,
            centres_mm=jnp.asarray(self.centres_mm, dtype=float),
            pen_minus_camera_mm=f(self.heights.pen_minus_camera_mm) if axes == "xyz" else None,
        )  # fmt: skip
        return np.asarray(out)

    def frames(self) -> Frames:
        """The fitted frames as plain numbers (NumPy), from the parameters and the rig."""
        z = None if self.heights is None else self.heights.pen_minus_camera_mm
        return compute_frames(self.model, self.rig, self.correction, self.centres_mm,
                              pen_minus_camera_z_mm=z, deploy_stage=self.deploy_stage,
                              distortion=self.distortion)  # fmt: skip

    @property
    def distortion(self) -> tuple[float, float, float, float, float] | None:
        """The lens distortion of the dataset's camera (plumb_bob k1 k2 p1 p2 k3), or ``None``."""
        return None if self.data is None else self.data.camera.distortion

    @in_float64
    def posterior(self, stage: str = "stage1", source: str | None = None) -> Prior:
        """The fit's Gaussian posterior of a stage's free parameters (Gauss–Newton at the
        optimum, its prior included): what a recalibration takes as its prior.

        Taken from the diagnostics' ``precision`` when present, else computed from the
        result's data.
        """
        s: StageResult = getattr(self, stage)
        free = s.free()
        diag = None if self.diagnostics is None else getattr(self.diagnostics, stage)
        P = sigma = None
        if diag is not None and np.shape(diag.precision) == (len(free), len(free)):
            if not diag.free or tuple(diag.free) == tuple(free):
                P, sigma = diag.precision, diag.sigma_mm
        if P is None:
            P, sigma = self._posterior_precision(stage, free)
        untested: tuple[str, ...] = ()
        alternatives: tuple[dict[str, float], ...] = ()
        if self.diagnostics is not None and stage == "stage1":
            untested, alternatives = self._untested(free)
        return Prior(free, [s.params[n] for n in free], np.asarray(P, dtype=float),
                     source or f"previous result ({self.dataset_name})",
                     max(s.F, 1e-6) / 4.0, sigma if sigma else None, untested,
                     alternatives)  # fmt: skip

    def _untested(self, free) -> tuple[tuple[str, ...], tuple[dict[str, float], ...]]:
        """The stage-1 parameters a prior from this result does not test (in a weak direction,
        or at the sign twin's fold), and the alternative fits (a mirror mount, the sign twin)
        against which it tests those they move (files from before ``untested_params``: none,
        every weak parameter untested)."""
        d = self.diagnostics
        if d.untested_params is None:
            return tuple(n for n in d.weak_params if n in free), ()
        alternatives = [a for a in d.ambiguities if not (a.edge or a.fold)]
        never = {p for w in d.stage1.weak_directions for p in w.params} if d.stage1 else set()
        never |= {p for a in d.ambiguities if a.fold for p in a.differs}
        moved = {p for a in alternatives for p in a.differs}
        untested = tuple(n for n in d.untested_params
                         if n in free and (n in never or n not in moved))  # fmt: skip
        return untested, tuple(dict(a.differs) for a in alternatives)

    def _posterior_precision(self, stage: str, free: tuple[str, ...]) -> np.ndarray:
        if self.data is None:
            raise InputError(None, "data", "the result does not carry its data, so its "
                             "posterior cannot be computed; calibrate again")  # fmt: skip
        obs = self.data.observations()
        s: StageResult = getattr(self, stage)
        if stage == "stage1":
            objective = Stage1Objective(self.model, obs, free)
        else:
            points = chain_points(self.model, obs)
            objective = Stage2Objective(self.correction, points, self.centre_index, free)
        x = jnp.asarray([s.params[n] for n in free])
        e, J = (np.asarray(a) for a in error_jacobian(objective, x))
        P_prior = None
        if s.prior is not None:
            P_prior = np.zeros((len(free), len(free)))
            idx = [free.index(n) for n in s.prior.names]
            P_prior[np.ix_(idx, idx)] = np.asarray(s.prior.precision)
        out = analyse_jacobian(e, J, free, ["1"] * len(free), None, P_prior)
        return np.asarray(out.precision), out.sigma_mm
