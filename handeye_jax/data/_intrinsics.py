"""Camera intrinsics as the camera's tools write them, read into a :class:`Camera`.

Three kinds of file, told apart by their content:

* **ROS ``camera_info`` YAML**: what ``camera_calibration`` saves (``camera_matrix: {rows,
  cols, data}``, ``distortion_model``, ``distortion_coefficients: {data}``) or what
  ``ros2 topic echo --once /camera/color/camera_info`` prints (``k:``, ``d:``,
  ``distortion_model:``; ROS 1's ``K:``, ``D:``). Read with PyYAML.
* **OpenCV calibration file** (``cv2.FileStorage`` YAML or XML, as ``calibrateCamera``'s
  samples write it): ``camera_matrix`` (or ``cameraMatrix``, ``K``) and
  ``distortion_coefficients`` (or ``dist_coeffs``, ``distCoeffs``, ``D``). Read with
  ``cv2.FileStorage``.
* **RealSense-style intrinsics JSON**: the fields of librealsense's ``rs2_intrinsics``,
  ``{"width", "height", "ppx", "ppy", "fx", "fy", "model", "coeffs"}``, at the top or under
  ``"color"`` (the stream depth is aligned to).

The distortion must be Brown–Conrady with at most OpenCV's first five coefficients
(``plumb_bob``; an 8-coefficient ``rational_polynomial`` whose k4–k6 are 0 is the same), or
none. librealsense's ``Inverse Brown Conrady`` and ``Modified Brown Conrady`` apply the
tangential terms to the radially distorted point; they are read as plumb_bob when that moves
no pixel of the picture by more than :data:`MODEL_DIFFERENCE_PX` (librealsense 2.59 projects a
RealSense-like lens both ways within 0.001 px), else refused.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from .._core import MAX_PX, MAX_TEXT_BYTES, InputError, describe, read_text
from ._dataset import Camera
from ._lens import distort_px
from ._tables import MAX_DISTORTION

#: Largest pixel difference between a RealSense model and plumb_bob read as plumb_bob.
MODEL_DIFFERENCE_PX = 0.01
PLUMB_BOB = ("plumb_bob", "brown_conrady", "brown conrady", "opencv")
REALSENSE_VARIANTS = ("inverse brown conrady", "modified brown conrady",
                      "inverse_brown_conrady", "modified_brown_conrady")  # fmt: skip
NO_DISTORTION = ("none", "")
MATRIX_NAMES = ("camera_matrix", "cameraMatrix", "K", "intrinsic_matrix")
DIST_NAMES = ("distortion_coefficients", "dist_coeffs", "distCoeffs", "D", "dist_coefs")


def read_intrinsics(path: str | Path) -> Camera:
    """The intrinsics (px) and lens distortion in a ROS ``camera_info`` YAML, an OpenCV
    calibration file or a RealSense-style JSON; :class:`InputError` names the file and field."""
    path = Path(path)
    _, text = read_text(path, MAX_TEXT_BYTES)
    head = text.lstrip()[:64]
    if head.startswith("{"):
        return _realsense(path, text)
    if head.startswith(("%YAML:", "<?xml", "<opencv_storage")) or "opencv-matrix" in text:
        return _opencv(path)
    return _ros(path, text)


def _camera(path: Path, where: str, K: Any, coeffs: Any, model: str,
            size: tuple[float, float] | None = None) -> Camera:  # fmt: skip
    """A :class:`Camera` from a 3×3 matrix and a distortion vector, checked."""
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.isfinite(K).all():
        raise InputError(path, where, f"camera matrix must be 3x3 finite numbers (got shape "
                         f"{K.shape})")  # fmt: skip
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if not (1 <= fx <= MAX_PX and 1 <= fy <= MAX_PX) or K[0, 1] != 0 or K[1, 0] != 0 \
            or tuple(K[2]) != (0.0, 0.0, 1.0):  # fmt: skip
        raise InputError(path, where, f"is not a pinhole camera matrix [fx 0 cx; 0 fy cy; 0 0 1] "
                         f"with fx, fy of 1 to {MAX_PX:g} px")  # fmt: skip
    for name, v in (("cx", cx), ("cy", cy)):
        if abs(v) > MAX_PX:
            raise InputError(path, f"{where}.{name}", f"must be at most {MAX_PX:g} px")
    d = _distortion(path, coeffs, model, (fx, fy, cx, cy), size)
    return Camera(float(fx), float(fy), float(cx), float(cy), d)


def _distortion(path: Path, coeffs: Any, model: str, px: tuple, size) -> tuple | None:
    c = np.asarray([] if coeffs is None else coeffs, dtype=np.float64).ravel()
    if not np.isfinite(c).all() or (np.abs(c) > MAX_DISTORTION).any():
        raise InputError(path, "distortion", f"coefficients must be finite and at most "
                         f"{MAX_DISTORTION:g} in magnitude")  # fmt: skip
    name = model.strip().lower()
    if name in NO_DISTORTION or not c.any():
        if name not in (*NO_DISTORTION, *PLUMB_BOB, *REALSENSE_VARIANTS, "rational_polynomial"):
            raise InputError(path, "distortion_model", f"unknown model {model!r:.40}")
        return None
    if name not in (*PLUMB_BOB, *REALSENSE_VARIANTS, "rational_polynomial"):
        raise InputError(path, "distortion_model", f"is {model!r:.40}: only plumb_bob "
                         "(Brown-Conrady k1 k2 p1 p2 k3) is modelled")  # fmt: skip
    if len(c) not in (4, 5, 8, 12, 14):
        raise InputError(path, "distortion", f"has {len(c)} coefficients; expected k1 k2 p1 p2 "
                         "[k3 [k4 k5 k6 ...]]")  # fmt: skip
    if len(c) > 5 and c[5:].any():
        raise InputError(path, "distortion", "has non-zero coefficients beyond k3 (rational, "
                         "thin-prism or tilt terms): only plumb_bob k1 k2 p1 p2 k3 is modelled")
    d = tuple(float(x) for x in np.pad(c[:5], (0, 5 - len(c[:5]))))
    if name in REALSENSE_VARIANTS:
        diff = realsense_difference_px(px, d, size)
        if diff > MODEL_DIFFERENCE_PX:
            raise InputError(path, "model", f"{model!r}: its tangential terms differ from "
                             f"plumb_bob's by {diff:.3f} px in this picture (more than "
                             f"{MODEL_DIFFERENCE_PX:g} px): not modelled")  # fmt: skip
    return d


def realsense_difference_px(camera_px: tuple, distortion: tuple, size) -> float:
    """Largest difference, px, between plumb_bob and librealsense's modified/inverse
    Brown–Conrady (tangential terms of the radially distorted point) over a picture of
    ``size = (width, height)`` px (or twice the principal point when not given)."""
    fx, fy, cx, cy = camera_px
    w, h = size if size else (2 * cx + 1, 2 * cy + 1)
    u, v = np.meshgrid(np.linspace(0, w - 1, 33), np.linspace(0, h - 1, 25))
    x, y = ((u - cx) / fx).ravel(), ((v - cy) / fy).ravel()
    k1, k2, p1, p2, k3 = distortion
    r2 = x * x + y * y
    f = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2**3
    xr, yr = x * f, y * f
    mod = np.stack([xr + 2 * p1 * xr * yr + p2 * (r2 + 2 * xr * xr),
                    yr + 2 * p2 * xr * yr + p1 * (r2 + 2 * yr * yr)], -1)  # fmt: skip
    ideal = np.stack([fx * x + cx, fy * y + cy], -1)
    plumb = distort_px(ideal, camera_px, distortion)
    return float(np.abs(mod * [fx, fy] + [cx, cy] - plumb).max())


def _ros(path: Path, text: str) -> Camera:
    import yaml

    try:
        docs = [d for d in yaml.safe_load_all(text) if d is not None]
    except yaml.YAMLError as e:
        raise InputError(path, "", f"not a ROS camera_info YAML, an OpenCV file or a JSON: "
                         f"{' '.join(str(e).split())[:120]}") from None  # fmt: skip
    doc = docs[0] if docs else None
    if not isinstance(doc, dict):
        raise InputError(path, "", f"must be a YAML mapping (got {describe(doc)})")
    if "camera_matrix" in doc:  # camera_calibration_parsers' file
        K = _matrix(path, doc, "camera_matrix", 9)
        D = _matrix(path, doc, "distortion_coefficients", None) \
            if "distortion_coefficients" in doc else []  # fmt: skip
    else:  # a CameraInfo message, as `topic echo` prints it (ROS 2: k, d; ROS 1: K, D)
        key = "k" if "k" in doc else "K"
        if key not in doc:
            raise InputError(path, "camera_matrix", "missing: expected a ROS camera_info "
                             "(camera_matrix or k), an OpenCV file or a RealSense "
                             "JSON")  # fmt: skip
        K = _numbers(path, doc[key], key, 9)
        dkey = "d" if "d" in doc else "D"
        D = _numbers(path, doc.get(dkey) or [], dkey, None)
    model = doc.get("distortion_model", "plumb_bob" if len(D) else "none")
    if not isinstance(model, str):
        raise InputError(path, "distortion_model", f"must be a string (got {describe(model)})")
    size = (doc.get("image_width", doc.get("width")), doc.get("image_height", doc.get("height")))
    size = size if all(isinstance(s, int) and s > 0 for s in size) else None
    return _camera(path, "camera_matrix", np.reshape(K, (3, 3)), D, model, size)


def _matrix(path: Path, doc: dict, key: str, n: int | None) -> list[float]:
    m = doc[key]
    if not isinstance(m, dict) or "data" not in m:
        raise InputError(path, key, f"must be a table with rows, cols and data (got "
                         f"{describe(m)})")  # fmt: skip
    return _numbers(path, m["data"], f"{key}.data", n)


def _numbers(path: Path, x: Any, where: str, n: int | None) -> list[float]:
    if not isinstance(x, list) or (n is not None and len(x) != n) or len(x) > 16:
        want = f"{n} numbers" if n else "a list of numbers"
        raise InputError(path, where, f"must be {want} (got {describe(x)})")
    for i, v in enumerate(x):
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise InputError(path, f"{where}[{i}]", f"must be a finite number (got {describe(v)})")
    return [float(v) for v in x]


def _opencv(path: Path) -> Camera:
    import cv2

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as e:
        why = " ".join(str(e).split())[:120]
        raise InputError(path, "", f"OpenCV cannot read it: {why}") from None
    try:
        if not fs.isOpened():
            raise InputError(path, "", "OpenCV cannot read it as a FileStorage YAML or XML")
        node = next((fs.getNode(k) for k in MATRIX_NAMES if not fs.getNode(k).empty()), None)
        if node is None or not node.isMap() and node.mat() is None:
            raise InputError(path, "camera_matrix", f"missing: expected one of "
                             f"{', '.join(MATRIX_NAMES)}")  # fmt: skip
        K = node.mat()
        if K is None:
            raise InputError(path, "camera_matrix", "must be a 3x3 matrix (!!opencv-matrix)")
        dist = next((fs.getNode(k) for k in DIST_NAMES if not fs.getNode(k).empty()), None)
        D = None if dist is None else dist.mat()
        if dist is not None and D is None:
            raise InputError(path, "distortion_coefficients", "must be a matrix of numbers")
        model = fs.getNode("distortion_model")
        name = model.string() if not model.empty() and model.isString() else "plumb_bob"
        w, h = fs.getNode("image_width"), fs.getNode("image_height")
        size = (int(w.real()), int(h.real())) if not (w.empty() or h.empty()) else None
    finally:
        fs.release()
    return _camera(path, "camera_matrix", K, D, name if D is not None else "none", size)


def _realsense(path: Path, text: str) -> Camera:
    try:
        doc = json.loads(text)
    except (json.JSONDecodeError, RecursionError, ValueError) as e:
        raise InputError(path, "", f"not valid JSON: {e}") from None
    where = ""
    if isinstance(doc, dict) and isinstance(doc.get("color"), dict):
        doc, where = doc["color"], "color."
    if not isinstance(doc, dict):
        raise InputError(path, "", f"must be a JSON object (got {describe(doc)})")
    for key in ("fx", "fy", "ppx", "ppy"):
        v = doc.get(key)
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise InputError(path, where + key, f"must be a finite number, px (got "
                             f"{describe(v)})")  # fmt: skip
    coeffs = _numbers(path, doc.get("coeffs", []), where + "coeffs", None)
    model = doc.get("model", "Brown Conrady" if any(coeffs) else "None")
    if not isinstance(model, str):
        raise InputError(path, where + "model", f"must be a string (got {describe(model)})")
    size = (doc.get("width"), doc.get("height"))
    size = size if all(isinstance(s, int) and s > 0 for s in size) else None
    K = [[doc["fx"], 0.0, doc["ppx"]], [0.0, doc["fy"], doc["ppy"]], [0.0, 0.0, 1.0]]
    return _camera(path, where + "fx", K, coeffs, model.replace("_", " "), size)


__all__ = ["read_intrinsics", "realsense_difference_px"]
