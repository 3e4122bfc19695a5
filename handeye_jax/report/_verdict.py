"""The first screen of a calibration's summary: the verdict a robot engineer acts on, then the
checks that failed, each with what fixes it.

Every number is printed with the digits its standard deviation supports (the σ rounded to two
significant digits, the value to the same place); a number without a validated σ gets three
significant digits and says why it has none.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from ..calibration import Bootstrap, CalibrationResult, Pose

#: Checks a summary lists at most; more are counted.
MAX_CHECKS = 12
#: The run-to-run spread is small when its mean is at most this fraction of the expected
#: touching error's mean: refits then differ by less than half of what a touch misses by.
SMALL_SPREAD = 0.5
#: An alternative fit is worth a check when it moves commands elsewhere by more than this, mm.
AMBIGUITY_MM = 0.1


def with_sigma(value: float | None, sigma: float | None, unit: str = "") -> str:
    """``value ± sigma unit`` with the digits ``sigma`` supports (two significant digits of
    σ); without σ, ``value`` to three significant digits; ``"not determined"`` for ``None``."""
    u = f" {unit}" if unit else ""
    if value is None:
        return "not determined"
    if sigma is None or not math.isfinite(sigma):
        return f"{_sig(value, 3)}{u}"
    if sigma <= 0:
        return f"{value:.6g} ± 0{u}"
    place = decimals_for(sigma)
    return f"{value:.{place}f} ± {sigma:.{place}f}{u}"


def decimals_for(sigma: float) -> int:
    """The decimals that show ``sigma`` (> 0) to two significant digits, and a value to the
    digits that σ supports."""
    return max(-int(math.floor(math.log10(sigma))) + 1, 0)


def _sig(value: float, digits: int) -> str:
    if value == 0 or not math.isfinite(value):
        return f"{value:g}"
    place = max(digits - 1 - int(math.floor(math.log10(abs(value)))), 0)
    return f"{value:.{place}f}"


def some(indices: Sequence[int], most: int = 10) -> str:
    """Landmark or touch indices, at most ``most`` of them and how many more."""
    shown = ", ".join(str(m) for m in indices[:most])
    return shown + (f" and {len(indices) - most} more" if len(indices) > most else "")


def mm_text(value: float) -> str:
    """An error length, mm, to two significant digits."""
    return f"{_sig(value, 2)} mm"


def verdict_lines(result: CalibrationResult, saved: str | None) -> list[str]:
    """The verdict: the stage to deploy and why, the touching error to expect, the camera and
    the pen on the flange, and whether the result was saved."""
    d = result.diagnostics
    stage = result.deploy_stage
    eq = "eq. 25: the model and its affine correction" if stage == 2 else "eq. 8: the model alone"
    lines = [f"VERDICT  deploy stage {stage} ({eq})"]
    if result.deploy is not None:
        lines.append(f"  why: {result.deploy.reason}")
    expected = None if d is None else d.expected
    why_not = contradicted(result)
    if expected is not None and why_not:
        lines.append(f"  expected touching error: not given: {why_not} (see CHECKS)")
    elif expected is not None:
        lines.append(f"  expected touching error: {mm_text(expected.mean_mm)} mean, "
                     f"{mm_text(expected.p95_mm)} 95th percentile (hand-command x-y error for "
                     f"{expected.where}; from the fit's covariance and noise model)")  # fmt: skip
    else:
        lines.append("  expected touching error: not computed (" + _no_expected(result) + ")")
    if d is not None and d.bootstrap is not None:
        lines += bootstrap_lines(d.bootstrap)
    mount = None if d is None else d.mount
    if mount is not None:
        lines += _pose_lines("T_tool0_camera (camera optical frame in the flange)", mount.camera)
        lines += _pose_lines("pen tip in the flange", mount.pen)
    if result.heights is not None:
        h = result.heights
        lines.append(f"  height: z_pen − z_camera = "
                     f"{with_sigma(h.pen_minus_camera_mm, h.pen_minus_camera_sigma_mm, 'mm')}"
                     " (hand heights recorded: commands carry z)")  # fmt: skip
    if saved:
        lines.append(f"  saved: {saved}  (handeye-jax export {saved} --format urdf|ros2|"
                     "opencv|json|yaml|python)")  # fmt: skip
    else:
        lines.append("  saved: nothing (no --out): run again with --out RESULT.json to keep "
                     "the result for predict and export")  # fmt: skip
    return lines


def contradicted(result: CalibrationResult) -> str | None:
    """Why the expected touching error is not to be believed, or ``None``: the deployed
    stage's own touches miss by more than the noise model allows (its outliers), so the
    covariance and noise model that predict it do not describe this fit."""
    d = result.diagnostics
    if d is None:
        return None
    deployed = d.stage2 if result.deploy_stage == 2 else d.stage1
    if deployed is None or not deployed.outliers:
        return None
    return (f"touch(es) {some(deployed.outliers)} miss by more than "
            f"{d.outlier_threshold_mm:g} mm, which the noise model does not allow")


def bootstrap_lines(boot: Bootstrap) -> list[str]:
    """The bootstrap in two lines: how far commands move between refits on resamples of the
    data (mm), beside the covariance's prediction; and whether that is small against the
    expected touching error (:data:`SMALL_SPREAD`)."""
    fitted = (f"{boot.fitted}" if boot.fitted == boot.resamples
              else f"{boot.fitted} of {boot.resamples}")  # fmt: skip
    line = (f"  repeatability: commands move {mm_text(boot.spread_mean_mm)} mean, "
            f"{mm_text(boot.spread_p95_mm)} 95th percentile between refits on {fitted} "
            f"resamples of the data (bootstrap of {boot.resampled}; stage {boot.stage}, "
            "the calibration's views)")  # fmt: skip
    if boot.predicted_mean_mm is not None:
        line += (f"; the covariance predicts {mm_text(boot.predicted_mean_mm)} mean, "
                 f"{mm_text(boot.predicted_p95_mm)} 95th percentile")  # fmt: skip
    lines = [line]
    touch = boot.touching_mean_mm
    if touch is None or touch <= 0:
        lines.append("    → no expected touching error to compare it with (a loss other "
                     "than ml has no noise model)")  # fmt: skip
        return lines
    ratio = boot.spread_mean_mm / touch
    if ratio <= SMALL_SPREAD:
        lines.append(f"    → small against the expected touching error ({mm_text(touch)} "
                     f"mean; the spread is {ratio:.2g} of it): repeated calibrations agree "
                     "within what a touch misses by")  # fmt: skip
    else:
        lines.append(f"    → NOT small against the expected touching error ({mm_text(touch)} "
                     f"mean; the spread is {ratio:.2g} of it): the calibration changes from "
                     "run to run; more touches or captures would steady it (handeye-jax "
                     "plan)")  # fmt: skip
    return lines


def _no_expected(result: CalibrationResult) -> str:
    if result.diagnostics is None or result.diagnostics.stage1 is None:
        return "diagnostics skipped"
    if result.settings.loss != "ml":
        return (f"loss {result.settings.loss}: the error and σ are validated for the "
                "maximum-likelihood fit, --loss ml, the default")
    return "no noise model in this result"


def _pose_lines(title: str, pose: Pose) -> list[str]:
    x, y, z = (with_sigma(v, s, "mm") for v, s in zip(pose.xyz_mm, pose.xyz_sigma_mm,
                                                       strict=True))  # fmt: skip
    lines = [f"  {title}:", f"    xyz  x {x}, y {y}, z {z}"]
    if pose.rpy_deg is not None:
        sig = pose.rpy_sigma_deg or (None, None, None)
        r, p, w = (with_sigma(v, s, "deg") for v, s in zip(pose.rpy_deg, sig, strict=True))
        lines.append(f"    rpy  roll {r}, pitch {p}, yaw {w} (fixed axes, URDF's)")
    if pose.quaternion_xyzw is not None:
        sig = pose.quaternion_sigma or (None,) * 4
        # Each component named, as xyz and rpy are: a σ belongs to its own component.
        q = ", ".join(f"{c} {with_sigma(v, s)}" for c, v, s in zip("xyzw", pose.quaternion_xyzw,
                                                                    sig, strict=True))  # fmt: skip
        lines.append(f"    quaternion  {q}")
    if pose.note:
        lines.append(f"    ({pose.note})")
    return lines


def failed_checks(result: CalibrationResult) -> list[str]:
    """Each check that failed, with what fixes it (warnings carry their own fix)."""
    checks = [str(w) for w in result.warnings]
    d = result.diagnostics
    if d is not None:
        scope = d.scope
        if scope is not None and scope.captures == 1 and result.heights is None:
            checks.append(
                "one capture: the calibration holds only for pictures from this capture pose of "
                "points at about this depth; commands from another height are not determined "
                "by these data → take two more pictures, 40 and 80 mm higher with the hand "
                "turned ±30 deg (handeye-jax plan DATASET), and record hand_z at the touches"
            )  # fmt: skip
        for a in d.ambiguities:
            if a.elsewhere_mm[1] > AMBIGUITY_MM or a.here_mm > AMBIGUITY_MM:
                checks.append(ambiguity_line(a) + f" → {a.separate_by}")
        for key in ("stage1", "stage2"):
            stage = getattr(d, key)
            if stage is not None and stage.outliers:
                which = some(stage.outliers)
                checks.append(
                    f"{'stage 1' if key == 'stage1' else 'stage 2'}: outlier touch(es) {which} "
                    f"(an error above {d.outlier_threshold_mm:g} mm) → retake them, or fit with "
                    "--loss cauchy"
                )  # fmt: skip
        if d.expected is None and result.settings.loss != "ml":
            checks.append(f"no validated uncertainty for loss {result.settings.loss} → "
                          "calibrate with --loss ml (the default)")  # fmt: skip
    return checks


def ambiguity_line(a) -> str:
    """An alternative fit in one line: what it is and what it does to commands."""
    diff = ", ".join(f"{n} {v:+.3g}" for n, v in list(a.differs.items())[:6])
    # A weak direction's far end is a point of its valley; other alternatives are fits by name.
    what = f"{a.kind}: the valley's far end" if a.edge else f"the {a.kind}"
    return (f"ambiguity: {what} fits as well (Δ(−2 log L) = {a.delta_chi2:.2g}; {diff}); "
            f"commands differ by {_sig(a.here_mm, 2)} mm here and up to "
            f"{_sig(a.elsewhere_mm[1], 2)} mm for {a.elsewhere}")  # fmt: skip


def checks_lines(checks: Sequence[str]) -> list[str]:
    """The failed checks, numbered, at most :data:`MAX_CHECKS`."""
    if not checks:
        return ["CHECKS  all passed"]
    lines = [f"CHECKS FAILED  {len(checks)}, each with what fixes it:"]
    lines += [f"  {i}. {c}" for i, c in enumerate(checks[:MAX_CHECKS], 1)]
    if len(checks) > MAX_CHECKS:
        lines.append(f"  … and {len(checks) - MAX_CHECKS} more (the result file's warnings "
                     "list them)")  # fmt: skip
    return lines


def alternatives_lines(result: CalibrationResult) -> list[str]:
    """Every fit the data cannot tell from this one, in one line each, with what would tell
    them apart (those that move commands are failed checks too)."""
    d = result.diagnostics
    if d is None or not d.ambiguities:
        return []
    lines = ["ALTERNATIVE FITS the data cannot tell from this one:"]
    for a in d.ambiguities:
        harm = ("commands do not move (< 0.1 mm)" if max(a.here_mm, a.elsewhere_mm[1]) <=
                AMBIGUITY_MM else f"commands from elsewhere move up to "
                f"{_sig(a.elsewhere_mm[1], 2)} mm")  # fmt: skip
        lines.append(f"  - {a.kind}: {harm}; told apart by {a.separate_by}")
    return lines
