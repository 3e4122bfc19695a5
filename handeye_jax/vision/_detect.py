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


def _spread(points: np.ndarray, among: np.ndarray | None = None) -> bool:
    """Whether some four of the points have no three nearly in a row (:data:`MIN_TRIANGLE`
    of the nearest two of ``among``, by default the points themselves)."""
    among = points if among is None else among
    spacing = min(np.linalg.norm(a - b) for a, b in itertools.combinations(among, 2))
    return bool(_frames(points)[2].max() >= MIN_TRIANGLE * spacing**2)


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
    ordered as the latter: keep the tablet's x axis roughly along the picture's u axis. A
    layout whose outermost four have three nearly in a row (a staircase or an L of at most
    :data:`MAX_PARTIAL_LANDMARKS` landmarks), or a picture of it, fixes no map that way: it
    is matched as :func:`match_blobs` matches a part (within that function's bounds on the
    view).

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
    try:
        q_layout = _max_area_quad(layout_px, "drawn landmarks (tablet_px)")
        q_blobs = _max_area_quad(blobs_px, "blobs")
        spread = _spread(layout_px[q_layout], layout_px) and _spread(blobs_px[q_blobs], blobs_px)
    except ValueError:
        if n > MAX_PARTIAL_LANDMARKS or not (_spread(layout_px) and _spread(blobs_px)):
            raise
        spread = False
    if not spread and n <= MAX_PARTIAL_LANDMARKS:
        # Three of the outermost four in a row (a staircase, an L) fix no map: match the
        # whole layout as a part is matched.
        return match_blobs(blobs_px, layout_px)[1]
    spacing = np.min([np.linalg.norm(a - b) for a, b in itertools.combinations(blobs_px, 2)])
    candidates = [m for m in (_corner_match(blobs_px, layout_px, q_layout, np.roll(ring, turn))
                              for ring in (q_blobs, q_blobs[::-1]) for turn in range(4))
                  if m is not None]  # fmt: skip
    if not candidates:
        raise ValueError("no turn or mirror of the drawn layout matches the blobs one to one")
    best_rms = min(c[0] for c in candidates)
    good = [c for c in candidates if c[0] <= best_rms + 0.1 * spacing]
    # Prefer unmirrored matches, then tablet +x along +u.
    good.sort(key=lambda c: (not c[2], -c[1]))
    return good[0][3]


def _corner_match(blobs_px, layout_px, q_layout, q_blobs):
    """The layout's outermost four mapped onto the blobs' four ``q_blobs`` (in that order), and
    every landmark onto its nearest blob: ``(rms px, cos of tablet +x from +u, unmirrored,
    order)``, or ``None`` if two landmarks take one blob."""
    n = len(layout_px)
    H = cv2.getPerspectiveTransform(
        layout_px[q_layout].astype(np.float32), blobs_px[q_blobs].astype(np.float32)
    )
    mapped = cv2.perspectiveTransform(layout_px[None].astype(np.float64), H)[0]
    dist = np.linalg.norm(mapped[:, None] - blobs_px[None], axis=2)
    order = dist.argmin(axis=1)
    if len(set(order.tolist())) != n:
        return None
    rms = float(np.sqrt(np.mean(dist[np.arange(n), order] ** 2)))
    # Direction of tablet +x in the picture, at the layout's centre.
    c = layout_px.mean(axis=0)
    ends = cv2.perspectiveTransform(np.array([[c, c + [1.0, 0.0]]]), H)[0]
    x_dir = ends[1] - ends[0]
    cos_u = x_dir[0] / (np.linalg.norm(x_dir) + 1e-300)
    return rms, cos_u, np.linalg.det(H[:2, :2]) > 0, order


#: Most landmarks for which :func:`match_blobs` tries every subset (C(n, 4) quadrilaterals).
MAX_PARTIAL_LANDMARKS = 16


#: Largest ratio of the two scales of a layout-to-picture map in :func:`match_blobs`: a
#: camera that looks at the tablet less than about 48 deg off its normal.
MAX_ANISOTROPY = 1.5
#: A match whose tablet x axis is within this of +u in the picture is a plausible reading.
PLAUSIBLE_TURN_DEG = 55.0
#: Four points fix a homography only if no three of them are nearly on a line: in
#: :func:`match_blobs` (and :func:`order_blobs`) the smallest triangle three of four blobs
#: make must cover at least this fraction of the square of the nearest two blobs' distance
#: (a cell of a square grid gives 0.5; three dots of one row give 0, plus noise).
MIN_TRIANGLE = 0.1


def _frames(points: Float[np.ndarray, "n 2"]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every four of the points, as the four correspondences that fix a homography.

    Returns:
        ``(quads, convex, area)``: each four's indices ``(m, 4)``, in order around their
        quadrilateral if they are its corners (``convex``), else the three around the
        triangle that holds the fourth, then the fourth; and the smallest triangle three
        of them make, px² (near 0 when three are nearly on a line, which fixes no map).
    """
    quads = np.array(list(itertools.combinations(range(len(points)), 4))).reshape(-1, 4)
    p = points[quads]
    # twice the area of the triangle without corner i, for each i
    others = ((1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2))
    tri = np.stack([np.abs(_cross(p[:, b] - p[:, a], p[:, c] - p[:, a])) for a, b, c in others],
                   axis=1)  # fmt: skip
    # A corner inside the triangle of the other three: that triangle is the other three's sum.
    convex = tri.max(axis=1) < 0.5 * tri.sum(axis=1) * (1 - 1e-9)
    inner = ~convex[:, None] & (np.arange(4) == tri.argmax(axis=1)[:, None])
    centre = p.mean(axis=1, keepdims=True)
    angle = np.arctan2(p[..., 1] - centre[..., 1], p[..., 0] - centre[..., 0])
    # around the centre, the inner corner (angles are at most pi) last
    quads = np.take_along_axis(quads, np.argsort(np.where(inner, 10.0, angle), axis=1), axis=1)
    return quads, convex, 0.5 * tri.min(axis=1)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _rings(frame: Int[np.ndarray, " 4"], convex: bool) -> Int[np.ndarray, "r 4"]:
    """Each way four points in order can meet another four of the same kind: the corners of
    a quadrilateral in each of 4 turns and 2 senses; a triangle's in 3 and 2, the inner last."""
    m = 4 if convex else 3
    ring = [np.r_[np.roll(frame[:m][::s], t), frame[m:]] for s in (1, -1) for t in range(m)]
    return np.array(ring)


def _fit_homographies(
    src: Float[np.ndarray, "m p 2"], dst: Float[np.ndarray, "m p 2"]
) -> Float[np.ndarray, "m 3 3"]:
    """The homography taking each ``src`` onto its ``dst``: exact for 4 points (what
    ``cv2.getPerspectiveTransform`` does), least squares in the algebraic error for more; all at
    once. Both are scaled to about unit size first (Hartley's normalisation)."""

    def normaliser(pts):
        c = pts.reshape(-1, 2).mean(axis=0)
        s = np.sqrt(2.0) / np.mean(np.linalg.norm(pts.reshape(-1, 2) - c, axis=1))
        return np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])

    Ts, Td = normaliser(src), normaliser(dst)
    a, b = src @ Ts[:2, :2].T + Ts[:2, 2], dst @ Td[:2, :2].T + Td[:2, 2]
    x, y, u, v = a[..., 0], a[..., 1], b[..., 0], b[..., 1]
    zero, one = np.zeros_like(x), np.ones_like(x)
    A = np.concatenate([np.stack([x, y, one, zero, zero, zero, -u * x, -u * y], axis=-1),
                        np.stack([zero, zero, zero, x, y, one, -v * x, -v * y], axis=-1)],
                       axis=1)  # fmt: skip
    rhs = np.concatenate([u, v], axis=1)[..., None]
    At = np.swapaxes(A, 1, 2)
    h = np.linalg.solve(At @ A, At @ rhs)[..., 0]
    Hn = np.concatenate([h, np.ones((len(h), 1))], axis=1).reshape(-1, 3, 3)
    return np.linalg.inv(Td) @ Hn @ Ts


def _project(H: Float[np.ndarray, "m 3 3"], points: Float[np.ndarray, "n 2"]):
    """The points mapped by each ``H``, px, ``(m, n, 2)``, and whether each ``H`` keeps all of
    them in front of the camera (on one side of the line it sends to infinity), ``(m,)``.
    A map that puts some landmarks behind the camera folds the tablet: no camera sees that."""
    p = np.einsum("mij,nj->mni", H, np.c_[points, np.ones(len(points))])
    w = p[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):  # w = 0: on the horizon, not in front
        return p[..., :2] / w[..., None], w.min(axis=-1) * w.max(axis=-1) > 0


def _local_maps(H: Float[np.ndarray, "m 3 3"], at_px: Float[np.ndarray, "2"]):
    """How each ``H`` maps the tablet near the point ``at_px``: the direction of tablet +x in
    the picture (deg from +u), the ratio of its largest to its smallest scale, and whether it
    keeps handedness (unmirrored); each ``(m,)``."""
    p = H @ np.append(at_px, 1.0)
    uv = p[:, :2] / p[:, 2:]
    # the Jacobian of the map; columns: the images of tablet x and y
    J = (H[:, :2, :2] - uv[:, :, None] * H[:, None, 2, :2]) / p[:, 2, None, None]
    s = np.linalg.svd(J, compute_uv=False)
    x_deg = np.degrees(np.arctan2(J[:, 1, 0], J[:, 0, 0]))
    return x_deg, s[:, 0] / np.maximum(s[:, 1], 1e-300), np.linalg.det(J) > 0


def _nearest(blobs_px: np.ndarray, mapped: np.ndarray) -> np.ndarray:
    """The mapped landmark nearest each blob, ``(m, k)``."""
    return np.linalg.norm(blobs_px[None, :, None] - mapped[:, None], axis=3).argmin(axis=2)


def _readings(blobs_px: np.ndarray, layout_px: np.ndarray, frame: np.ndarray, convex: bool):
    """Every landmark of each blob, ``(r, k)``, that four landmarks mapped onto the four blobs
    ``frame`` (of the same kind, in each way they can meet) give one to one, with every
    landmark in front of the camera."""
    quads, kind, area = _frames(layout_px)
    spacing = min(np.linalg.norm(a - b) for a, b in itertools.combinations(layout_px, 2))
    # No three landmarks nearly on a line: their picture would be too (a plausible view changes
    # the ratio by at most its anisotropy, hence the margin).
    quads = quads[(kind == convex) & (area >= MIN_TRIANGLE / 3 * spacing**2)]
    rings = _rings(frame, convex)
    src = np.repeat(layout_px[quads], len(rings), axis=0)
    dst = np.tile(blobs_px[rings], (len(quads), 1, 1))
    mapped, in_front = _project(_fit_homographies(src, dst), layout_px)
    which = _nearest(blobs_px, mapped)
    one_to_one = np.all(np.diff(np.sort(which, axis=1), axis=1) > 0, axis=1)
    return np.unique(which[in_front & one_to_one], axis=0)


def _assess(H, which, blobs_px, layout_px, max_anisotropy):
    """Which readings ``which`` (``(r, k)``) a camera could see through their maps ``H``:
    every landmark in front, each blob's landmark mapped nearest it, the two scales within
    ``max_anisotropy`` (a shear can map a part onto another part); and each reading's rms
    distance from the blobs (px), its tablet x axis (deg from +u) and handedness."""
    mapped, in_front = _project(H, layout_px)
    x_deg, anisotropy, unmirrored = _local_maps(H, layout_px.mean(axis=0))
    gap = np.take_along_axis(mapped, which[..., None], axis=1) - blobs_px
    ok = in_front & np.all(_nearest(blobs_px, mapped) == which, axis=1)
    ok &= anisotropy <= max_anisotropy
    return ok, np.sqrt(np.mean(np.sum(gap**2, axis=2), axis=1)), x_deg, unmirrored


def match_blobs(
    blobs_px: Float[np.ndarray, "k 2"], layout_px: Float[np.ndarray, "n 2"]
) -> tuple[Int[np.ndarray, " k"], Int[np.ndarray, " k"]]:
    """Which landmark each blob is, when the picture shows only some of them (``k <= n``).

    Four blobs that fix a homography are chosen: the four whose smallest triangle (of three
    of them) is the largest, so that no three are nearly on a line. Every four landmarks of
    the same kind (the corners of a quadrilateral, or a triangle with one inside) are mapped
    onto them, in each way they can meet; each map that pairs every blob with a different
    landmark gives a reading, whose homography is then fitted to all its pairs (by algebraic
    least squares, to sort out the readings far from plausible, then by reprojection error,
    ``cv2.findHomography``). A reading is a candidate if that map could be a camera's view
    of a flat tablet:
    every landmark in front of the camera (the map does not fold the tablet through the line
    it sends to infinity), its scales along two directions differ by at most
    :data:`MAX_ANISOTROPY` (no shear), each blob's landmark is the one mapped nearest it; and
    if it fits within 10 % of the blobs' spacing of the best reading. As in
    :func:`order_blobs`, unmirrored candidates win, then the one whose tablet x axis points
    most nearly along +u. If another candidate of the same handedness reads the blobs
    otherwise and is about as plausible (turned within 15 deg of the winner, or within
    :data:`PLAUSIBLE_TURN_DEG` of +u), the reading is ambiguous (a 2 x 3 part of a 3 x 3 grid
    may be either end): then nothing is guessed.

    Args:
        blobs_px: blob centroids, image px, ``(k, 2)``, at least 4.
        layout_px: where the landmarks are drawn, tablet px, ``(n, 2)``, at most
            :data:`MAX_PARTIAL_LANDMARKS`.

    Returns:
        ``(landmarks, order)``: the landmarks seen, ascending, and the blob of each:
        ``blobs_px[order][j]`` is landmark ``landmarks[j]``.

    Raises:
        ValueError: no match, an ambiguous one, blobs nearly on one line, or too few blobs
            or too many landmarks.
    """
    blobs_px, layout_px = np.asarray(blobs_px, float), np.asarray(layout_px, float)
    k, n = len(blobs_px), len(layout_px)
    if not 4 <= k <= n:
        raise ValueError(f"need 4 to {n} blobs to match {n} landmarks, got {k}")
    if n > MAX_PARTIAL_LANDMARKS:
        raise ValueError(f"telling which of {n} landmarks {k} blobs are is tried for at most "
                         f"{MAX_PARTIAL_LANDMARKS} landmarks; name the landmarks seen")  # fmt: skip
    spacing = np.min([np.linalg.norm(a - b) for a, b in itertools.combinations(blobs_px, 2)])
    quads, convex, area = _frames(blobs_px)
    best = area.argmax()
    if area[best] < MIN_TRIANGLE * spacing**2:
        raise ValueError(f"no four of the {k} blobs span a quadrilateral (nearly collinear?)")
    which, H = _fitted_readings(blobs_px, layout_px, quads[best], convex[best])
    ok, rms, x_deg, unmirrored = _assess(H, which, blobs_px, layout_px, MAX_ANISOTROPY)
    if not ok.any():
        raise ValueError(f"no part of the drawn layout matches the {k} blobs one to one")
    good = np.flatnonzero(ok & (rms <= rms[ok].min() + 0.1 * spacing))
    good = good[np.lexsort((-np.cos(np.radians(x_deg[good])), ~unmirrored[good]))]
    first = good[0]
    for other in good[1:]:  # another reading about as plausible: nothing is guessed
        turned = abs((x_deg[other] - x_deg[first] + 180.0) % 360.0 - 180.0)
        plausible = turned < 15.0 or abs(x_deg[other]) < PLAUSIBLE_TURN_DEG
        if unmirrored[other] == unmirrored[first] and plausible:
            a, b = (sorted(which[c].tolist()) for c in (first, other))
            raise ValueError(f"the {k} blobs fit landmarks {a} as well as {b}; name the "
                             "landmarks seen")  # fmt: skip
    order = np.argsort(which[first])
    return which[first][order], order


def _fitted_readings(blobs_px, layout_px, frame, convex):
    """The readings (:func:`_readings`) from the four blobs ``frame`` that a camera might see,
    ``(r, k)``, each with its homography fitted to all its pairs by reprojection error,
    ``(r, 3, 3)``. Least squares in the algebraic error, all at once, first sorts out the
    readings no camera sees (with a margin)."""
    k = len(blobs_px)
    which = _readings(blobs_px, layout_px, frame, convex)
    if not len(which):
        raise ValueError(f"no part of the drawn layout matches the {k} blobs one to one")
    H = _fit_homographies(layout_px[which], np.broadcast_to(blobs_px, (len(which), k, 2)))
    which = which[_assess(H, which, blobs_px, layout_px, 1.5 * MAX_ANISOTROPY)[0]]
    fits = [(w, cv2.findHomography(layout_px[w], blobs_px, 0)[0]) for w in which]
    fits = [(w, H) for w, H in fits if H is not None]
    if not fits:
        raise ValueError(f"no part of the drawn layout matches the {k} blobs one to one")
    return np.array([w for w, _ in fits]), np.array([H for _, H in fits])


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
