"""Held-out touching error on a synthetic twin: the paper's Tables 9 and 12, done honestly.

For each held-out target (drawn at a tablet position and touched at a hand angle the
calibration never saw) the hand is sent to the command a calibration predicts from the
target's measured image point and depth; the pen lands where the twin's true chain puts it,
and the touching error is where it lands on the display minus the target, in mm and tablet px.
The oracle sends the hand with the true parameters and the same measured observations: what
a perfect stage 1 would achieve with these measurements; "oracle + stage 2" adds a stage-2
correction fitted on top of the true parameters, to show what stage 2 does to a perfect model.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from .._core import MAX_DEG, MAX_MM, MAX_PX, InputError
from .._jax import in_float64
from ..calibration import CalibrationResult, Settings, fit_correction, load_result
from ..data import Dataset, csv_number, load_dataset, read_points_csv
from ..models import AbstractModel, Targets, hand_command
from ._truth import TwinTruth, load_truth


@dataclass(frozen=True)
class Heldout:
    """Held-out targets: as measured (``u, v``, depth, hand angle) and where drawn.

    Attributes:
        image_px: measured image point of each target, px, ``(k, 2)``.
        depth_mm: measured depth, mm, ``(k,)``.
        hand_angle_deg: hand angle to touch it with, deg, ``(k,)``.
        tablet_px: where it is drawn on the display, tablet px, ``(k, 2)``.
        capture_position_mm, capture_angle_deg: the capture pose each target was seen from
            (mm ``(k, 3)``, deg ``(k,)``), a multi-capture twin's; else ``None``.
        true_mm: each target's true position, base frame, mm, ``(k, 3)``, or ``None``.
        above_mm: how far above the display each target stands, mm, ``(k,)``, or ``None``.
    """

    image_px: np.ndarray
    depth_mm: np.ndarray
    hand_angle_deg: np.ndarray
    tablet_px: np.ndarray
    capture_position_mm: np.ndarray | None = None
    capture_angle_deg: np.ndarray | None = None
    true_mm: np.ndarray | None = None
    above_mm: np.ndarray | None = None


#: The columns of a multi-capture twin's held-out targets beyond the single capture's.
_POINT_COLUMNS = {
    "capture_x": MAX_MM, "capture_y": MAX_MM, "capture_z": MAX_MM, "capture_angle": MAX_DEG,
    "true_x": MAX_MM, "true_y": MAX_MM, "true_z": MAX_MM, "above_mm": MAX_MM,
}  # fmt: skip


def load_heldout(path: str | Path) -> Heldout:
    """Read ``heldout.csv`` (``u,v,depth,hand_angle,tablet_x,tablet_y``, and a multi-capture
    twin's capture pose, true position and height columns); InputError if bad."""
    path = Path(path)
    header, rows, values = read_points_csv(path)

    def column(name: str, limit: float) -> np.ndarray:
        if name not in header:
            raise InputError(path, "header", f"missing column {name}")
        j = header.index(name)
        return np.array(
            [csv_number(path, f"line {i}.{name}", r[j], limit) for i, r in enumerate(rows, 2)]
        )

    tablet = np.column_stack([column(c, MAX_PX) for c in ("tablet_x", "tablet_y")])
    if "true_x" not in header:
        return Heldout(values[:, :2], values[:, 2], values[:, 3], tablet)
    c = {name: column(name, limit) for name, limit in _POINT_COLUMNS.items()}
    return Heldout(
        values[:, :2], values[:, 2], values[:, 3], tablet,
        capture_position_mm=np.column_stack([c["capture_x"], c["capture_y"], c["capture_z"]]),
        capture_angle_deg=c["capture_angle"],
        true_mm=np.column_stack([c["true_x"], c["true_y"], c["true_z"]]),
        above_mm=c["above_mm"],
    )  # fmt: skip


@in_float64
def landing_tablet_px(
    truth: TwinTruth, hand_xy_mm: Float[np.ndarray, "k 2"], hand_angle_deg: Float[np.ndarray, " k"]
) -> Float[np.ndarray, "k 2"]:
    """Where the pen lands on the display, tablet px, when the hand goes to ``hand_xy_mm``.

    The pen tip is at the hand plus the true pen offset (eqs. 6–7); it comes down on the
    display plane where the true tablet pose (eq. 11) puts that base-frame ``(x, y)``.
    """
    model: AbstractModel = truth.htm()
    offset = model.pen_offset(truth.rig().phi_deg(jnp.asarray(hand_angle_deg, dtype=float)))
    tip_xy = np.asarray(hand_xy_mm) + np.asarray(offset)[:, :2]
    R_base_tablet, t_base_tablet = (np.asarray(a) for a in model.tablet_pose())
    # Points of the display plane are R[:, :2]·q + t; solve the x-y rows for q (mm).
    q_mm = np.linalg.solve(R_base_tablet[:2, :2], (tip_xy - t_base_tablet[:2]).T).T
    return q_mm / truth.mm_per_tablet_px


@dataclass(frozen=True)
class TouchingError:
    """Touching error over the held-out targets.

    Attributes:
        label: what sent the hand (``"stage 1"``, ``"stage 2"``, ``"oracle"``).
        errors_px: landing minus target per target, tablet px, ``(k, 2)``.
        mm_per_px: the display's tablet px size, mm.
    """

    label: str
    errors_px: np.ndarray
    mm_per_px: float

    @property
    def lengths_px(self) -> np.ndarray:
        return np.linalg.norm(self.errors_px, axis=1)

    @property
    def mean_mm(self) -> float:
        return float(self.lengths_px.mean() * self.mm_per_px)

    @property
    def max_mm(self) -> float:
        return float(self.lengths_px.max() * self.mm_per_px)

    @property
    def mean_px(self) -> float:
        return float(self.lengths_px.mean())

    @property
    def max_px(self) -> float:
        return float(self.lengths_px.max())


@in_float64
def evaluate(
    result: CalibrationResult,
    truth: TwinTruth,
    heldout: Heldout,
    dataset: Dataset | None = None,
) -> list[TouchingError]:
    """Touching error of the result's stages and of the oracle.

    Rows, in order: ``stage 1`` and ``stage 2`` (the result, eqs. 8 and 25), ``oracle`` (the
    true parameters, eq. 8) and, when ``dataset`` is given, ``oracle + stage 2`` (the true
    parameters with a stage-2 correction fitted to ``dataset`` as the result's stage 2 was,
    :func:`oracle_settings`).

    Args:
        result: a calibration of the twin's dataset.
        truth: the twin's rig truth.
        heldout: the held-out targets as measured.
        dataset: the dataset the result was fitted to, for the oracle's stage 2.
    """
    image_px = jnp.asarray(heldout.image_px)
    depth_mm = jnp.asarray(heldout.depth_mm)
    angle_deg = jnp.asarray(heldout.hand_angle_deg)
    rows = []
    for label, stage in (("stage 1", 1), ("stage 2", 2)):
        rows.append((label, result.predict(image_px, depth_mm, angle_deg, stage)))
    model, rig = truth.htm(), truth.rig()
    ideal_px = jnp.asarray(truth.undistort(heldout.image_px))  # the truth knows its lens
    targets = Targets(ideal_px, depth_mm, angle_deg)
    rows.append(("oracle", hand_command(model, rig, targets)))
    if dataset is not None:
        correction, centres = fit_correction(dataset, model, oracle_settings(result))
        cmd = hand_command(model, rig, targets, correction=correction,
                           centres_mm=jnp.asarray(centres))
        rows.append(("oracle + stage 2", cmd))
    return [
        TouchingError(
            label,
            landing_tablet_px(truth, np.asarray(cmd), heldout.hand_angle_deg) - heldout.tablet_px,
            truth.mm_per_tablet_px,
        )
        for label, cmd in rows
    ]


@dataclass(frozen=True)
class PointErrors:
    """Errors of hand commands for held-out targets with known 3-D positions.

    Attributes:
        label: what sent the hand (``"stage 1"``, ``"stage 2"``, ``"oracle"``…).
        xy_mm: |command − true command| in x-y per target, mm (where the pen tip lands off
            the target, seen from above).
        z_mm: |command z − true z| per target, mm; ``None`` when the calibration determines
            no height.
        rise_mm: how far above the calibration's first capture each target's capture was, mm.
        above_mm: how far above the display each target stands, mm.
    """

    label: str
    xy_mm: np.ndarray
    z_mm: np.ndarray | None
    rise_mm: np.ndarray
    above_mm: np.ndarray

    def groups(self) -> list[tuple[float, float, np.ndarray]]:
        """``(rise mm, above mm, mask)`` of each group of targets, in order."""
        rise = np.round(self.rise_mm, 6)
        keys = sorted({(float(r), float(a)) for r, a in zip(rise, self.above_mm, strict=True)})
        return [(r, a, (rise == r) & (self.above_mm == a)) for r, a in keys]


@in_float64
def evaluate_points(
    result: CalibrationResult,
    truth: TwinTruth,
    heldout: Heldout,
    dataset: Dataset | None = None,
) -> list[PointErrors]:
    """x-y and z errors of the result's stages and of the oracle for held-out targets seen
    from their own capture poses (a multi-capture twin's ``heldout.csv``).

    The oracle sends the hand with the true parameters (and the true ``z_p − z_c``) from the
    same measurements; ``oracle + stage 2`` adds a stage-2 correction fitted to ``dataset``
    on top of them.
    """
    image_px = jnp.asarray(heldout.image_px)
    depth_mm = jnp.asarray(heldout.depth_mm)
    angle = jnp.asarray(heldout.hand_angle_deg)
    pose = dict(capture_position_mm=heldout.capture_position_mm,
                capture_hand_angle_deg=heldout.capture_angle_deg)  # fmt: skip
    axes = "xyz" if result.heights else "xy"
    rows = [(label, result.predict(image_px, depth_mm, angle, stage, axes=axes, **pose))
            for label, stage in (("stage 1", 1), ("stage 2", 2))]  # fmt: skip
    model, rig = truth.htm(), truth.rig()
    dz = jnp.asarray(truth.pen_z_mm - truth.camera_z_mm)
    ideal_px = jnp.asarray(truth.undistort(heldout.image_px))  # the truth knows its lens
    targets = Targets(ideal_px, depth_mm, angle, *(jnp.asarray(v) for v in pose.values()))
    rows.append(("oracle", hand_command(model, rig, targets, pen_minus_camera_mm=dz)))
    if dataset is not None:
        correction, centres = fit_correction(dataset, model, oracle_settings(result))
        rows.append(("oracle + stage 2", hand_command(
            model, rig, targets, correction=correction, centres_mm=jnp.asarray(centres),
            pen_minus_camera_mm=dz)))  # fmt: skip
    want = truth.true_command(heldout.true_mm, heldout.hand_angle_deg)
    rise = heldout.capture_position_mm[:, 2] - truth.capture_position_mm[2]
    out = []
    for label, cmd in rows:
        cmd = np.asarray(cmd)
        z = np.abs(cmd[:, 2] - want[:, 2]) if cmd.shape[1] == 3 else None
        out.append(PointErrors(label, np.linalg.norm(cmd[:, :2] - want[:, :2], axis=1), z,
                               rise, heldout.above_mm))  # fmt: skip
    return out


def format_point_errors(rows: list[PointErrors]) -> str:
    """A Markdown table of mean x-y (and z) errors by capture height and target height, mm."""
    lines = [
        f"held-out errors over {len(rows[0].xy_mm)} targets, mean mm (x-y: where the pen tip "
        "lands off the target seen from above; z: hand height)",
        "",
        "| capture above the first, mm | target above the display, mm | targets | "
        + " | ".join(f"{r.label} x-y" for r in rows) + " | "
        + " | ".join(f"{r.label} z" for r in rows if r.z_mm is not None) + " |",
        "|" + "---|" * (3 + len(rows) + sum(r.z_mm is not None for r in rows)),
    ]  # fmt: skip
    for rise, above, mask in rows[0].groups():
        xy = [f"{r.xy_mm[mask].mean():.3f}" for r in rows]
        z = [f"{r.z_mm[mask].mean():.3f}" for r in rows if r.z_mm is not None]
        lines.append(f"| {rise:.0f} | {above:.0f} | {int(mask.sum())} | " + " | ".join(xy)
                     + " | " + " | ".join(z) + " |")  # fmt: skip
    return "\n".join(lines).replace(" |  |", " |")


def oracle_settings(result: CalibrationResult) -> Settings:
    """How the oracle's stage 2 is fitted: as the result's stage 2 was (its seed and DE
    settings), but with at most the default population, generations and restarts.

    A result file records what its calibration ran, not what an evaluation may allocate: a
    file saying ``population = 10**9`` once made ``evaluate`` allocate 80 GB.
    """
    s, budget = result.settings, Settings()
    return dataclasses.replace(
        s, population=min(s.population, budget.population),
        generations=min(s.generations, budget.generations),
        restarts=min(s.restarts, budget.restarts),
    )  # fmt: skip


def evaluate_twin(
    result: CalibrationResult | str | Path, twin_dir: str | Path
) -> list[TouchingError] | list[PointErrors]:
    """:func:`evaluate` on a folder written by ``simulate``, with the oracle's stage 2
    (:func:`evaluate_points` for a multi-capture twin).

    Reads ``truth.json``, ``heldout.csv`` and ``dataset.toml`` from ``twin_dir``; ``result``
    is a result or its file. Raises :class:`InputError` unless the result was fitted on that
    ``dataset.toml`` (:func:`check_fitted_on`).
    """
    twin_dir = Path(twin_dir)
    result_path = None
    if not isinstance(result, CalibrationResult):
        result_path = Path(result)
        result = load_result(result_path)
    if not twin_dir.is_dir():
        raise InputError(twin_dir, "", "not a folder written by 'handeye-jax simulate'")
    dataset = load_dataset(twin_dir / "dataset.toml")
    dataset = check_fitted_on(result, dataset, result_path)
    truth = load_truth(twin_dir / "truth.json")
    heldout = load_heldout(twin_dir / "heldout.csv")
    if heldout.true_mm is not None:
        return evaluate_points(result, truth, heldout, dataset)
    return evaluate(result, truth, heldout, dataset)


def check_fitted_on(
    result: CalibrationResult, dataset: Dataset, result_path: str | Path | None = None
) -> Dataset:
    """The part of ``dataset`` ``result`` was fitted on: all of it, or the landmarks
    ``calibrate --landmarks`` kept; :class:`InputError` if it was fitted on other data.

    Compared: the dataset's name and, when the result carries its data, the whole dataset
    (camera, captures, landmarks, touches, tablet); else the rig (camera, capture position,
    hand-angle convention) and the number of landmarks. The message names the result's file
    (``result_path``) and the dataset's.
    """
    where = dataset.source or "the dataset"
    path = result_path if result_path is not None else dataset.source

    def refuse(why: str):
        raise InputError(path, "dataset", f"{why}; evaluate a result on the twin it was "
                         "fitted on")  # fmt: skip

    name = result.dataset_name
    if name != dataset.name:
        refuse(f"fitted on dataset {name!r}, not on {dataset.name!r} ({where})")
    fitted = result.data
    if fitted is not None:
        if fitted.n_landmarks != dataset.n_landmarks:
            subset = landmarks_fitted(fitted, dataset)
            if subset is None:
                refuse(f"fitted on {fitted.n_landmarks} landmarks of a dataset {name!r} that "
                       f"are not a part of {where}'s {dataset.n_landmarks}")  # fmt: skip
            dataset = dataset.landmark_subset(subset)
        if fitted.mm_per_tablet_px != dataset.mm_per_tablet_px:
            refuse(f"fitted on a dataset {name!r} with another tablet ppi or scale than {where}")
        for what in Dataset.FIELDS:
            if what in ("name", "search", "tablet_ppi", "tablet_scale"):
                continue
            ours, theirs = getattr(dataset, what), getattr(fitted, what)
            same = (np.array_equal(ours, theirs, equal_nan=True)
                    if isinstance(ours, np.ndarray) else ours == theirs)  # fmt: skip
            if not same:
                refuse(f"fitted on a dataset {name!r} whose {what} differs from {where}'s")
        return dataset
    c, rig = dataset.camera, result.rig
    mine = [c.fx_px, c.fy_px, c.cx_px, c.cy_px, *dataset.captures[0].hand_position_mm,
            dataset.hand_angle_zero_deg, dataset.hand_angle_sign]  # fmt: skip
    theirs = [rig.fx_px, rig.fy_px, rig.cx_px, rig.cy_px, *np.asarray(rig.capture_position_mm),
              rig.angle_zero_deg, rig.angle_sign]  # fmt: skip
    if not np.array_equal(np.asarray(mine, float), np.asarray(theirs, float)):
        refuse(f"fitted on a dataset {name!r} with another camera, capture position or "
               f"hand-angle convention than {where}")  # fmt: skip
    n = len(result.stage1.residuals_mm) or dataset.n_rows
    if n != dataset.n_rows:
        refuse(f"fitted on {n} landmarks of a dataset {name!r}; {where} has "
               f"{dataset.n_rows}")  # fmt: skip
    return dataset


def landmarks_fitted(fitted: Dataset, dataset: Dataset) -> tuple[int, ...] | None:
    """The landmarks m of ``dataset`` a result was fitted on when it was fitted on a part of
    them (``calibrate --landmarks``): each fitted landmark found by its place on the tablet
    (places are distinct), or ``None`` when some is not ``dataset``'s."""
    where = {tuple(p): m for m, p in enumerate(np.asarray(dataset.tablet_px).tolist())}
    ms = tuple(where.get(tuple(p), -1) for p in np.asarray(fitted.tablet_px).tolist())
    return None if -1 in ms else ms


def format_evaluation(rows: list[TouchingError] | list[PointErrors]) -> str:
    """A Markdown table of the touching errors, mm and tablet px (by capture and target
    height for a multi-capture twin: :func:`format_point_errors`)."""
    if isinstance(rows[0], PointErrors):
        return format_point_errors(rows)
    n = len(rows[0].errors_px)
    lines = [
        f"held-out touching error over {n} targets (landing minus target on the display)",
        "",
        "| sent by | mean mm | max mm | mean tablet px | max tablet px |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.label} | {r.mean_mm:.3f} | {r.max_mm:.3f} | {r.mean_px:.2f} | {r.max_px:.2f} |"
        )
    return "\n".join(lines)
