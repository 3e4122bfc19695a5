"""Where each stage searches: a box around a closed-form estimate of the rig, or a preset.

With the ``estimate`` preset (the default) stage 1's box comes from the data. The closed-form
estimate (:func:`~handeye_jax.closed_form_estimate`: the touches by linear least squares, the
camera mount by a rigid fit of the views) gives one or two candidates (the two signs of the
tablet's tilt, when the views cannot tell them apart); Levenberg–Marquardt polishes each on
the stage's objective; the Jacobian at the lowest end gives each parameter's standard
deviation σ. Each parameter's range is then the hull of the candidates and their ends,
widened on each side by :data:`BOX_SIGMAS` σ, at least the unit's floor and at most its cap
(:data:`HALF_WIDTH`; a parameter the data do not determine gets the cap). The polished ends
are handed to the fit as starts, so it never ends above them. Nothing about the rig's place
in the robot's workspace is assumed.

With the ``paper`` preset stage 1 searches the paper's Tables 5 and 6 (the model's
``default_ranges``), exactly as before. Stage 2's corrections are small whatever the rig, so
it searches the correction's default ranges under either preset. The dataset's ``[search]``
ranges replace any of them by name.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from .._core import SEARCH_PRESETS, spec
from .._jax import single_device_mesh
from ..data import Dataset, Observations
from ..models import AbstractParametric, AffinePair, HTMModel
from ..optim import Box, minimise_many
from ..problem import (
    ClosedFormEstimate,
    Stage1Objective,
    analyse_jacobian,
    closed_form_estimate,
)
from ._programs import stage_error_jacobian, stage_report

#: Each range holds the estimates plus this many standard deviations on each side.
BOX_SIGMAS = 4.0
#: The least and the most a range reaches beyond the estimates, by unit: (floor, cap).
HALF_WIDTH: dict[str, tuple[float, float]] = {"mm": (10.0, 250.0), "deg": (5.0, 60.0),
                                              "1": (0.05, 0.5)}  # fmt: skip
#: A polished candidate is kept in the box's hull when its F is at most this factor of the
#: lowest (the sign twin's is equal); a worse one is a local optimum the box need not hold.
KEEP_F_FACTOR = 1.5
#: Where a range came from: the box around the estimate, the paper's tables, the
#: correction's (or the model's, for a parameter not searched) defaults, a recalibration's
#: previous value ± half the paper's range, the dataset's ``[search]``.
SOURCES = ("estimate", "paper", "default", "previous", "[search]")


@dataclass(frozen=True)
class SearchRange:
    """One parameter's search range, in its unit, and where it came from (one of
    :data:`SOURCES`)."""

    strict: ClassVar[bool] = True

    lower: float
    upper: float
    source: str


@dataclass(frozen=True)
class SearchReport:
    """Where a calibration searched (a result file's ``search``).

    Attributes:
        preset: ``"estimate"`` or ``"paper"``.
        stage1, stage2: each stage's ranges, by parameter.
        estimate: the closed-form estimate's parameters (the first candidate), or ``None``.
        estimate_F_mm: F (the paper's, x-y) at the lowest end of its LM polish, mm, or
            ``None``.
        sigma: each parameter's standard deviation there (its unit; ``None``: not determined),
            which set the ranges' widths, or ``None``.
        box_sigmas: how many σ each range holds beyond the estimates.
        candidates: how many polished candidates the box holds (2: the views could not tell
            the tablet tilt's sign, or both signs led to about the same F).
        fallback: why the preset's ranges were searched instead of the estimate's, or
            ``None``.
        frames_F_mm: for a model other than HTM, F of the closed-form frames themselves in
            the six-DoF chain (which holds any frames), mm: far below the model's best F, the
            model cannot hold the rig.
    """

    preset: str
    stage1: dict[str, SearchRange]
    stage2: dict[str, SearchRange]
    estimate: dict[str, float] | None = spec(omit="none", default=None)
    estimate_F_mm: float | None = spec("estimate_F", omit="none", default=None)
    sigma: dict[str, float | None] | None = spec(omit="none", default=None)
    box_sigmas: float | None = spec(omit="none", default=None)
    candidates: int | None = spec(omit="none", default=None)
    fallback: str | None = spec(omit="none", default=None)
    frames_F_mm: float | None = spec("frames_F", omit="none", default=None)

    def bounds(self, stage: str, names) -> tuple[np.ndarray, np.ndarray]:
        """``(lower, upper)`` of ``names`` in a stage (``"stage1"``, ``"stage2"``)."""
        ranges = getattr(self, stage)
        return (np.array([ranges[n].lower for n in names], dtype=float),
                np.array([ranges[n].upper for n in names], dtype=float))  # fmt: skip


@dataclass(frozen=True)
class SearchPlan:
    """Both stages' boxes (all parameters, in ``param_names`` order), the starts the
    estimate offers stage 1 (``(k, d)``, with their labels) and the report."""

    box1: Box
    box2: Box
    starts1: np.ndarray | None
    labels1: tuple[str, ...]
    report: SearchReport


def resolve_preset(dataset: Dataset, preset: str | None) -> str:
    """The preset a calibration uses: the settings', else the dataset's, else ``estimate``."""
    out = preset or dataset.search_preset or SEARCH_PRESETS[0]
    if out not in SEARCH_PRESETS:
        raise ValueError(f"unknown search preset {out!r}; known: {', '.join(SEARCH_PRESETS)}")
    return out


def _ranges(cls, lo, hi, source: str, search: dict) -> dict[str, SearchRange]:
    """``SearchRange`` per parameter, the dataset's ``[search]`` ones replacing the others."""
    out = {}
    for i, name in enumerate(cls.param_names):
        if name in search:
            out[name] = SearchRange(float(search[name][0]), float(search[name][1]), "[search]")
        else:
            out[name] = SearchRange(float(lo[i]), float(hi[i]), source)
    return out


def _box(ranges: dict[str, SearchRange], cls) -> Box:
    return Box([ranges[n].lower for n in cls.param_names],
               [ranges[n].upper for n in cls.param_names])  # fmt: skip


def _unwrapped(X: np.ndarray, units) -> np.ndarray:
    """Candidates with each angle moved by whole turns to within 180° of the first's."""
    X = np.array(X, dtype=float)
    for j, u in enumerate(units):
        if u == "deg":
            X[:, j] = X[0, j] + (X[:, j] - X[0, j] + 180.0) % 360.0 - 180.0
    return X


def _half_widths(cls, sigma: dict[str, float | None]) -> np.ndarray:
    out = []
    for name, unit in zip(cls.param_names, cls.param_units, strict=True):
        floor, cap = HALF_WIDTH.get(unit, HALF_WIDTH["1"])
        s = sigma.get(name)
        out.append(cap if s is None else float(np.clip(BOX_SIGMAS * s, floor, cap)))
    return np.array(out)


def estimate_box(
    model_cls: type, obs: Observations, estimate: ClosedFormEstimate | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Stage 1's box around the closed-form estimate (see the module).

    Returns ``(lower, upper, ends, info)``: the box, the polished candidates inside it (best
    first), and what the report records (``estimate``, ``estimate_F_mm``, ``sigma``,
    ``candidates``). Raises ``ValueError`` (the data give no estimate) or
    ``NotImplementedError`` (the model has no ``from_frames``).
    """
    from ._search import stack
    from ._stage import POLISH

    estimate = estimate or closed_form_estimate(obs)
    names, units = model_cls.param_names, model_cls.param_units
    params = [c.params(model_cls) for c in estimate.candidates]
    X = _unwrapped([[p[n] for n in names] for p in params], units)
    caps = np.array([HALF_WIDTH.get(u, HALF_WIDTH["1"])[1] for u in units])
    objective = Stage1Objective(model_cls.nominal(), obs)
    # The candidates polished as one batch on the program the fit's stage-1 polish compiles
    # anyway: one compilation fewer. The end points matched one LM run per candidate bit for
    # bit where checked (the paper's data, three twins, HTM and DH; benchmarks/RESULTS.md).
    k = len(X)
    box = Box(np.tile(X.min(axis=0) - caps, (k, 1)), np.tile(X.max(axis=0) + caps, (k, 1)))
    ends = minimise_many(stack([objective] * k), POLISH, box, x0=X, mesh=single_device_mesh())
    values = np.where(np.isfinite(ends.value), ends.value, np.inf)
    order = np.argsort(values, kind="stable")
    best = int(order[0])
    keep = [i for i in order if values[i] <= KEEP_F_FACTOR * values[best] + 1e-9]
    hull = np.vstack([X[keep], ends.x[keep]])
    e, J = (np.asarray(a) for a in stage_error_jacobian(objective, ends.x[best]))
    sigma = analyse_jacobian(e, J, names, units).std
    half = _half_widths(model_cls, sigma)
    lower, upper = hull.min(axis=0) - half, hull.max(axis=0) + half
    F = float(stage_report(objective, ends.x[best])[1][0])  # the paper's F, x-y
    info = dict(estimate=dict(zip(names, (float(v) for v in X[0]), strict=True)),
                estimate_F_mm=F, sigma=dict(sigma), candidates=len(keep),
                frames_F_mm=_frames_F(model_cls, obs, estimate))  # fmt: skip
    return lower, upper, ends.x[keep], info


def _frames_F(model_cls, obs: Observations, estimate: ClosedFormEstimate) -> float | None:
    """F of the closed-form frames themselves, unpolished, in the six-DoF chain that holds any
    frames (``None`` for that chain's own fits): a model whose best F is far above it cannot
    hold the rig."""
    if model_cls is HTMModel:
        return None
    general = Stage1Objective(HTMModel.nominal(), obs)
    values = [float(stage_report(general, np.array([c.params(HTMModel)[n] for n in
                                                HTMModel.param_names]))[1][0])
              for c in estimate.candidates]  # fmt: skip
    return min(values)


def plan_search(dataset: Dataset, model_cls: type, preset: str | None,
                obs: Observations | None = None) -> SearchPlan:  # fmt: skip
    """Both stages' boxes for a calibration of ``dataset`` with ``model_cls``, by ``preset``
    (``None``: the dataset's, else ``estimate``), the dataset's ``[search]`` ranges replacing
    any by name. Falls back to the paper's ranges, saying why, when the data give no
    estimate or the model has no conversion from frames."""
    preset = resolve_preset(dataset, preset)
    search = dataset.search
    ranges2 = _ranges(AffinePair, *AffinePair.search_bounds(), "default", search)
    starts, labels, info, fallback = None, (), {}, None
    lo, hi = model_cls.search_bounds()
    source = "paper"
    if preset == "estimate":
        try:
            lo, hi, starts, info = estimate_box(model_cls, obs or dataset.observations())
            source = "estimate"
            labels = tuple(f"LM from the closed-form estimate (candidate {i + 1})"
                           for i in range(len(starts)))  # fmt: skip
        except (ValueError, NotImplementedError) as e:
            fallback = f"{e}; the paper's ranges were searched"
            lo, hi = model_cls.search_bounds()
    ranges1 = _ranges(model_cls, lo, hi, source, search)
    report = SearchReport(preset, ranges1, ranges2, box_sigmas=BOX_SIGMAS if starts is not None
                          else None, fallback=fallback, **info)  # fmt: skip
    return SearchPlan(_box(ranges1, model_cls), _box(ranges2, AffinePair), starts, labels, report)


def searched_box(cls: type[AbstractParametric], report: SearchReport | None, stage: str,
                 search: dict) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """A stage's box over all of ``cls``'s parameters: the report's when the result recorded
    it, else the preset ranges with the dataset's ``[search]`` (older results)."""
    if report is not None:
        return report.bounds(stage, cls.param_names)
    return cls.search_bounds(search)
