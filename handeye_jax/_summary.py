"""The human-readable summary the CLI prints after a calibration."""

from __future__ import annotations

from ._result import CalibrationResult, StageResult
from ._rig_change import change_line
from ._scope import scope_lines
from .models import AffinePair


def _unit(u: str) -> str:
    return "" if u == "1" else f" {u}"


def _value(v: float, std: float | None, unit: str, has_std: bool) -> str:
    if not has_std:
        return f"{v:>12.5f}{_unit(unit)}"
    spread = "undetermined" if std is None else f"{std:.3g}"
    return f"{v:>12.5f} ± {spread:<12}{_unit(unit)}"


def _stage_lines(
    title: str, s: StageResult, names, units, early_stop: bool, std: dict | None = None
) -> list[str]:
    head = f"{title}: F = {s.F:.6f} mm  (f1 = {s.f1:.6f} mm, f2 = {s.f2:.6f} mm)"
    # With a prior, DE and LM minimise the MAP objective (data term + prior term), not F.
    minimised = "F" if s.prior_F is None else "MAP objective"
    if s.prior_F is not None:
        head += f"; prior term of the MAP objective {s.prior_F:.6f} mm"
    lines = [head]
    pol = s.polish
    de = s.de
    lm = "off"
    if pol.get("ran"):
        verdict = "accepted" if pol.get("accepted") else "rejected (did not lower F)"
        lm = f"{verdict}, {pol.get('steps', 0)} steps, {minimised} {pol['F_before']:.6f} -> " + (
            f"{pol['F_after']:.6f} mm"
        )
    if "generations" not in de:
        lines.append("  DE: none (nothing to search: the fit starts from the previous result)")
    else:
        if de["converged"]:
            stop = "stopped: population converged"
        elif early_stop:
            stop = "stopped: generation limit reached before the population converged"
        else:
            stop = "all generations run (early stop off)"
        searched = de.get("searched")
        over = f" over {', '.join(searched)}" if searched and len(searched) < len(names) else ""
        lines.append(
            f"  DE{over}: {de['generations']} generations, {de['evaluations']:,} evaluations, "
            f"{minimised} = {de['F']:.6f} mm; {stop}"
        )
    lines.append(f"  LM polish: {lm}")
    found = found_by_line(pol)
    if found:
        lines.append(found)
    lines.append("  parameters" + (" (± one standard deviation):" if std else ":"))
    prior_of = {p["param"]: p for p in (s.prior or {}).get("pulls", [])}
    for name, unit in zip(names, units, strict=True):
        status = s.status.get(name, "free")
        shown = std is not None and status != "fixed"
        value = _value(s.params[name], (std or {}).get(name), unit, shown)
        if status == "fixed":
            value += f"  fixed ({s.fixed_source.get(name, 'given')})"
        elif status == "prior" and name in prior_of:
            p = prior_of[name]
            sig = "" if p["sigma"] is None else f" ± {p['sigma']:.3g}"
            value += f"  prior {p['mean']:.5g}{sig}, pull {p['pull']:+.1f} sigma"
        lines.append(f"    {name:<9} {value}".rstrip())
    if s.prior:
        scale = s.prior["data_scale_mm"]
        line = f"  prior: from {s.prior['source']}; data scale s = {scale:.3g} mm"
        if s.prior.get("data_sigma_mm"):
            line += (f"; the data weighed as Gaussian errors of its fit's noise, "
                     f"{s.prior['data_sigma_mm']:.3g} mm per component")  # fmt: skip
        lines.append(line)
    lines.append("  residuals per landmark, mm:")
    lines.append("    m   |image - tablet|   |hand - target|")
    for r in s.residuals_mm:
        lines.append(f"    {r['m']:<3} {r['image_vs_tablet_mm']:>16.4f} {r['hand_mm']:>17.4f}")
    return lines


def found_by_line(polish: dict) -> str:
    """One line: which search found the stage's optimum, and how many restarts reached it."""
    how = polish.get("found_by")
    if not how:  # results written before the restarts
        return ""
    line = f"  optimum found by: {how}"
    rs = polish.get("restarts")
    if rs:
        where = f" on {rs['landmarks']} landmarks" if rs.get("landmarks") else ""
        line += (f"; {rs['reached_result']} of {rs['starts']} LM restarts{where} ended within "
                 "1e-4 mm of it")  # fmt: skip
    replaced = polish.get("replaced_F")
    if replaced:
        F = polish.get("F_after", replaced[-1])
        line += (f"; it replaced the fit's first optimum (F = "
                 f"{', then '.join(f'{f:.6f}' for f in replaced)} mm, "
                 f"{replaced[0] - F:.2g} mm above it)")  # fmt: skip
    return line


def format_summary(result: CalibrationResult) -> str:
    """A few dozen lines: parameters, f1 / f2 / F per stage, residuals, twin, warnings, time."""
    model_cls = type(result.model)
    settings = result.settings
    lines = [
        f"handeye-jax calibration of {result.dataset_name!r}: model {result.model_name}, "
        f"seed {settings.seed}, population {settings.population}, "
        f"at most {settings.generations} generations"
        + ("" if settings.early_stop else " (no early stop)"),
    ]
    recal = result.recalibration
    if recal:
        others = ("held at its values" if recal.get("others") == "fixed"
                  else "given its posterior as their prior")  # fmt: skip
        lines.append(f"recalibrated from {recal['previous']}: refitted "
                     f"{', '.join(recal['refit'])}; the other parameters {others}")  # fmt: skip
        if recal.get("rig_changes"):
            lines.append(change_line(recal["rig_changes"]))
    lines.append("")
    early_stop = settings.early_stop
    diag = result.diagnostics
    rows = result.data is not None and not result.data.is_simple()
    lines += _stage_lines(
        "stage 1", result.stage1, model_cls.param_names, model_cls.param_units, early_stop,
        diag.get("stage1", {}).get("std") if diag else None,
    )  # fmt: skip
    twin = result.sign_twin
    if twin:
        found = ", ".join(f"{k} = {v:+.4f}" for k, v in twin["found"].items())
        lines.append(
            f"  sign twin found: {found}; the mirror twin (both signs flipped) has "
            f"F = {twin['F_flipped']:.6f} mm"
        )
    if diag:
        lines += diagnostic_lines(
            diag, "stage1", dict(zip(model_cls.param_names, model_cls.param_units, strict=True)),
            rows,
        )  # fmt: skip
    lines += scope_lines((diag or {}).get("scope"), result.heights)
    lines.append("")
    lines += _stage_lines(
        "stage 2", result.stage2, AffinePair.param_names, AffinePair.param_units, early_stop,
        diag.get("stage2", {}).get("std") if diag else None,
    )  # fmt: skip
    c1, c2 = result.centres_mm
    lines.append(
        f"  centres of rotation (landmark {result.centre_index}): A1 ({c1[0]:.3f}, {c1[1]:.3f}) mm,"
        f" A2 ({c2[0]:.3f}, {c2[1]:.3f}) mm"
    )
    if diag:
        lines += diagnostic_lines(
            diag, "stage2", dict(zip(AffinePair.param_names, AffinePair.param_units, strict=True)),
            rows,
        )  # fmt: skip
        lines += convention_lines(diag.get("convention", {}))
    for w in result.warnings:
        lines.append(f"warning: {w}")
    t = result.timings_s
    lines.append("")
    lines.append(
        f"time: {t['total']:.2f} s (stage 1: DE {t['stage1_de']:.2f} s, LM "
        f"{t['stage1_polish']:.2f} s; stage 2: DE {t['stage2_de']:.2f} s, LM "
        f"{t['stage2_polish']:.2f} s"
        + (f"; diagnostics {t['diagnostics']:.2f} s" if "diagnostics" in t else "")
        + "; includes JIT compilation)"
    )
    return "\n".join(lines)


def _modes_line(label: str, modes: list[dict], units: dict[str, str]) -> list[str]:
    if not modes:
        return []
    out = [f"  {label}: {len(modes)}"]
    for m in modes:
        if "differs_from_fit" in m:
            diff = ", ".join(
                f"{n} {d:+.3g}{_unit(units.get(n, '1'))}" for n, d in m["differs_from_fit"].items()
            )
            what = f"differs from the fit by {diff}" if diff else "the fit (within 1 % of range)"
        else:  # older results compared with the population's best member
            diff = ", ".join(f"{n} {d:+.3g}" for n, d in m["differs_from_best"].items())
            what = f"differs from the best by {diff}" if diff else "the best"
        twin = " (the sign twin)" if m.get("sign_twin") else ""
        out.append(f"    F = {m['F']:.6f} mm, {m['members']} member(s): {what}{twin}")
    return out


def diagnostic_lines(
    diag: dict, stage: str, units: dict[str, str], rows: bool = False
) -> list[str]:
    """The diagnostics of one stage: weak directions, optima, bounds, LOO, outliers.

    ``units`` maps the stage's parameter names to their units; ``rows``: the data came from
    several captures, and each m is a row (a view paired with a touch), not a landmark.
    """
    d = diag.get(stage)
    if not d:
        return []
    lines = [f"  diagnostics (residual std {d['sigma_mm']:.4f} mm, {d['dof']} dof):"]
    sv = d.get("singular_values", [])
    if sv and sv[0] > 0:
        rel = " ".join(f"{v / sv[0]:.2g}" for v in sv)
        lines.append(
            f"  singular values of the column-scaled Jacobian, relative to the largest: {rel}"
        )
    weak = d.get("weak_directions", [])
    if weak:
        lines.append("  weak directions (singular value relative to the largest):")
        for w in weak:
            lines.append(f"    {w['relative_singular_value']:.1e}: {w['note']}")
    else:
        lines.append("  weak directions: none (every parameter is determined by the data)")
    lines += _modes_line("distinct optima in the final DE population", d.get("modes", []), units)
    lines += _modes_line(
        "local optima of the multi-start LM refits", d.get("local_optima", []), units
    )
    hits = d.get("bound_hits", [])
    lines.append(
        "  on a search-range bound: "
        + (", ".join(f"{h['param']} = {h['value']:.4g}{_unit(h['unit'])} ({h['side']} bound; "
                     f"widen to [{h['widen_to'][0]:g}, {h['widen_to'][1]:g}]{_unit(h['unit'])})"
                     for h in hits)
           or "none")
    )  # fmt: skip
    loo = d.get("loo")
    if loo:
        what = "stage 1 refitted" if stage == "stage1" else "stages 1 and 2 refitted"
        unit = "row m (one view and its touch)" if rows else "landmark m"
        lines.append(
            f"  leave-one-out ({what} without {unit}, m predicted): held-out F = "
            f"{loo['F']:.4f} mm (f1 = {loo['f1']:.4f}, f2 = {loo['f2']:.4f} mm); in-sample "
            f"F = {loo['in_sample_F']:.4f} mm"
        )
        method = d.get("loo_method", "")
        if method and not method.startswith("exact"):
            lines.append(f"    refits approximated: {method}")
        per = "  ".join(
            f"{r['m']}: {r['image_vs_tablet_mm']:.2f}/{r['hand_mm']:.2f}"
            for r in loo["held_out_mm"]
        )
        lines.append(f"    held out |image - tablet|/|hand - target| mm, m: {per}")
    out = d.get("outliers", [])
    threshold = diag.get("outlier_threshold_mm", float("nan"))
    lines.append(
        f"  outlier landmarks (an error > {threshold:g} mm): "
        + (", ".join(f"m = {m}" for m in out) if out else "none")
    )
    return lines


def convention_lines(conv: dict) -> list[str]:
    """The hand-angle convention check, one line per convention."""
    if not conv:
        return []
    dec = conv["declared"]
    lines = [
        f"convention check (F1st refitted under each hand-angle convention; declared "
        f"zero = {dec['zero_deg']:g} deg, sign = {dec['sign']:+d}): "
        + ("passed" if conv["passed"] else "FAILED")
    ]
    for c in sorted(conv["fits"], key=lambda c: c["F"]):
        mark = (
            "  <- declared" if (c["zero_deg"], c["sign"]) == (dec["zero_deg"], dec["sign"]) else ""
        )
        lines.append(
            f"    zero {c['zero_deg']:>5g} deg, sign {c['sign']:+d}: F1st = {c['F']:.4f} mm{mark}"
        )
    return lines
