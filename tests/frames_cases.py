"""Random calibrations and points for the predictor and export tests (hypothesis strategies).

A case is a model's parameters drawn in its default search ranges, a stage-2 correction in its
ranges, a rig (intrinsics, capture position, hand-angle convention) and centres: everything a
result holds. The reference is the JAX path, :func:`handeye_jax.data._points.hand_command`, jitted.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np

from handeye_jax import (
    AffinePair,
    CalibrationResult,
    Rig,
    Settings,
    StageResult,
    Targets,
    compute_frames,
    get_model,
    hand_command,
)

ROOT = Path(__file__).resolve().parents[1]
N_POINTS = 6  # one shape, so the jitted reference compiles once per model and stage
TOL_MM = 1e-9


@dataclass(frozen=True)
class Case:
    model: str
    params: dict
    affine: dict
    camera: tuple  # fx, fy, cx, cy px
    capture_mm: tuple
    zero_deg: float
    sign: int
    centres_mm: tuple

    def fitted(self):
        with jax.enable_x64(True):
            model = get_model(self.model).from_dict(self.params)
            rig = Rig(*self.camera, np.array(self.capture_mm), self.zero_deg, self.sign)
            return model, rig, AffinePair.from_dict(self.affine)

    def frames(self, **known):
        model, rig, correction = self.fitted()
        return compute_frames(model, rig, correction, np.array(self.centres_mm), known=known)

    def result(self) -> CalibrationResult:
        """A result holding this case, as ``calibrate`` would write it (without the fit's
        records)."""

        def stage(params):
            return StageResult(F=0.0, f1=0.0, f2=0.0, params=dict(params))

        fx, fy, cx, cy = self.camera
        with jax.enable_x64(True):
            rig = Rig(fx, fy, cx, cy, list(self.capture_mm), self.zero_deg, self.sign)
            model = get_model(self.model).from_dict(self.params)
            correction = AffinePair.from_dict(self.affine)
        return CalibrationResult(
            model=model, correction=correction, rig=rig,
            centres_mm=[list(c) for c in self.centres_mm], centre_index=0,
            stage1=stage(self.params), stage2=stage(self.affine),
            settings=Settings(model=self.model, seed=0), dataset_name="drawn",
        )  # fmt: skip


def _in(lo, hi):
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


@st.composite
def cases(draw, models=("htm", "dh")) -> Case:
    name = draw(st.sampled_from(models))
    ranges = get_model(name).default_ranges
    params = {k: draw(_in(*ranges[k])) for k in get_model(name).param_names}
    affine = {k: draw(_in(*AffinePair.default_ranges[k])) for k in AffinePair.param_names}
    camera = (draw(_in(300, 1500)), draw(_in(300, 1500)), draw(_in(200, 800)), draw(_in(150, 600)))
    capture = tuple(draw(_in(-600, 600)) for _ in range(3))
    zero = draw(st.one_of(st.sampled_from([0.0, 90.0, -90.0, 180.0]), _in(-360, 360)))
    sign = draw(st.sampled_from([1, -1]))
    centres = tuple(tuple(draw(_in(-600, 600)) for _ in range(2)) for _ in range(2))
    return Case(name, params, affine, camera, capture, zero, sign, centres)


@st.composite
def points(draw, n: int = N_POINTS):
    """``(image_px (n, 2), depth_mm (n,), hand_angle_deg (n,))``."""
    uv = np.array([[draw(_in(0, 1280)), draw(_in(0, 960))] for _ in range(n)])
    depth = np.array([draw(_in(50, 1500)) for _ in range(n)])
    angle = np.array([draw(_in(-360, 360)) for _ in range(n)])
    return uv, depth, angle


@jax.jit
def _jax_hand_command(model, rig, correction, centres, uv, depth, angle):
    # Both stages in one program: one compilation per model class.
    targets = Targets(uv, depth, angle)
    return (hand_command(model, rig, targets),
            hand_command(model, rig, targets, correction=correction, centres_mm=centres))


def jax_reference_of(model, rig, correction, centres_mm, uv, depth, angle, stage: int):
    """The JAX path's hand commands, mm, float64."""
    with jax.enable_x64(True):
        args = (
            jnp.asarray(centres_mm, float),
            *(jnp.asarray(a, float) for a in (uv, depth, angle)),
        )
        return np.asarray(_jax_hand_command(model, rig, correction, *args)[stage - 1])


def jax_reference(case: Case, uv, depth, angle, stage: int) -> np.ndarray:
    """The JAX path's hand commands for ``case``, mm, float64."""
    return jax_reference_of(*case.fitted(), case.centres_mm, uv, depth, angle, stage)


BLOCKER = textwrap.dedent(
    """
    import importlib.abc, json, sys
    BLOCKED = ("jax", "jaxlib", "equinox", "optimistix", "matplotlib", "cv2", "jaxtyping")

    class Block(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ModuleNotFoundError(f"No module named {name!r} (blocked)", name=name)

    sys.meta_path.insert(0, Block())
    """
)


def run_without_jax(code: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", BLOCKER + textwrap.dedent(code), *args],
        capture_output=True, text=True, timeout=120, cwd=ROOT,
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
    )  # fmt: skip
