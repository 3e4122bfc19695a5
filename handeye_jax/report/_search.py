"""The summary's lines on where stage 1 searched: a block of its own, placed by the summary."""

from __future__ import annotations

from collections.abc import Sequence

from ..calibration import HALF_WIDTH, BoundHit, CalibrationResult


def search_lines(result: CalibrationResult) -> list[str]:
    """Where stage 1 searched: the preset, or the box around the closed-form estimate (how it
    was made and each range), and which ranges the dataset's ``[search]`` set."""
    report = result.search
    if report is None:
        return []
    cls = type(result.model)
    own = [n for n in cls.param_names if report.stage1[n].source == "[search]"]
    given = f"; the dataset's [search] set {', '.join(own)}" if own else ""
    if report.preset == "paper":
        return [f"search: the paper's ranges (Tables 5 and 6, preset paper){given}"]
    if report.fallback is not None:
        return [f"search: no closed-form estimate ({report.fallback}){given}"]
    if report.estimate_F_mm is None:  # a recalibration's: around the previous values
        return [f"search: around the previous result's values (each ± half its paper range, "
                f"widened to hold the prior){given}"]
    (mm_floor, mm_cap), (deg_floor, deg_cap) = HALF_WIDTH["mm"], HALF_WIDTH["deg"]
    twin = ("; it holds both signs of the tablet's tilt, which the views could not tell apart"
            if report.candidates == 2 else "")  # fmt: skip
    cells = ", ".join(
        f"{n} [{report.stage1[n].lower:.4g}, {report.stage1[n].upper:.4g}]"
        + ("" if u == "1" else f" {u}")
        for n, u in zip(cls.param_names, cls.param_units, strict=True)
    )
    return [
        f"search: around a closed-form estimate from the data (touches by least squares, "
        f"camera mount by a rigid fit of the views; polished F = {report.estimate_F_mm:.4f} "
        f"mm), each range the estimate ± {report.box_sigmas:g} σ, at least {mm_floor:g} mm or "
        f"{deg_floor:g} deg and at most {mm_cap:g} mm or {deg_cap:g} deg{twin}{given}",
        f"  ranges: {cells}",
    ]


def bound_lines(hits: Sequence[BoundHit]) -> list[str]:
    """The diagnostics' parameters on a bound of the range searched, each with what would
    help (older results: the range to widen to)."""
    if not hits:
        return ["  on a search-range bound: none"]
    lines = ["  on a search-range bound:"]
    for h in hits:
        u = "" if h.unit == "1" else f" {h.unit}"
        lo, hi = h.range
        head = f"    {h.param} = {h.value:.4g}{u} ({h.side} bound of [{lo:.4g}, {hi:.4g}]{u})"
        if h.advice:
            lines.append(f"{head}: {h.advice}")
        elif h.widen_to is not None:
            lines.append(f"{head}: widen to [{h.widen_to[0]:g}, {h.widen_to[1]:g}]{u}")
        else:
            lines.append(head)
    return lines
