"""The human-readable summary the CLI prints after a calibration."""

from __future__ import annotations

from .models import AffinePair, get_model
from .result import CalibrationResult, StageResult


def _unit(u: str) -> str:
    return "" if u == "1" else f" {u}"


def _stage_lines(title: str, s: StageResult, names, units, early_stop: bool) -> list[str]:
    lines = [f"{title}: F = {s.F:.6f} mm  (f1 = {s.f1:.6f} mm, f2 = {s.f2:.6f} mm)"]
    pol = s.polish
    de = s.de
    lm = "off"
    if pol.get("ran"):
        verdict = "accepted" if pol.get("accepted") else "rejected (did not lower F)"
        lm = f"{verdict}, {pol.get('steps', 0)} steps, F {pol['F_before']:.6f} -> " + (
            f"{pol['F_after']:.6f} mm"
        )
    if de["converged"]:
        stop = "stopped: population converged"
    elif early_stop:
        stop = "stopped: generation limit reached before the population converged"
    else:
        stop = "all generations run (early stop off)"
    lines.append(
        f"  DE: {de['generations']} generations, {de['evaluations']:,} evaluations, "
        f"F = {de['F']:.6f} mm; {stop}"
    )
    lines.append(f"  LM polish: {lm}")
    lines.append("  parameters:")
    for name, unit in zip(names, units, strict=True):
        lines.append(f"    {name:<9} {s.params[name]:>12.5f}{_unit(unit)}")
    lines.append("  residuals per landmark, mm:")
    lines.append("    m   |image - tablet|   |hand - target|")
    for r in s.residuals_mm:
        lines.append(f"    {r['m']:<3} {r['image_vs_tablet_mm']:>16.4f} {r['hand_mm']:>17.4f}")
    return lines


def format_summary(result: CalibrationResult) -> str:
    """A few dozen lines: parameters, f1 / f2 / F per stage, residuals, twin, warnings, time."""
    model_cls = get_model(result.model)
    lines = [
        f"handeye-jax calibration of {result.dataset!r}: model {result.model}, "
        f"seed {result.seed}, population {result.settings['population']}, "
        f"at most {result.settings['generations']} generations"
        + ("" if result.settings.get("early_stop", True) else " (no early stop)"),
        "",
    ]
    early_stop = bool(result.settings.get("early_stop", True))
    lines += _stage_lines(
        "stage 1", result.stage1, model_cls.param_names, model_cls.param_units, early_stop
    )
    twin = result.sign_twin
    if twin:
        found = ", ".join(f"{k} = {v:+.4f}" for k, v in twin["found"].items())
        lines.append(
            f"  sign twin found: {found}; the mirror twin (both signs flipped) has "
            f"F = {twin['F_flipped']:.6f} mm"
        )
    lines.append("")
    lines += _stage_lines(
        "stage 2", result.stage2, AffinePair.param_names, AffinePair.param_units, early_stop
    )
    c1, c2 = result.centres_mm
    lines.append(
        f"  centres of rotation (landmark {result.centre_index}): A1 ({c1[0]:.3f}, {c1[1]:.3f}) mm,"
        f" A2 ({c2[0]:.3f}, {c2[1]:.3f}) mm"
    )
    for w in result.warnings:
        lines.append(f"warning: {w}")
    t = result.timings_s
    lines.append("")
    lines.append(
        f"time: {t['total']:.2f} s (stage 1: DE {t['stage1_de']:.2f} s, LM "
        f"{t['stage1_polish']:.2f} s; stage 2: DE {t['stage2_de']:.2f} s, LM "
        f"{t['stage2_polish']:.2f} s; includes JIT compilation)"
    )
    return "\n".join(lines)
