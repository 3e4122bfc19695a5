"""Render what the twin's RGB-D camera sees of the tablet: a colour picture and a depth image.

The display is projected into the camera through the twin's true chain
(:meth:`~handeye_jax.twin.TwinTruth.project`). Each landmark dot is a square of ``dot_px``
tablet px; the paper's one-pixel dot is about 0.7 image px wide, so it lands as a small blob
only through the lens's point-spread function. The dot is sampled on a fine grid in the tablet
plane and each sample's darkness is spread over the pixels by the exact integral of a Gaussian
PSF over each pixel's area, so the picture's intensity-weighted centroid has no pixel-locking
bias. Image coordinates follow OpenCV: pixel ``(row v, column u)`` has its centre at ``(u, v)``.

The depth image holds the distance along the optical axis to the display plane at each pixel
centre, in mm, as ``uint16`` (RealSense convention: 0 means no measurement).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from jax.scipy.special import ndtr
from jaxtyping import Float, UInt8, UInt16

from .._jax import in_float64
from ._truth import TwinTruth

# Linear radiance of the lit display, of a black display pixel and of the bezel, 0..1.
DISPLAY_WHITE = 0.92
DISPLAY_BLACK = 0.03
BEZEL = 0.06
# Sub-samples per side of each dot, and the supersampling of the display outline.
DOT_SAMPLES = 12
OUTLINE_SUPERSAMPLING = 4


@dataclass(frozen=True)
class Imaging:
    """How the picture departs from the ideal.

    Attributes:
        blur_px: σ of extra Gaussian blur (defocus) on top of the lens PSF, image px.
        noise_levels: σ of the sensor noise, grey levels (0–255).
        vignetting: fractional darkening at the picture's corners (0 = none).
        gamma: the encoding gamma, ``I = 255·L^(1/γ)`` (1 = linear).
    """

    blur_px: float = 0.0
    noise_levels: float = 0.0
    vignetting: float = 0.0
    gamma: float = 1.0


@dataclass(frozen=True)
class DepthSensing:
    """How the depth image departs from the truth.

    Attributes:
        noise_mm: σ of Gaussian depth noise, mm.
        step_mm: depths are rounded to multiples of this, mm (1 = the file's own unit).
        holes: fraction of pixels with no measurement (written as 0).
    """

    noise_mm: float = 0.0
    step_mm: float = 1.0
    holes: float = 0.0


@in_float64
def _pixel_weights(centres: np.ndarray, lo: int, n: int, sigma: float) -> np.ndarray:
    """∫ over pixel k of a unit Gaussian at each centre, for pixels ``lo … lo+n-1``; (s, n)."""
    edges = np.arange(lo, lo + n + 1) - 0.5
    cdf = ndtr((edges[None, :] - centres[:, None]) / sigma)
    return np.diff(np.asarray(cdf), axis=1)


def dot_darkness(truth: TwinTruth, sigma_px: float) -> Float[np.ndarray, "h w"]:
    """Darkness the landmark dots add, blurred by the PSF and integrated over pixels, (h, w).

    In units of the display's contrast: a pixel fully covered by black reads 1.
    """
    w, h = truth.image_size_px
    k = (np.arange(DOT_SAMPLES) + 0.5) / DOT_SAMPLES - 0.5
    offsets = np.stack(np.meshgrid(k, k), axis=-1).reshape(-1, 2) * truth.dot_px
    corners = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]) * truth.dot_px
    out = np.zeros((h, w))
    reach = int(np.ceil(5 * sigma_px)) + 2
    for xy in truth.landmarks_tablet_px:
        samples, _ = truth.project(xy + offsets)
        quad, _ = truth.project(xy + corners)
        d1, d2 = quad[2] - quad[0], quad[3] - quad[1]
        area = 0.5 * abs(d1[0] * d2[1] - d1[1] * d2[0])  # image px²
        c = samples.mean(axis=0)
        u0, v0 = int(np.floor(c[0])) - reach, int(np.floor(c[1])) - reach
        n = 2 * reach + 1
        wu = _pixel_weights(samples[:, 0], u0, n, sigma_px)
        wv = _pixel_weights(samples[:, 1], v0, n, sigma_px)
        patch = (wv.T @ wu) * (area / len(samples))
        us, vs = slice(max(u0, 0), min(u0 + n, w)), slice(max(v0, 0), min(v0 + n, h))
        out[vs, us] += patch[vs.start - v0 : vs.stop - v0, us.start - u0 : us.stop - u0]
    return out


def display_coverage(truth: TwinTruth) -> Float[np.ndarray, "h w"]:
    """Fraction of each pixel covered by the lit display (area-integrated), (h, w)."""
    w, h = truth.image_size_px
    dw, dh = truth.display_px
    corners, _ = truth.project(np.array([[0.0, 0.0], [dw, 0.0], [dw, dh], [0.0, dh]]))
    s = OUTLINE_SUPERSAMPLING
    canvas = np.zeros((h * s, w * s), np.uint8)
    # Pixel centres sit at integers, so pixel (0, 0) spans [-0.5, 0.5) in image px.
    pts = np.round(((corners + 0.5) * s - 0.5) * 16).astype(np.int32)
    cv2.fillConvexPoly(canvas, pts, 255, lineType=cv2.LINE_8, shift=4)
    return cv2.resize(canvas, (w, h), interpolation=cv2.INTER_AREA).astype(float) / 255.0


def render_capture(
    truth: TwinTruth, imaging: Imaging, rng: np.random.Generator
) -> UInt8[np.ndarray, "h w 3"]:
    """The colour picture of the tablet showing the landmarks, ``uint8`` BGR ``(h, w, 3)``.

    Args:
        truth: the rig.
        imaging: blur, noise, vignetting and gamma.
        rng: the source of the sensor noise.
    """
    w, h = truth.image_size_px
    sigma = float(np.hypot(truth.lens_blur_px, imaging.blur_px))
    cover = cv2.GaussianBlur(display_coverage(truth), (0, 0), sigma)
    radiance = BEZEL + (DISPLAY_WHITE - BEZEL) * cover
    radiance -= (DISPLAY_WHITE - DISPLAY_BLACK) * dot_darkness(truth, sigma)
    if imaging.vignetting:
        v, u = np.mgrid[0:h, 0:w]
        half_w, half_h = (w - 1) / 2, (h - 1) / 2
        r2 = ((u - half_w) ** 2 + (v - half_h) ** 2) / (half_w**2 + half_h**2)
        radiance *= 1.0 - imaging.vignetting * r2
    grey = 255.0 * np.clip(radiance, 0.0, 1.0) ** (1.0 / imaging.gamma)
    if imaging.noise_levels:
        grey = grey + rng.normal(0.0, imaging.noise_levels, grey.shape)
    grey = np.clip(np.round(grey), 0, 255).astype(np.uint8)
    return cv2.merge([grey, grey, grey])


def true_depth_mm(truth: TwinTruth) -> Float[np.ndarray, "h w"]:
    """Depth of the display plane along the optical axis at every pixel centre, mm, (h, w)."""
    w, h = truth.image_size_px
    p0, px, py = truth.camera_points(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]))
    normal = np.cross(px - p0, py - p0)
    c = truth.camera_px
    v, u = np.mgrid[0:h, 0:w].astype(float)
    if truth.distortion is not None:  # each pixel sees along its undistorted ray
        u, v = np.moveaxis(truth.undistort(np.stack([u, v], -1).reshape(-1, 2)), -1, 0)
        u, v = u.reshape(h, w), v.reshape(h, w)
    rays = np.stack([(u - c["cx"]) / c["fx"], (v - c["cy"]) / c["fy"], np.ones_like(u)], -1)
    return float(normal @ p0) / (rays @ normal)


def render_depth(
    truth: TwinTruth, sensing: DepthSensing, rng: np.random.Generator
) -> UInt16[np.ndarray, "h w"]:
    """The depth image, ``uint16`` mm ``(h, w)``; 0 where there is no measurement.

    Args:
        truth: the rig.
        sensing: noise, quantisation and holes.
        rng: the source of noise and holes.
    """
    z = true_depth_mm(truth)
    if sensing.noise_mm:
        z = z + rng.normal(0.0, sensing.noise_mm, z.shape)
    z = np.round(z / sensing.step_mm) * sensing.step_mm
    if sensing.holes:
        z[rng.random(z.shape) < sensing.holes] = 0.0
    return np.clip(np.round(z), 0, np.iinfo(np.uint16).max).astype(np.uint16)
