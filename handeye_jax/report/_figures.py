"""Figures of a calibration result for people: ``handeye-jax report RESULT.json [--out DIR]``.

Each figure is saved as PNG and SVG, all put in place together once all are drawn:

* ``fig3_landmarks``: the landmarks in the captured image (px) and the hand positions at the
  touches in the base frame (mm), as the paper's Fig. 3;
* ``chains_stage1``, ``chains_stage2``: the landmarks taken to the base frame by both chains,
  with the residual arrows scaled up (the same scale in both) and a length key, as the
  paper's Figs. 6 and 7;
* ``residuals``: per-landmark error lengths of both terms, for each stage;
* ``convergence``: DE's best and median F against generation, for each stage;
* ``loo``: leave-one-out (held-out) errors against the in-sample ones, for each stage;
* ``workspace_error_map`` (a result with a bootstrap, ``calibrate --bootstrap B``): how far
  the hand commands of the stage to deploy move between the bootstrap's refits, over the
  tablet area and over capture heights.

The figures need the landmark data: results carry it (``data``); for a result
without it, pass the dataset it was fitted on.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from .._core import (
    BOOTSTRAP_FIGURE,
    REPORT_FIGURES,
    REPORT_FORMATS,
    InputError,
    check_folder_output,
    write_folder_atomic,
)
from .._jax import fast_compile, in_float64
from ..calibration import CalibrationResult, load_result
from ..data import Observations, load_dataset
from ..optim import CHUNK_GENERATIONS
from ..problem import chain_points, stage1_errors, stage2_errors, touch_groups
from ._verdict import contradicted, mm_text

DPI = 120
#: Residual arrows are drawn this many times their length in both stages' figures (which say
#: so), so that arrows of the two stages compare at a glance.
ARROW_SCALE = 10.0
#: The length key below the arrows shows an error of this many mm.
KEY_MM = 1.0


class ChainPlotData:
    """Base-frame x-y points (mm) of one stage for the chain figures."""

    def __init__(self, image_xy, tablet_xy, hand_pred_xy, hand_target_xy):
        self.image_xy = np.asarray(image_xy)
        self.tablet_xy = np.asarray(tablet_xy)
        self.hand_pred_xy = np.asarray(hand_pred_xy)
        self.hand_target_xy = np.asarray(hand_target_xy)


def _observations(result: CalibrationResult) -> Observations:
    return result.data.observations()


@in_float64
def chain_data(result: CalibrationResult) -> tuple[ChainPlotData, ChainPlotData]:
    """Both stages' points in the base frame, recomputed from the result and its data."""
    obs = _observations(result)
    s1, s2 = _chain_arrays(result.model, result.correction, obs)
    return ChainPlotData(*map(np.asarray, s1)), ChainPlotData(*map(np.asarray, s2))


@fast_compile  # one small program, not one per operation (2.9 s -> 0.5 s here)
def _chain_arrays(model, correction, obs: Observations):
    points = chain_points(model, obs)
    e1 = stage1_errors(points)
    e2, _ = stage2_errors(correction, points, obs.centre_index)
    s1 = (points.image_xy, points.tablet_xy, points.hand_target_xy + e1.hand,
          points.hand_target_xy)  # fmt: skip
    s2 = (points.tablet_xy + e2.image_vs_tablet, points.tablet_xy,
          points.hand_target_xy + e2.hand, points.hand_target_xy)  # fmt: skip
    return s1, s2


# -- figures -----------------------------------------------------------------------------


@contextlib.contextmanager
def _drawing() -> Iterator[None]:
    """Matplotlib's own defaults, whatever the user's matplotlibrc says (a font without "×"
    or "−" would warn and draw boxes), and no warnings about layout or fonts on stderr."""
    import matplotlib.style

    with matplotlib.style.context("default"), warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        yield


def _figure(**kwargs):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(layout="constrained", **kwargs)
    FigureCanvasAgg(fig)
    return fig


def _label_points(ax, xy, dx=0.0, dy=0.0, labels=None, **kwargs):
    """Number each point (``labels``, default its index); a label at a point already
    labelled so (one landmark's rows from several captures) is written once."""
    done = set()
    for m, (x, y) in enumerate(xy):
        text = str(m if labels is None else int(labels[m]))
        key = (text, round(float(x), 6), round(float(y), 6))
        if key in done:
            continue
        done.add(key)
        ax.annotate(text, (x, y), xytext=(4 + dx, 4 + dy), textcoords="offset points",
                    fontsize=9, **kwargs)  # fmt: skip


def _row_landmarks(data) -> np.ndarray | None:
    """The landmark of each row of the fit (several captures), or None (one per landmark)."""
    if data is None or data.is_simple():
        return None
    return data.touch_landmark[data.rows()[2]]


def fig_landmarks(result: CalibrationResult):
    """The paper's Fig. 3: landmarks in the image, hand positions in the base frame."""
    data = result.data
    image = np.concatenate([c.image_px for c in data.captures])
    hand = np.asarray(data.hand_xy_mm)
    fig = _figure(figsize=(11, 4.8))
    ax1, ax2 = fig.subplots(1, 2)
    for c, cap in enumerate(data.captures):  # one colour per picture
        label = "landmark m in the image"
        if len(data.captures) > 1:
            z = cap.hand_position_mm[2]
            label = f"capture {c} (hand z {z:.0f} mm, θ {cap.hand_angle_deg:.0f} deg)"
        ax1.plot(cap.image_px[:, 0], cap.image_px[:, 1], "o", color=f"C{c}", label=label)
        _label_points(ax1, cap.image_px, labels=cap.landmarks)
    ax1.plot(data.camera.cx_px, data.camera.cy_px, "+", color="k", ms=12,
             label="principal point")  # fmt: skip
    ax1.set_xlim(0, max(640.0, image[:, 0].max() + 40))
    ax1.set_ylim(max(480.0, image[:, 1].max() + 40), 0)  # image rows grow downwards
    ax1.set_aspect("equal")
    ax1.set_xlabel("u (px)")
    ax1.set_ylabel("v (px)")
    ax1.set_title("landmarks in the captured image")
    if len(data.captures) > 1:  # below the axes: the pictures' points fill them
        ax1.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), fontsize=8, ncol=2)
    else:
        ax1.legend(loc="lower right", fontsize=9)
    ax2.plot(hand[:, 0], hand[:, 1], "s", color="C1", label="hand position at touch m")
    _label_points(ax2, hand, labels=data.touch_landmark)
    capture = np.array([c.hand_position_mm for c in data.captures])
    ax2.plot(capture[:, 0], capture[:, 1], "*", color="k", ms=12, label="hand at capture")
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.set_xlabel("x, base frame (mm)")
    ax2.set_ylabel("y, base frame (mm)")
    ax2.set_title("hand positions in the base frame")
    ax2.legend(loc="best", fontsize=9)
    ax2.grid(alpha=0.3)
    fig.suptitle(f"{result.dataset_name}: the data (paper's Fig. 3)")
    return fig


def fig_chains(result: CalibrationResult, data: ChainPlotData, stage: int):
    """The paper's Figs. 6 / 7: both chains in the base frame with scaled residual arrows."""
    k = ARROW_SCALE
    fig = _figure(figsize=(12, 6))
    ax1, ax2 = fig.subplots(1, 2)
    image_label = "image chain x_bi" if stage == 1 else "image chain after A1"
    for ax, pred, target, names in (
        (ax1, data.image_xy, data.tablet_xy, (image_label, "tablet chain x_bt")),
        (ax2, data.hand_pred_xy, data.hand_target_xy,
         ("hand command from the image" + (" (A2)" if stage == 2 else ""),
          "hand at touch, touch error removed")),
    ):  # fmt: skip
        ax.plot(target[:, 0], target[:, 1], "o", mfc="none", color="C1", ms=8, label=names[1])
        ax.plot(pred[:, 0], pred[:, 1], ".", color="C0", ms=7, label=names[0])
        d = pred - target
        q = ax.quiver(target[:, 0], target[:, 1], k * d[:, 0], k * d[:, 1], angles="xy",
                      scale_units="xy", scale=1, color="C3", width=0.004,
                      label=f"error ×{k:g}, arrow from ○ to •")  # fmt: skip
        key_xy = _chain_limits(ax, np.concatenate([target, pred, target + k * d]), k * KEY_MM)
        # The length key: the arrow an error of KEY_MM has. With the label on its right
        # ("E"), quiverkey puts the arrow's tip at the given point.
        ax.quiverkey(q, *key_xy, k * KEY_MM, f"{KEY_MM:g} mm error", labelpos="E",
                     coordinates="data", fontproperties={"size": 8})  # fmt: skip
        _label_points(ax, target, dx=2, dy=-14, labels=_row_landmarks(result.data),
                      color="0.3")  # fmt: skip
        ax.set_xlabel("x, base frame (mm)")
        ax.set_ylabel("y, base frame (mm)")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.11), ncols=2, fontsize=8)
    s = result.stage1 if stage == 1 else result.stage2
    ax1.set_title(f"image vs tablet: f1 = {s.f1:.3f} mm")
    ax2.set_title(f"hand vs target: f2 = {s.f2:.3f} mm")
    fig.suptitle(
        f"stage {stage}: landmarks in the base frame by both chains, F = {s.F:.4f} mm "
        f"(errors drawn ×{k:g})"
    )
    return fig


def _chain_limits(ax, xy: np.ndarray, key_mm: float) -> tuple[float, float]:
    """Equal-aspect limits around ``xy`` (mm) with a strip at the bottom for the length key
    (an arrow ``key_mm`` long and its label); returns where the key's tip goes, mm."""
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    span = max(float((hi - lo).max()), 6.0 * key_mm, 1e-9)
    pad = 0.06 * span
    strip = 0.1 * span  # below the data: the key never covers a point or an arrow
    # Data limits, not fixed ones: the equal aspect then widens one range to fit the panel.
    ax.update_datalim([(lo[0] - pad, lo[1] - pad - strip), (hi[0] + pad, hi[1] + pad)])
    ax.autoscale_view()
    ax.set_aspect("equal", adjustable="datalim")
    return lo[0] - pad + 0.3 * pad + key_mm, lo[1] - pad - 0.5 * strip


def _bars(ax, values: list[np.ndarray], labels: list[str], colors: list[str]):
    n = len(values[0])
    width = 0.8 / len(values)
    x = np.arange(n)
    for i, (v, lab, c) in enumerate(zip(values, labels, colors, strict=True)):
        ax.bar(x + (i - (len(values) - 1) / 2) * width, v, width, label=lab, color=c)
    ax.set_xticks(x)
    ax.set_xlabel("landmark m")
    ax.set_ylabel("error length (mm)")
    ax.grid(axis="y", alpha=0.3)


def _legend_below(fig, ax) -> None:
    """One legend for both panels, below them: inside an axes it would cover a bar."""
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncols=4,
               fontsize=9)  # fmt: skip


def fig_residuals(result: CalibrationResult):
    """Per-landmark error lengths of both terms, for each stage."""
    fig = _figure(figsize=(11, 4.5))
    axes = fig.subplots(1, 2, sharey=True)
    for ax, s, name in zip(axes, (result.stage1, result.stage2), ("stage 1", "stage 2"),
                           strict=True):  # fmt: skip
        e1 = np.array([r.image_vs_tablet_mm for r in s.residuals_mm])
        e2 = np.array([r.hand_mm for r in s.residuals_mm])
        _bars(ax, [e1, e2], ["|image − tablet|", "|hand − target|"], ["C0", "C1"])
        ax.set_title(f"{name}\nf1 = {s.f1:.3f} mm, f2 = {s.f2:.3f} mm, F = {s.F:.3f} mm")
    fig.suptitle("residual of every landmark (in-sample)")
    _legend_below(fig, axes[0])
    return fig


def fig_convergence(result: CalibrationResult):
    """DE's best and median F against generation, for each stage."""
    from matplotlib.ticker import LogFormatter

    fig = _figure(figsize=(11, 4.5))
    axes = fig.subplots(1, 2)
    for ax, s, name in zip(axes, (result.stage1, result.stage2), ("stage 1", "stage 2"),
                           strict=True):  # fmt: skip
        c = s.convergence
        best = np.asarray(c.best_F_mm or [], dtype=float)
        if best.size:
            ax.plot(np.arange(1, best.size + 1), best, color="C0", label="best F")
        med = np.asarray(c.median_F_mm or [], dtype=float)
        if med.size:
            every = f"every {CHUNK_GENERATIONS} generations"
            ax.plot(c.median_generation, med, "o-", color="C1", ms=4,
                    label=f"median F of the population ({every})")  # fmt: skip
        ax.axhline(s.F, color="0.3", ls="--", lw=1, label=f"after LM polish: {s.F:.4f} mm")
        ax.set_yscale("log")
        # Plain numbers (2, 5, 10, not 2×10^0); labels between the powers of ten only where
        # they fit: all below 0.7 decades, 2, 3, 4, 6 up to two, none above (LogFormatter).
        ax.yaxis.set_major_formatter(LogFormatter())
        ax.yaxis.set_minor_formatter(LogFormatter(labelOnlyBase=False, minor_thresholds=(2, 0.7)))
        ax.set_xlabel("DE generation")
        ax.set_ylabel("F (mm)")
        generations = "?" if s.de.generations is None else s.de.generations
        ax.set_title(f"{name}: {generations} generations")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=9)
    fig.suptitle("differential evolution: convergence")
    return fig


def fig_loo(result: CalibrationResult):
    """Held-out (leave-one-out) against in-sample error of each landmark, for each stage."""
    fig = _figure(figsize=(11, 4.5))
    axes = fig.subplots(1, 2, sharey=True)
    diag = result.diagnostics
    legend_from = None
    for ax, key, s, name in zip(axes, ("stage1", "stage2"), (result.stage1, result.stage2),
                                ("stage 1", "stages 1 + 2 (pipeline)"), strict=True):  # fmt: skip
        stage = None if diag is None else getattr(diag, key)
        loo = None if stage is None else stage.loo
        if not loo:
            ax.text(0.5, 0.5, "no leave-one-out in this result", ha="center",
                    transform=ax.transAxes)  # fmt: skip
            ax.set_axis_off()
            continue
        held = np.array([r.image_vs_tablet_mm + r.hand_mm for r in loo.held_out_mm])
        ins = np.array([r.image_vs_tablet_mm + r.hand_mm for r in s.residuals_mm])
        if len(ins) != len(held) and result.data is not None:  # held out by touch: its rows'
            group = touch_groups(result.data.observations())  # in-sample mean beside it
            ins = np.array([ins[group == t].mean() for t in range(len(held))])
        _bars(ax, [ins, held], ["in-sample", "held out (refit without m)"], ["0.6", "C3"])
        ax.set_ylabel("|image − tablet| + |hand − target| (mm)")
        ax.set_title(f"{name}\nheld-out F = {loo.F_mm:.3f} mm, in-sample F = {s.F:.3f} mm")
        legend_from = ax
    fig.suptitle("leave-one-out: does the fit predict a landmark it has not seen?\n"
                 + verdict_title(result))
    if legend_from is not None:
        _legend_below(fig, legend_from)
    return fig


def fig_workspace_error_map(result: CalibrationResult):
    """The workspace error map of the stage to deploy: the bootstrap's command spread (mm)
    over the tablet area, from the first capture, and against the capture's height."""
    boot = result.diagnostics.bootstrap
    m = boot.map
    fig = _figure(figsize=(12, 5.2))
    ax1, ax2 = fig.subplots(1, 2, width_ratios=(1.15, 1))
    xs, ys, spread = np.asarray(m.grid_x_mm), np.asarray(m.grid_y_mm), np.asarray(m.spread_mm)
    mesh = ax1.pcolormesh(xs, ys, spread, shading="gouraud", cmap="viridis", vmin=0.0)
    bar = fig.colorbar(mesh, ax=ax1, shrink=0.9)
    bar.set_label("command spread, mean over refits (mm)")
    marks = np.asarray(m.landmarks_mm)
    ax1.plot(marks[:, 0], marks[:, 1], "o", mfc="white", mec="k", ms=8,
             label="landmark (drawn on the tablet)")  # fmt: skip
    import matplotlib.patheffects as pe

    _label_points(ax1, marks, color="black", fontweight="bold",
                  path_effects=[pe.withStroke(linewidth=2.5, foreground="white")])  # fmt: skip
    ax1.set_xlim(xs[0], xs[-1])
    ax1.set_ylim(ys[-1], ys[0])  # the display's y grows down, as on the screen
    ax1.set_aspect("equal")
    ax1.set_xlabel("tablet x (mm)")
    ax1.set_ylabel("tablet y, down the screen (mm)")
    ax1.set_title(f"over the tablet, seen from the first capture (hand z {m.capture_z_mm:.0f} mm)",
                  fontsize=10)  # fmt: skip
    ax1.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), fontsize=9)
    z = m.capture_z_mm + np.asarray(m.rises_mm)
    ax2.plot(z, m.height_mean_mm, "o-", color="C0", label="bootstrap: mean")
    ax2.plot(z, m.height_p95_mm, "s--", color="C0", mfc="none",
             label="bootstrap: 95th percentile")  # fmt: skip
    if m.height_predicted_mm is not None:
        ax2.plot(z, m.height_predicted_mm, "^:", color="C1",
                 label="covariance's prediction: mean")  # fmt: skip
    heights = sorted({float(c.hand_position_mm[2]) for c in result.data.captures})
    for i, h in enumerate(heights):
        ax2.axvline(h, color="0.4", lw=1, ls="-.",
                    label="capture height of the calibration" if i == 0 else None)  # fmt: skip
    from matplotlib.ticker import FixedLocator, FormatStrFormatter, NullFormatter

    # Log scale: the spread at the calibration's own height and far from it both read; ticks
    # at 1, 2, 5 × 10^k as plain numbers.
    ax2.set_yscale("log")
    ax2.yaxis.set_major_locator(FixedLocator([f * 10.0**k for k in range(-4, 5)
                                              for f in (1, 2, 5)]))  # fmt: skip
    ax2.yaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax2.yaxis.set_minor_formatter(NullFormatter())
    ax2.set_xlabel("hand height at the capture (mm)")
    ax2.set_ylabel("command spread (mm, log scale)")
    ax2.set_title("the same landmarks seen from higher or lower captures", fontsize=10)
    ax2.grid(alpha=0.3, which="both")
    ax2.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncols=2, fontsize=9)
    fig.suptitle(
        f"workspace error map, stage {boot.stage}: how far hand commands move between "
        f"{boot.fitted} bootstrap refits\nover the landmarks: {mm_text(boot.spread_mean_mm)} "
        f"mean, {mm_text(boot.spread_p95_mm)} 95th percentile"
        + ("" if boot.touching_mean_mm is None else
           f"; expected touching error {mm_text(boot.touching_mean_mm)} mean")
    )  # fmt: skip
    return fig


def verdict_title(result: CalibrationResult) -> str:
    """The summary's verdict in one line: the stage to deploy and the touching error to
    expect (mm), as the summary prints them."""
    line = f"verdict: deploy stage {result.deploy_stage}"
    expected = None if result.diagnostics is None else result.diagnostics.expected
    if expected is not None and contradicted(result) is None:
        line += (f"; expected touching error {mm_text(expected.mean_mm)} mean, "
                 f"{mm_text(expected.p95_mm)} 95th percentile")  # fmt: skip
    return line


# -- driver ------------------------------------------------------------------------------


def render(result: CalibrationResult) -> dict[str, Any]:
    """All figures of a result (matplotlib Figures) by name; needs ``result.data``."""
    s1, s2 = chain_data(result)
    with _drawing():
        figures = {
            "fig3_landmarks": fig_landmarks(result),
            "chains_stage1": fig_chains(result, s1, 1),
            "chains_stage2": fig_chains(result, s2, 2),
            "residuals": fig_residuals(result),
            "convergence": fig_convergence(result),
            "loo": fig_loo(result),
        }
        if has_error_map(result):
            figures[BOOTSTRAP_FIGURE] = fig_workspace_error_map(result)
        return figures


def has_error_map(result: CalibrationResult) -> bool:
    """The result carries a bootstrap with its workspace error map."""
    d = result.diagnostics
    return d is not None and d.bootstrap is not None and d.bootstrap.map is not None


def write_report(
    result_path: str | Path,
    out_dir: str | Path | None = None,
    dataset: str | Path | None = None,
    *,
    field: str = "",
) -> list[Path]:
    """Draw every figure of a result file and write them (PNG and SVG) into ``out_dir``.

    Args:
        result_path: a ``handeye-jax.result/1`` file.
        out_dir: where to write; default ``<result stem>_report`` next to the result. Created
            if its parent exists.
        dataset: the dataset the result was fitted on; needed only if the result does not
            carry its data (older results).
        field: how errors about ``out_dir`` name it (the command line's ``"--out"``).

    Returns:
        The files written. Nothing is written unless every figure was drawn and every file
        can be put in place; on any failure the folder is as it was.
    """
    result_path = Path(result_path)
    result = load_result(result_path)
    if dataset is not None:
        ds = load_dataset(dataset)
        fitted = len(result.stage1.residuals_mm)
        if fitted and ds.n_landmarks != fitted:
            raise InputError(dataset, "landmarks", f"{ds.n_landmarks} landmarks, but the "
                             f"result was fitted on {fitted}")  # fmt: skip
        result = dataclasses.replace(result, data=ds)
    if result.data is None:
        raise InputError(result_path, "data",
                         "missing (a result from an older version): pass --dataset")  # fmt: skip
    out = Path(out_dir) if out_dir is not None else result_path.with_name(
        f"{result_path.stem}_report"
    )  # fmt: skip
    drawn = (*REPORT_FIGURES, *((BOOTSTRAP_FIGURE,) if has_error_map(result) else ()))
    names = [f"{name}.{ext}" for name in drawn for ext in REPORT_FORMATS]
    check_folder_output(out, names, field, [result_path, dataset])
    rendered = {}
    figures = render(result)
    with _drawing():
        for name, fig in figures.items():
            for ext in REPORT_FORMATS:
                buf = io.BytesIO()
                fig.savefig(buf, format=ext, dpi=DPI)
                rendered[f"{name}.{ext}"] = buf.getvalue()
    return write_folder_atomic(out, rendered, field)
