"""Landmarks from the camera's picture of the tablet, and their depths (paper, section 4.2).

The steps, each a function:

1. :func:`darkness`: how much darker than its surroundings each pixel is, ``D = B − I``, with
   ``B`` the local white level (a median filter much wider than a dot). This is the paper's
   ``255 − I`` weight with the true white level in place of 255, so vignetting, a grey display
   and the dark bezel do not bias the centroids.
2. :func:`binarise`: Otsu's threshold on the picture's black top-hat (never below a few σ of
   the image noise, with hysteresis), or OpenCV's adaptive threshold on the picture.
3. :func:`find_blobs`: connected components within the area limits and clear of the
   picture's edge, each with a sub-pixel centroid weighted by ``D`` in a small window that
   is re-centred until it settles.
4. :func:`order_blobs`: the blobs put into the dataset's landmark order by matching their
   layout to the drawn one (``tablet_px``) through a homography, so a grid rotated in the
   picture or seen in perspective is ordered correctly.
5. :func:`depth_at`: the median of the valid (non-zero) depth pixels around each centroid.

:func:`detect_landmarks` runs them on files and raises :class:`InputError` for bad input;
:func:`fill_dataset` puts the result into a dataset. Image coordinates follow OpenCV: the
centre of pixel ``(row v, column u)`` is ``(u, v)``, as in the dataset's ``image_px``.
"""

from __future__ import annotations

import io
import itertools
import math
import os
import struct
import sys
import tempfile
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from jaxtyping import Float, Int, UInt8, UInt16

from .._core import (
    MAX_AREA_PX,
    MAX_IMAGE_BYTES,
    MAX_IMAGE_PIXELS,
    MIN_AREA_PX,
    InputError,
    read_bytes,
)
from ..data import Capture, Dataset


@dataclass(frozen=True)
class DetectSettings:
    """How to find the landmark blobs.

    Attributes:
        threshold: ``"otsu"`` (on the darkness image) or ``"adaptive"`` (on the picture).
        background_px: side of the median filter that estimates the white level, image px
            (odd; several times a blob's size).
        noise_sigmas: Otsu's threshold is raised to at least this many σ of the image noise.
        peak_sigmas: a blob must also peak this many σ above the noise (hysteresis).
        smoothing_px: σ of the Gaussian that smooths the picture before thresholding, px
            (about a blob's size: it averages the noise down, not the dots).
        adaptive_block_px, adaptive_offset: OpenCV's ``adaptiveThreshold`` block size (odd,
            image px) and offset ``C`` (grey levels) for ``threshold="adaptive"``.
        min_area_px, max_area_px: blobs outside these areas (image px²) are ignored.
        centroid_window_px: the centroid is taken over ``±centroid_window_px`` pixels.
        depth_window_px: depth is the median over ``±depth_window_px`` pixels.
        depth_scale_mm: mm per unit of the 16-bit depth image (RealSense's ``depth_scale``
            in mm: 1 for its default 0.001 m units, 0.1 for 0.0001 m).
    """

    threshold: str = "otsu"
    background_px: int = 9
    noise_sigmas: float = 4.0
    peak_sigmas: float = 7.0
    smoothing_px: float = 1.0
    adaptive_block_px: int = 15
    adaptive_offset: float = 3.0
    min_area_px: int = MIN_AREA_PX
    max_area_px: int = MAX_AREA_PX
    centroid_window_px: int = 1
    depth_window_px: int = 2
    depth_scale_mm: float = 1.0

    def __post_init__(self):
        if not (math.isfinite(self.depth_scale_mm) and 0 < self.depth_scale_mm <= 100):
            raise ValueError(f"depth_scale_mm must be > 0 and at most 100 mm per unit (got "
                             f"{self.depth_scale_mm})")  # fmt: skip
        if self.threshold not in ("otsu", "adaptive"):
            raise ValueError(f"threshold must be 'otsu' or 'adaptive' (got {self.threshold!r})")
        for name in ("background_px", "adaptive_block_px"):
            v = getattr(self, name)
            if v < 3 or v % 2 == 0:
                raise ValueError(f"{name} must be odd and >= 3 (got {v})")
        if not 1 <= self.min_area_px <= self.max_area_px:
            raise ValueError(
                f"need 1 <= min_area_px <= max_area_px (got {self.min_area_px}, {self.max_area_px})"
            )


@dataclass(frozen=True)
class Blobs:
    """Dark blobs found in a picture, in the order found.

    Attributes:
        image_px: sub-pixel centroid ``(u, v)`` of each blob, image px, ``(k, 2)``.
        area_px: each blob's area above the threshold, image px², ``(k,)``.
    """

    image_px: np.ndarray
    area_px: np.ndarray


def to_grey(image: np.ndarray) -> np.ndarray:
    """A ``uint8`` picture (grey, BGR or BGRA) as ``uint8`` grey."""
    if image.ndim == 2:
        return image
    code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
    return cv2.cvtColor(image, code)


def darkness(grey: UInt8[np.ndarray, "h w"], background_px: int = 9) -> Float[np.ndarray, "h w"]:
    """``D = B − I`` in grey levels (float): darkness below the local white level ``B``."""
    return cv2.medianBlur(grey, background_px).astype(float) - grey.astype(float)


def binarise(grey: UInt8[np.ndarray, "h w"], settings: DetectSettings) -> UInt8[np.ndarray, "h w"]:
    """The mask (``uint8``, 255 = dot) of pixels dark enough to belong to a dot.

    Otsu's threshold is taken on the black top-hat of the picture (its closing minus itself,
    which keeps only dark details smaller than ``background_px``: the dots, not the bezel or
    the display's corners). With a few dot pixels among 300,000, Otsu alone would split the
    noise, so the threshold is never below ``noise_sigmas`` robust σ of the top-hat.
    """
    if settings.threshold == "adaptive":
        smooth = cv2.GaussianBlur(grey, (0, 0), settings.smoothing_px)
        return cv2.adaptiveThreshold(
            smooth, 255, cv2.ADAPTIVE_THRESH_GAUSSIAN_C, cv2.THRESH_BINARY_INV,
            settings.adaptive_block_px, settings.adaptive_offset,
        )  # fmt: skip
    kernel = cv2.getStructuringElement(
        cv2.MORPH_RECT, (settings.background_px, settings.background_px)
    )
    r = settings.background_px
    smooth = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), settings.smoothing_px)
    padded = cv2.copyMakeBorder(smooth, r, r, r, r, cv2.BORDER_REPLICATE)  # no edge artefacts
    top_hat = cv2.morphologyEx(padded, cv2.MORPH_BLACKHAT, kernel)[r:-r, r:-r]
    # Otsu's method is scale-free: run it on the top-hat stretched to 0..255.
    scale = 255.0 / max(float(top_hat.max()), 1e-6)
    stretched = np.round(top_hat * scale).astype(np.uint8)
    otsu, _ = cv2.threshold(stretched, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    med = float(np.median(top_hat))
    sigma = 1.4826 * float(np.median(np.abs(top_hat - med)))
    low = max(float(otsu) / scale, med + settings.noise_sigmas * sigma, 0.5)
    high = max(low, med + settings.peak_sigmas * sigma)
    # Hysteresis: a blob is the pixels above ``low`` around a peak above ``high``.
    mask = np.where(top_hat > low, 255, 0).astype(np.uint8)
    n, labels = cv2.connectedComponents(mask, connectivity=8)
    peak = np.zeros(n)
    np.maximum.at(peak, labels.ravel(), top_hat.ravel())
    return np.where((labels > 0) & (peak[labels] > high), 255, 0).astype(np.uint8)


def refine_centroid(
    dark: Float[np.ndarray, "h w"], start_px: Float[np.ndarray, "2"], half: int
) -> Float[np.ndarray, "2"]:
    """Darkness-weighted centroid in a ``(2·half+1)²`` window re-centred until it settles."""
    h, w = dark.shape
    c = np.asarray(start_px, dtype=float)
    for _ in range(5):
        u0, v0 = int(round(c[0])), int(round(c[1]))
        if not (half <= u0 < w - half and half <= v0 < h - half):
            return c
        win = dark[v0 - half : v0 + half + 1, u0 - half : u0 + half + 1]
        total = win.sum()
        if total <= 0:
            return c
        k = np.arange(-half, half + 1)
        new = np.array([u0 + (win.sum(axis=0) @ k) / total, v0 + (win.sum(axis=1) @ k) / total])
        if np.array_equal(np.round(new), np.round(c)):
            return new
        c = new
    return c


def find_blobs(image: np.ndarray, settings: DetectSettings | None = None) -> Blobs:
    """Dark blobs in a picture (``uint8`` grey or BGR) with sub-pixel centroids."""
    settings = settings or DetectSettings()
    grey = to_grey(image)
    dark = darkness(grey, settings.background_px)
    mask = binarise(grey, settings)
    n, _, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
    area = stats[1:, cv2.CC_STAT_AREA]
    x, y = stats[1:, cv2.CC_STAT_LEFT], stats[1:, cv2.CC_STAT_TOP]
    right, bottom = x + stats[1:, cv2.CC_STAT_WIDTH], y + stats[1:, cv2.CC_STAT_HEIGHT]
    h, w = grey.shape
    # A blob cut by the picture's edge has no reliable centroid (and is not a whole dot).
    inside = (x > 0) & (y > 0) & (right < w) & (bottom < h)
    sized = (area >= settings.min_area_px) & (area <= settings.max_area_px)
    keep = np.flatnonzero(sized & inside)
    pts = [refine_centroid(dark, centroids[1 + i], settings.centroid_window_px) for i in keep]
    return Blobs(np.array(pts, dtype=float).reshape(-1, 2), area[keep].astype(float))


def _max_area_quad(points: np.ndarray, what: str) -> np.ndarray:
    """Indices of the four hull points spanning the largest quadrilateral, in hull order.

    Raises:
        ValueError: fewer than four points on the convex hull (e.g. all on one line).
    """
    hull = cv2.convexHull(points.astype(np.float32), returnPoints=False).ravel()
    if len(hull) < 4:
        raise ValueError(
            f"the {what} span no quadrilateral (only {len(hull)} points on their convex hull;"
            " collinear?)"
        )
    best, best_area = None, -1.0
    for quad in itertools.combinations(sorted(hull), 4):
        idx = np.array(quad)
        # Keep the hull's cyclic order so the quadrilateral does not cross itself.
        idx = idx[np.argsort([list(hull).index(i) for i in idx])]
        area = cv2.contourArea(points[idx].astype(np.float32))
        if area > best_area:
            best, best_area = idx, area
    return best


def order_blobs(
    blobs_px: Float[np.ndarray, "n 2"], layout_px: Float[np.ndarray, "n 2"]
) -> Int[np.ndarray, " n"]:
    """Indices that put the blobs into the layout's order: ``blobs_px[order][m]`` is landmark m.

    The four outermost landmarks of the layout (the corners of the largest quadrilateral on
    its convex hull) are matched to the blobs' in each of the eight ways a quadrilateral can
    be turned or mirrored; the homography of each match maps every landmark into the picture,
    and each landmark takes the nearest blob. The matches that pair all blobs one to one and
    fit best (within 10 % of the layout's spacing) are kept; among those, the one whose tablet
    x axis points most nearly along +u wins, because the paper's 3×3 grid maps onto itself
    when turned by a quarter turn. So the picture may show the grid turned by less than ±45°
    in its plane, and in perspective, not mirrored (as a camera above the display sees it). A
    square grid turned by more than 45° is indistinguishable from one turned by less, and is
    ordered as the latter: keep the tablet's x axis roughly along the picture's u axis.

    Args:
        blobs_px: blob centroids, image px, ``(n, 2)``.
        layout_px: where the landmarks are drawn, tablet px, ``(n, 2)``, in landmark order.

    Raises:
        ValueError: no match pairs the blobs with the layout, or either set of points spans no
            quadrilateral.
    """
    blobs_px, layout_px = np.asarray(blobs_px, float), np.asarray(layout_px, float)
    n = len(layout_px)
    if len(blobs_px) != n or n < 4:
        raise ValueError(f"need the same number (>= 4) of blobs and landmarks, got {len(blobs_px)}"
                         f" and {n}")  # fmt: skip
    q_layout = _max_area_quad(layout_px, "drawn landmarks (tablet_px)")
    q_blobs = _max_area_quad(blobs_px, "blobs")
    spacing = np.min([np.linalg.norm(a - b) for a, b in itertools.combinations(blobs_px, 2)])
    candidates = []
    for mirror in (False, True):
        ring = q_blobs[::-1] if mirror else q_blobs
        for turn in range(4):
            dst = np.roll(ring, turn)
            H = cv2.getPerspectiveTransform(
                layout_px[q_layout].astype(np.float32), blobs_px[dst].astype(np.float32)
            )
            mapped = cv2.perspectiveTransform(layout_px[None].astype(np.float64), H)[0]
            dist = np.linalg.norm(mapped[:, None] - blobs_px[None], axis=2)
            order = dist.argmin(axis=1)
            if len(set(order.tolist())) != n:
                continue
            rms = float(np.sqrt(np.mean(dist[np.arange(n), order] ** 2)))
            # Direction of tablet +x in the picture, at the layout's centre.
            c = layout_px.mean(axis=0)
            ends = cv2.perspectiveTransform(np.array([[c, c + [1.0, 0.0]]]), H)[0]
            x_dir = ends[1] - ends[0]
            cos_u = x_dir[0] / (np.linalg.norm(x_dir) + 1e-300)
            det = np.linalg.det(H[:2, :2])
            candidates.append((rms, cos_u, det > 0, order))
    if not candidates:
        raise ValueError("no turn or mirror of the drawn layout matches the blobs one to one")
    best_rms = min(c[0] for c in candidates)
    good = [c for c in candidates if c[0] <= best_rms + 0.1 * spacing]
    # Prefer unmirrored matches, then tablet +x along +u.
    good.sort(key=lambda c: (not c[2], -c[1]))
    return good[0][3]


#: Most landmarks for which :func:`match_blobs` tries every subset (C(n, 4) quadrilaterals).
MAX_PARTIAL_LANDMARKS = 16


#: Largest ratio of the two scales of a layout-to-picture map in :func:`match_blobs`: a
#: camera that looks at the tablet less than about 48 deg off its normal.
MAX_ANISOTROPY = 1.5
#: A match whose tablet x axis is within this of +u in the picture is a plausible reading.
PLAUSIBLE_TURN_DEG = 55.0


def _local_map(H: np.ndarray, layout_px: np.ndarray) -> tuple[float, float, bool]:
    """How ``H`` maps the tablet near the layout's centre: the direction of tablet +x in the
    picture (deg from +u), the ratio of its largest to its smallest scale, and whether it
    keeps handedness (unmirrored)."""
    c = layout_px.mean(axis=0)
    p = cv2.perspectiveTransform(np.array([[c, c + [1.0, 0.0], c + [0.0, 1.0]]]), H)[0]
    J = np.stack([p[1] - p[0], p[2] - p[0]], axis=1)  # columns: images of tablet x and y
    s = np.linalg.svd(J, compute_uv=False)
    return (
        float(np.degrees(np.arctan2(J[1, 0], J[0, 0]))),
        s[0] / max(s[1], 1e-300),
        bool(np.linalg.det(J) > 0),
    )


def match_blobs(
    blobs_px: Float[np.ndarray, "k 2"], layout_px: Float[np.ndarray, "n 2"]
) -> tuple[Int[np.ndarray, " k"], Int[np.ndarray, " k"]]:
    """Which landmark each blob is, when the picture shows only some of them (``k <= n``).

    Every quadrilateral of four landmarks is matched to the blobs' outermost four, in each
    turn and mirror; a homography that maps some landmark onto every blob (one to one, within
    10 % of the blobs' spacing of the best match) and could be a camera's view of a flat
    tablet (its scales along two directions differ by at most :data:`MAX_ANISOTROPY`; no
    shear) is a candidate. As in :func:`order_blobs`,
    unmirrored candidates win, then the one whose tablet x axis points most nearly along +u.
    If another candidate of the same handedness names different landmarks and is about as
    plausible (turned within 15 deg of the winner, or within :data:`PLAUSIBLE_TURN_DEG` of
    +u), the reading is ambiguous (a 2 x 3 part of a 3 x 3 grid may be either end): then
    nothing is guessed.

    Args:
        blobs_px: blob centroids, image px, ``(k, 2)``, at least 4.
        layout_px: where the landmarks are drawn, tablet px, ``(n, 2)``, at most
            :data:`MAX_PARTIAL_LANDMARKS`.

    Returns:
        ``(landmarks, order)``: the landmarks seen, ascending, and the blob of each:
        ``blobs_px[order][j]`` is landmark ``landmarks[j]``.

    Raises:
        ValueError: no match, an ambiguous one, or too few blobs or too many landmarks.
    """
    blobs_px, layout_px = np.asarray(blobs_px, float), np.asarray(layout_px, float)
    k, n = len(blobs_px), len(layout_px)
    if not 4 <= k <= n:
        raise ValueError(f"need 4 to {n} blobs to match {n} landmarks, got {k}")
    if n > MAX_PARTIAL_LANDMARKS:
        raise ValueError(f"telling which of {n} landmarks {k} blobs are is tried for at most "
                         f"{MAX_PARTIAL_LANDMARKS} landmarks; name the landmarks seen")  # fmt: skip
    q_blobs = _max_area_quad(blobs_px, "blobs")
    spacing = np.min([np.linalg.norm(a - b) for a, b in itertools.combinations(blobs_px, 2)])
    candidates = []
    for quad in itertools.combinations(range(n), 4):
        hull = cv2.convexHull(layout_px[list(quad)].astype(np.float32), returnPoints=False)
        if len(hull) < 4:
            continue
        src = layout_px[np.array(quad)[hull.ravel()]].astype(np.float32)
        for mirror in (False, True):
            ring = q_blobs[::-1] if mirror else q_blobs
            for turn in range(4):
                dst = blobs_px[np.roll(ring, turn)].astype(np.float32)
                H = cv2.getPerspectiveTransform(src, dst)
                mapped = cv2.perspectiveTransform(layout_px[None], H)[0]
                dist = np.linalg.norm(blobs_px[:, None] - mapped[None], axis=2)  # (k, n)
                which = dist.argmin(axis=1)
                if len(set(which.tolist())) != k:
                    continue
                rms = float(np.sqrt(np.mean(dist[np.arange(k), which] ** 2)))
                x_deg, anisotropy, unmirrored = _local_map(H, layout_px)
                if anisotropy <= MAX_ANISOTROPY:  # a shear can map a part onto another part
                    candidates.append((rms, unmirrored, x_deg, which))
    if not candidates:
        raise ValueError(f"no part of the drawn layout matches the {k} blobs one to one")
    best_rms = min(c[0] for c in candidates)
    good = [c for c in candidates if c[0] <= best_rms + 0.1 * spacing]
    good.sort(key=lambda c: (not c[1], -np.cos(np.radians(c[2]))))
    first = good[0]
    for other in good[1:]:
        turned = abs((other[2] - first[2] + 180.0) % 360.0 - 180.0)
        plausible = turned < 15.0 or abs(other[2]) < PLAUSIBLE_TURN_DEG
        if other[1] == first[1] and plausible and not np.array_equal(other[3], first[3]):
            a, b = (sorted(c[3].tolist()) for c in (first, other))
            raise ValueError(f"the {k} blobs fit landmarks {a} as well as {b}; name the "
                             "landmarks seen")  # fmt: skip
    which = first[3]
    order = np.argsort(which)
    return which[order], order


def depth_at(
    depth_mm: UInt16[np.ndarray, "h w"], image_px: Float[np.ndarray, "n 2"], half: int = 2
) -> Float[np.ndarray, " n"]:
    """Median of the non-zero depth pixels within ``±half`` px of each point, mm; NaN if none.

    Args:
        depth_mm: the depth image, mm (0 = no measurement).
        image_px: ``(u, v)`` of each point, image px, ``(n, 2)``.
        half: half-width of the window, px.
    """
    h, w = depth_mm.shape
    out = np.full(len(image_px), np.nan)
    for i, (u, v) in enumerate(np.round(np.asarray(image_px, float)).astype(int)):
        win = depth_mm[
            max(v - half, 0) : min(v + half + 1, h), max(u - half, 0) : min(u + half + 1, w)
        ]
        valid = win[win > 0]
        if valid.size:
            out[i] = float(np.median(valid))
    return out


# -- files ----------------------------------------------------------------------------------


def read_image(path: str | Path, *, depth: bool = False) -> np.ndarray:
    """Read a colour (``uint8``) or depth (``uint16`` mm, one channel) PNG; InputError if bad.

    The file must be a regular file of at most 64 MiB (``MAX_IMAGE_BYTES``) whose header
    says at most 4096 x 4096 px (``MAX_IMAGE_PIXELS``); that is checked before decoding.
    """
    path = Path(path)
    raw = read_bytes(path, MAX_IMAGE_BYTES, "image")
    data = np.frombuffer(raw, dtype=np.uint8)
    if data.size == 0:
        raise InputError(path, "", "image file is empty")
    w, h = _header_size(path, raw)
    if w * h > MAX_IMAGE_PIXELS:
        raise InputError(path, "", f"cannot read image: too large ({w}x{h} px; at most "
                         f"{MAX_IMAGE_PIXELS:,} px, e.g. 4096x4096)")  # fmt: skip
    try:
        image, printed = _decode(data)
    except cv2.error as e:
        raise InputError(path, "", f"cannot read image: {_refused(data, e)}") from None
    if image is None or image.size == 0:
        why = "not a PNG/JPEG/TIFF OpenCV can decode"
        said = [line.removeprefix("libpng error: ") for line in printed.splitlines() if line]
        raise InputError(path, "", f"cannot read image: {why}" + (f" ({said[-1]})" if said else ""))
    if depth:
        if image.dtype != np.uint16 or image.ndim != 2:
            chans = 1 if image.ndim == 2 else image.shape[2]
            raise InputError(path, "", "expected a 16-bit one-channel depth image in mm "
                             f"(got {image.dtype}, {chans} channel(s))")  # fmt: skip
    elif image.dtype != np.uint8:
        raise InputError(path, "", f"expected an 8-bit picture (got {image.dtype})")
    return image


def _decode(data: np.ndarray) -> tuple[np.ndarray | None, str]:
    """``cv2.imdecode`` and what the codec printed meanwhile (libpng prints its errors to the
    process's standard error itself): the caller's error message says it once, in one line."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no standard error to keep clean
        return cv2.imdecode(data, cv2.IMREAD_UNCHANGED), ""
    with tempfile.TemporaryFile() as caught:
        os.dup2(caught.fileno(), 2)
        try:
            image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        caught.seek(0)
        return image, caught.read().decode("utf-8", "replace")


def _header_size(path: Path, data: bytes) -> tuple[int, int]:
    """The picture's ``(width, height)``, px, from its header, without decoding it.

    Raises :class:`InputError` naming ``path`` when it is not a picture Pillow identifies.
    """
    if data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR":
        return struct.unpack(">II", data[16:24])
    from PIL import Image  # matplotlib's dependency; open() reads only the header

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        try:
            with Image.open(io.BytesIO(data)) as image:
                return image.size
        except Image.DecompressionBombError:  # more than twice Pillow's own limit
            why = f"too large (more than {2 * Image.MAX_IMAGE_PIXELS:,} px)"
        except Exception:  # noqa: BLE001 - whatever Pillow raises, it is no picture it knows
            why = "not a PNG, JPEG or TIFF picture"
    raise InputError(path, "", f"cannot read image: {why}")


def _refused(data: np.ndarray, e: cv2.error) -> str:
    """Why OpenCV refused to decode, in one line."""
    if "CV_IO_MAX_IMAGE_PIXELS" in str(e):
        size = ""
        head = data[:24].tobytes()
        if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
            size = "{}x{} px, ".format(*struct.unpack(">II", head[16:24]))
        return f"too large ({size}more pixels than OpenCV decodes, CV_IO_MAX_IMAGE_PIXELS)"
    return " ".join((getattr(e, "err", "") or str(e)).split())


@dataclass(frozen=True)
class Detection:
    """Landmarks found in a picture, in the dataset's landmark order.

    Attributes:
        image_px: centroid of each landmark found, image px, ``(k, 2)``.
        depth_mm: depth at each centroid, mm, ``(k,)``.
        blobs: every blob found, in the order found.
        landmarks: the index of each landmark found, ascending, ``(k,)`` (all ``n`` unless
            the detection was asked for only some, ``partial``).
        no_depth: landmarks whose blob was found but had no valid depth around it, left out
            (``partial`` only).
    """

    image_px: np.ndarray
    depth_mm: np.ndarray
    blobs: Blobs
    landmarks: np.ndarray | None = None
    no_depth: tuple[int, ...] = ()

    def __post_init__(self):
        if self.landmarks is None:
            object.__setattr__(self, "landmarks", np.arange(len(self.image_px)))


class BlobCountError(InputError):
    """The picture holds a different number of blobs from the landmarks expected."""

    def __init__(self, path, blobs: Blobs, expected: int | str, note: str = "",
                 per: str = "per landmark"):  # fmt: skip
        self.blobs, self.expected, self.note, self.per = blobs, expected, note, per
        where = ", ".join(f"({u:.1f}, {v:.1f})" for u, v in blobs.image_px[:20])
        more = ", ..." if len(blobs.image_px) > 20 else ""
        super().__init__(
            path, "blobs",
            f"found {len(blobs.image_px)} blobs, expected {expected} (one {per})"
            + (f" at {where}{more}" if where else "") + note,
        )  # fmt: skip

    def with_note(self, note: str) -> BlobCountError:
        """The same error with ``note`` added to its message."""
        return BlobCountError(self.path, self.blobs, self.expected, self.note + note, self.per)


def detect_landmarks(
    capture_path: str | Path,
    depth_path: str | Path,
    layout_px: np.ndarray,
    settings: DetectSettings | None = None,
    *,
    partial: bool = False,
    landmarks: Sequence[int] | None = None,
) -> Detection:
    """Find the landmarks in a colour picture and read their depths from a depth image.

    Args:
        capture_path: the colour picture (8-bit PNG).
        depth_path: the depth image (16-bit PNG in units of ``settings.depth_scale_mm``, 0 =
            no measurement), aligned to the picture: the same size, pixel for pixel.
        layout_px: where the landmarks are drawn, tablet px, ``(n, 2)``, in landmark order.
        settings: detection settings.
        partial: the picture may show only some landmarks (a capture of a version-2
            dataset): fewer blobs are matched to the layout (:func:`match_blobs`), and a
            landmark without a valid depth is left out (``Detection.no_depth``).
        landmarks: the landmarks the picture shows, when the blobs alone cannot tell (implies
            ``partial``); there must be one blob for each.

    Raises:
        BlobCountError: the wrong number of blobs (its ``blobs`` says where they are).
        InputError: an unreadable or empty image, images of different sizes, blobs that
            match no (or more than one) part of the layout, or (unless ``partial``) a
            landmark with no valid depth around it.
    """
    settings = settings or DetectSettings()
    layout_px = np.asarray(layout_px, dtype=float)
    image = read_image(capture_path)
    depth = read_image(depth_path, depth=True)
    if depth.shape[:2] != image.shape[:2]:
        raise InputError(
            depth_path, "",
            f"size {depth.shape[1]}x{depth.shape[0]} px differs from the picture's "
            f"{image.shape[1]}x{image.shape[0]} px ({capture_path})",
        )  # fmt: skip
    blobs = find_blobs(image, settings)
    n, k = len(layout_px), len(blobs.image_px)
    if landmarks is not None:
        seen = np.asarray(landmarks, dtype=np.int64).reshape(-1)
        if k != len(seen):
            raise BlobCountError(capture_path, blobs, len(seen), per="per landmark named")
        order, partial = _order(capture_path, blobs, layout_px[seen]), True
    elif k == n:
        seen, order = np.arange(n), _order(capture_path, blobs, layout_px)
    elif partial and 4 <= k < n:
        try:
            seen, order = match_blobs(blobs.image_px, layout_px)
        except ValueError as e:
            why = f"cannot tell which landmarks the {k} blobs are: {e}"
            raise InputError(capture_path, "blobs", why) from None
    else:
        expected = f"4 to {n}" if partial else n
        raise BlobCountError(capture_path, blobs, expected, per="per landmark seen" * partial
                             or "per landmark")  # fmt: skip
    image_px = blobs.image_px[order]
    depth_mm = depth_at(depth, image_px, settings.depth_window_px) * settings.depth_scale_mm
    missing = np.flatnonzero(~np.isfinite(depth_mm))
    if missing.size and not partial:
        u, v = image_px[missing[0]]
        raise InputError(
            depth_path, f"landmarks[{missing[0]}].depth",
            f"no valid (non-zero) depth within ±{settings.depth_window_px} px "
            f"of ({u:.1f}, {v:.1f})",
        )  # fmt: skip
    keep = np.isfinite(depth_mm)
    no_depth = tuple(int(m) for m in seen[~keep])
    return Detection(image_px[keep], depth_mm[keep], blobs, seen[keep], no_depth)


def _order(capture_path: str | Path, blobs: Blobs, layout_px: np.ndarray) -> np.ndarray:
    try:
        return order_blobs(blobs.image_px, layout_px)
    except ValueError as e:
        raise InputError(capture_path, "blobs", f"cannot order the blobs as drawn: {e}") from None


def fill_dataset(dataset: Dataset, detection: Detection) -> Dataset:
    """The dataset with ``image_px`` and ``depth`` from a detection of every landmark (a
    single-capture dataset, e.g. version 1); every other field as is."""
    return dataset.replace(image_px=detection.image_px, depth_mm=detection.depth_mm)


def fill_capture(
    dataset: Dataset,
    detection: Detection,
    capture: int | None = None,
    *,
    hand_position_mm: Float[np.ndarray, "3"] | None = None,
    hand_angle_deg: float | None = None,
) -> Dataset:
    """The dataset with a detection as one of its captures; every other field as is.

    Args:
        dataset: the dataset to fill.
        detection: the landmarks found in the capture's picture (those not found are left
            out of the capture).
        capture: the index of the capture to replace (its landmarks, ``image_px`` and depths;
            its hand pose where given), or ``None`` to append a new capture, whose hand pose
            must then be given.
        hand_position_mm: the hand's position ``(x, y, z)`` when the picture was taken, mm,
            base frame.
        hand_angle_deg: the hand angle θ when the picture was taken, deg.

    Raises:
        ValueError: no such capture, or a new capture without its hand pose.
        InputError: a touched landmark would be in no capture (naming the dataset's file).
    """
    caps = list(dataset.captures)
    if capture is None:
        if hand_position_mm is None or hand_angle_deg is None:
            raise ValueError("a new capture needs its hand position and hand angle")
        old = None
    elif not 0 <= capture < len(caps):
        raise ValueError(f"capture {capture} does not exist (0 to {len(caps) - 1})")
    else:
        old = caps[capture]
    position = old.hand_position_mm if hand_position_mm is None else hand_position_mm
    angle = old.hand_angle_deg if hand_angle_deg is None else hand_angle_deg
    new = Capture(position, angle, detection.landmarks, detection.image_px, detection.depth_mm)
    k = len(caps) if capture is None else capture
    if capture is None:
        caps.append(new)
    else:
        caps[capture] = new
    seen = set().union(*(c.landmarks.tolist() for c in caps))
    for i, m in enumerate(dataset.touch_landmark.tolist()):
        if m not in seen:
            raise InputError(
                dataset.source, f"captures[{k}].landmarks",
                f"landmark {m} (touches[{i}]) would be in no capture: a touch needs a picture "
                "of what it touched; take a picture that shows it",
            )  # fmt: skip
    # A version-1 dataset stays version 1 while it fits (one capture of every landmark).
    return dataset.replace(captures=caps, version=None if dataset.version == 1 else 2)


def overlay_image(image: np.ndarray, points_px: np.ndarray, labels: list[str]) -> np.ndarray:
    """The picture with each point circled and labelled (BGR ``uint8``), for people to check."""
    out = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image[..., :3].copy()
    for (u, v), text in zip(points_px, labels, strict=True):
        # shift=4: sub-pixel circle centres, so the marks sit where the centroids are.
        c = (int(round(u * 16)), int(round(v * 16)))
        cv2.circle(out, c, 8 * 16, (0, 0, 255), 1, cv2.LINE_AA, shift=4)
        cv2.drawMarker(out, (int(round(u)), int(round(v))), (0, 160, 0), cv2.MARKER_CROSS, 5, 1)
        size = cv2.getTextSize(text, _LABEL_FONT, _LABEL_SCALE, 1)
        cv2.putText(out, text, _label_origin(u, v, size, out.shape), _LABEL_FONT, _LABEL_SCALE,
                    (0, 0, 255), 1, cv2.LINE_AA)  # fmt: skip
    return out


_LABEL_FONT = cv2.FONT_HERSHEY_SIMPLEX
_LABEL_SCALE = 0.5


def _label_origin(
    u: float, v: float, size: tuple[tuple[int, int], int], shape: tuple[int, ...], gap: int = 9
) -> tuple[int, int]:
    """Where a label of ``size`` (OpenCV's ``((width, height), baseline)``, px) starts: above
    and right of the point (u, v), px, or mirrored to the left / below where that would leave
    the picture; in a corner, inside it however long the label."""
    (w, h), baseline = size
    rows, cols = shape[:2]
    x = int(u) + gap
    if x + w > cols - 1:
        x = int(u) - gap - w
    y = int(v) - gap  # the text's baseline
    if y - h < 0:
        y = int(v) + gap + h
    return max(0, min(x, cols - 1 - w)), max(h, min(y, rows - 1 - baseline))
