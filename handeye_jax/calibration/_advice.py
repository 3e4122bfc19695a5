"""What to do about a parameter on a bound of its search range: advice that leads somewhere.

A parameter at the edge of the box it was searched in is named with what would help, by
why it is there:

* it came from a **prior** (a recalibration): its box held the prior's mean ± 6σ, and the
  data pulled it that far; say by how many σ, and that the part may have changed (refit it);
  widening does nothing;
* it lies along a **weak direction** of the fit (the camera mount's shift/tilt trade-off of
  pictures taken from one height): a wider range lets it slide further along the trade-off,
  which makes the held-out error worse, not better; pictures from other heights and hand
  angles determine it (``handeye-jax plan``);
* the **closed-form estimate** from the data lies outside the range (the paper's ranges, or
  a ``[search]`` range, on another rig): search around it, or widen to hold it;
* the estimate lies inside and the data still pull the parameter out: check the data before
  widening.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..data import Observations
from ..problem import JacobianAnalysis, ParameterSpace
from ._payloads import BoundHit
from ._plans import PRIOR_BOX_SIGMAS
from ._ranges import SearchReport, estimate_box
from ._result import StageResult

#: A parameter closer than this fraction of its range to a bound is on the bound.
BOUND_FRACTION = 1e-3


@dataclass
class AdviceContext:
    """What the advice may read: where the fit searched, the data, and each stage's
    Jacobian analysis at the fit (computed on first use, and only when a parameter is on a
    bound).

    Attributes:
        report: the search report (preset, ranges, the closed-form estimate), or ``None``.
        obs: the observations, for a closed-form estimate when the report has none.
        analysis: ``stage -> JacobianAnalysis`` at the fit (``"stage1"``, ``"stage2"``).
    """

    report: SearchReport | None = None
    obs: Observations | None = None
    analysis: Callable[[str], JacobianAnalysis | None] | None = None
    _analyses: dict = field(default_factory=dict, init=False, repr=False)
    _box: tuple | None = field(default=None, init=False, repr=False)

    def weak(self, stage: str) -> JacobianAnalysis | None:
        if self.analysis is None:
            return None
        if stage not in self._analyses:
            self._analyses[stage] = self.analysis(stage)
        return self._analyses[stage]

    def estimate(self, model_cls, name: str) -> tuple[tuple[float, ...], tuple[float, float]]:
        """The closed-form estimate of a stage-1 parameter polished (one value per kept
        candidate) and the range the default search gives it; ``((), (nan, nan))`` when the
        data or the model give none. Computed once, on first use."""
        if self._box is None:
            self._box = self._estimate_box(model_cls)
        if not self._box:
            return (), (float("nan"), float("nan"))
        lo, hi, ends, names = self._box
        j = names.index(name)
        return tuple(float(x[j]) for x in ends), (float(lo[j]), float(hi[j]))

    def _estimate_box(self, model_cls) -> tuple:
        if self.report is not None and self.report.estimate is not None:
            names = model_cls.param_names
            lo, hi = self.report.bounds("stage1", names)
            return lo, hi, [np.array([self.report.estimate[n] for n in names])], names
        if self.obs is None:
            return ()
        try:
            lo, hi, ends, _ = estimate_box(model_cls, self.obs)
        except (ValueError, NotImplementedError):
            return ()
        return lo, hi, list(ends), model_cls.param_names


def _unit(u: str) -> str:
    return "" if u == "1" else f" {u}"


def _side(v: float, lo: float, hi: float) -> str | None:
    width = hi - lo
    if v - lo <= BOUND_FRACTION * width:
        return "lower"
    if hi - v <= BOUND_FRACTION * width:
        return "upper"
    return None


def _prior_advice(stage: StageResult, space: ParameterSpace, name: str, unit: str) -> str:
    pull = next((p for p in (stage.prior.pulls if stage.prior else ()) if p.param == name), None)
    j = space.prior.names.index(name)
    mean, sigma = float(space.prior.mean[j]), float(space.prior.sigma[j])
    k = (stage.params[name] - mean) / sigma if pull is None else pull.pull
    return (f"it came from the prior ({space.prior.source}: {mean:.4g} ± {sigma:.3g}{_unit(unit)})"
            f" and the data pulled it {abs(k):.1f} σ, to the edge of the range searched (the "
            f"prior's mean ± {PRIOR_BOX_SIGMAS:g} σ): that part of the rig may have changed; "
            f"refit it (--refit {name}); widening the range does not help")  # fmt: skip


def _weak_advice(analysis: JacobianAnalysis | None, name: str, units: dict) -> str | None:
    if analysis is None:
        return None
    for w in analysis.weak_directions:
        if name not in w.params:
            continue
        if w.determined is not None:
            return (f"the data do not determine it: {w.note}; its bound does no harm "
                    "(and widening does nothing)")  # fmt: skip
        if {"mm", "deg"} <= {units[p] for p in w.params}:
            pair = "–".join(w.params)
            return (f"it lies along the camera mount's shift/tilt trade-off ({pair}), which "
                    "pictures from one height barely determine: a wider range lets it slide "
                    "further along the trade-off, which does not make the calibration better; "
                    "pictures from other heights and hand angles determine it (handeye-jax "
                    "plan DATASET, then calibrate with them)")  # fmt: skip
        return (f"the data barely determine it ({w.note}): a wider range would not determine "
                "it better; more landmarks or captures would")  # fmt: skip
    return None


def _estimate_advice(
    values: tuple[float, ...], box: tuple[float, float], name: str, unit: str, *,
    bounds: tuple[float, float], side: str, estimated_box: bool,
) -> tuple[str, tuple | None, str]:
    """Advice from the closed-form estimate (polished): search around it or widen to hold
    its range when it lies outside the range searched, else say the data disagree with it.
    Returns the advice, the range to widen to and the reason."""
    lo, hi = bounds
    shown = " or ".join(dict.fromkeys(f"{v:.4g}" for v in values)) + _unit(unit)
    if max(values) < lo or min(values) > hi:
        wider = (float(min(lo, box[0])), float(max(hi, box[1])))
        how = ("" if estimated_box else "search around it (the default, --search estimate, "
               "or [search] preset = \"estimate\"), or ")  # fmt: skip
        text = (f"the closed-form estimate from the data, polished, puts it at {shown}, outside "
                f"the range: {how}widen [search] {name} = [{wider[0]:.4g}, {wider[1]:.4g}]")
        return text, wider, "estimate outside"
    width = hi - lo
    wider = (float(lo - width), float(hi)) if side == "lower" else (float(lo), float(hi + width))
    text = (f"the closed-form estimate from the data, polished, puts it at {shown}, not outside "
            f"the range, yet the data pull it to the edge: check the dataset (units mm/deg/px, "
            f"[tablet] ppi and scale, [camera], the hand-angle convention) before widening "
            f"[search] {name} = [{wider[0]:.4g}, {wider[1]:.4g}]")  # fmt: skip
    return text, wider, "estimate inside"


def bound_hits(stage: StageResult, space: ParameterSpace, key: str = "stage1",
               context: AdviceContext | None = None) -> tuple[BoundHit, ...]:  # fmt: skip
    """The free parameters of a stage on a bound of the box they were searched in, each with
    what would help (see the module).

    Args:
        stage: the stage's result (its parameters and prior pulls).
        space: the stage's parameters and box, as fitted.
        key: ``"stage1"`` or ``"stage2"``.
        context: the search report, the data and the Jacobian analysis, for the advice.
    """
    context = context or AdviceContext()
    cls = type(space.template)
    units = dict(zip(cls.param_names, cls.param_units, strict=True))
    priors = set(space.prior.names) if space.prior is not None else set()
    out = []
    for j, name in enumerate(space.free):
        lo, hi, v = float(space.lower[j]), float(space.upper[j]), float(stage.params[name])
        side = _side(v, lo, hi)
        if side is None:
            continue
        unit, wider = units[name], None
        analysis = context.weak(key)
        if name in priors:
            advice, reason = _prior_advice(stage, space, name, unit), "prior"
        elif (weak := _weak_advice(analysis, name, units)) is not None:
            advice, reason = weak, "weak"
        elif key == "stage1" and (estimate := context.estimate(cls, name))[0]:
            estimated = context.report is not None and context.report.preset == "estimate"
            advice, wider, reason = _estimate_advice(
                *estimate, name, unit, bounds=(lo, hi), side=side, estimated_box=estimated
            )
        else:
            width = hi - lo
            wider = (lo - width, hi) if side == "lower" else (lo, hi + width)
            advice = (f"the optimum may lie outside it: widen it in the dataset's [search] table,"
                      f" e.g. {name} = [{wider[0]:g}, {wider[1]:g}]")  # fmt: skip
            reason = "range"
        out.append(BoundHit(name, v, unit, side, (lo, hi), wider, advice, reason))
    return tuple(out)


def bound_warning(hit: BoundHit) -> str:
    """One warning line for a parameter on a bound."""
    (lo, hi), u = hit.range, _unit(hit.unit)
    return (f"{hit.param} = {hit.value:.4g}{u} is on the {hit.side} bound of the range "
            f"searched [{lo:.4g}, {hi:.4g}]{u}: {hit.advice}")


def analyses_of(fits) -> Callable[[str], JacobianAnalysis | None]:
    """``stage -> JacobianAnalysis`` at a just-computed fit's optimum (its data objective)."""
    from ..problem import analyse_jacobian
    from ._programs import stage_error_jacobian

    def analysis(stage: str) -> JacobianAnalysis | None:
        fit = getattr(fits, stage)
        if fit.space.d == 0:
            return None
        cls = type(fit.space.template)
        units = [cls.param_units[cls.param_names.index(n)] for n in fit.space.free]
        e, J = (np.asarray(a) for a in stage_error_jacobian(fit.data, np.asarray(fit.x)))
        return analyse_jacobian(e, J, fit.space.free, units)

    return analysis
