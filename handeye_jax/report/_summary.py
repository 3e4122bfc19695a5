"""The human-readable summary the CLI prints after a calibration: the verdict and the failed
checks first (:mod:`._verdict`), the fit in brief, and behind ``verbose`` the optimisers' and
the diagnostics' detail."""

from __future__ import annotations

import math
from collections.abc import Sequence

from ..calibration import (
    CalibrationResult,
    ConventionCheck,
    Diagnostics,
    Mode,
    PolishSummary,
    StageDiagnostics,
    StageResult,
    change_line,
)
from ..diagnostics import scope_lines
from ..models import AffinePair
from ._search import bound_lines, search_lines
from ._verdict import (
    alternatives_lines,
    ambiguity_line,
    checks_lines,
    decimals_for,
    failed_checks,
    some,
    verdict_lines,
)

#: Per-landmark tables list at most this many rows (the largest errors first).
MAX_ROWS = 10


def _unit(u: str) -> str:
    return "" if u == "1" else f" {u}"


def _value(v: float, std: float | None, unit: str, has_std: bool, dof: float | None = None
           ) -> str:  # fmt: skip
    if not has_std:  # no diagnostics: no σ to say which digits hold
        return f"{v:>12.5f}{_unit(unit)}"
    if std is None or not math.isfinite(std):
        return f"{v:>12.3g} ± {'undetermined':<12}{_unit(unit)}"
    if std <= 0:  # as the verdict says it (with_sigma)
        out = f"{v:>12.6g} ± {'0':<12}{_unit(unit)}"
        return out if dof is None else f"{out}  ({dof:.0f} dof)"
    place = decimals_for(std)  # the digits σ supports, as in the verdict
    out = f"{v:>12.{place}f} ± {std:<12.{place}f}{_unit(unit)}"
    return out if dof is None else f"{out}  ({dof:.0f} dof)"


def _stage_lines(
    title: str, s: StageResult, cls, early_stop: bool, std: dict | None = None,
    dof: dict | None = None,
) -> list[str]:  # fmt: skip
    """A stage's fit: F and its terms, DE, the LM polish, the parameters (with each σ's
    degrees of freedom where known) and the residuals."""
    head = f"{title}: F = {s.F:.6f} mm  (f1 = {s.f1:.6f} mm, f2 = {s.f2:.6f} mm)"
    if s.prior_F is not None:
        head += f"; prior term of the MAP objective {s.prior_F:.6f} mm"
    lines = [head, *_search_lines(s, len(cls.param_names), early_stop)]
    legend = " (± one standard deviation" + ("; 95 %: ± t·σ, Student's t at its dof):" if dof
                                               else "):")  # fmt: skip
    lines.append("  parameters" + (legend if std else ":"))
    lines += _parameter_lines(s, cls, std, dof)
    if s.prior is not None:
        scale = s.prior.data_scale_mm
        line = f"  prior: from {s.prior.source}; data scale s = {scale:.3g} mm"
        if s.prior.data_sigma_mm:
            line += (f"; the data weighed as Gaussian errors of its fit's noise, "
                     f"{s.prior.data_sigma_mm:.3g} mm per component")  # fmt: skip
        lines.append(line)
    rows = sorted(s.residuals_mm, key=lambda r: -max(r.image_vs_tablet_mm, r.hand_mm))
    shown = sorted(rows[:MAX_ROWS], key=lambda r: r.m)
    more = len(rows) - len(shown)
    lines.append("  residuals per landmark, mm" + (f" (the {len(shown)} largest of {len(rows)})"
                                                   if more else "") + ":")  # fmt: skip
    lines.append("    m   |image - tablet|   |hand - target|")
    for r in shown:
        lines.append(f"    {r.m:<3} {r.image_vs_tablet_mm:>16.4f} {r.hand_mm:>17.4f}")
    return lines


def _search_lines(s: StageResult, n_params: int, early_stop: bool) -> list[str]:
    """What DE and the LM polish did, and which search found the optimum."""
    # With a prior, DE and LM minimise the MAP objective (data term + prior term), not F.
    minimised = "F" if s.prior_F is None else "MAP objective"
    pol, de = s.polish, s.de
    lm = "off"
    if pol.ran:
        verdict = "accepted" if pol.accepted else "rejected (did not lower F)"
        lm = f"{verdict}, {pol.steps or 0} steps, {minimised} {pol.F_before_mm:.6f} -> " + (
            f"{pol.F_after_mm:.6f} mm"
        )
    if de.generations is None:
        lines = ["  DE: none (nothing to search: the fit starts from the previous result)"]
    else:
        if de.converged:
            stop = "stopped: population converged"
        elif early_stop:
            stop = "stopped: generation limit reached before the population converged"
        else:
            stop = "all generations run (early stop off)"
        searched = de.searched
        over = f" over {', '.join(searched)}" if searched and len(searched) < n_params else ""
        lines = [
            f"  DE{over}: {de.generations} generations, {de.evaluations:,} evaluations, "
            f"{minimised} = {de.F_mm:.6f} mm; {stop}"
        ]
    lines.append(f"  LM polish: {lm}")
    found = found_by_line(pol)
    return [*lines, found] if found else lines


def _parameter_lines(s: StageResult, cls, std: dict | None, dof: dict | None = None
                     ) -> list[str]:  # fmt: skip
    """Each parameter: value ± σ in its unit (and σ's degrees of freedom), or where a fixed
    one came from, or its prior."""
    prior_of = {p.param: p for p in (s.prior.pulls if s.prior is not None else ())}
    lines = []
    for name, unit in zip(cls.param_names, cls.param_units, strict=True):
        status = s.status.get(name, "free")
        shown = std is not None and status != "fixed"
        value = _value(s.params[name], (std or {}).get(name), unit, shown, (dof or {}).get(name))
        if status == "fixed":
            value += f"  fixed ({s.fixed_source.get(name, 'given')})"
        elif status == "prior" and name in prior_of:
            p = prior_of[name]
            sig = "" if p.sigma is None else f" ± {p.sigma:.3g}"
            value += f"  prior {p.mean:.5g}{sig}, pull {p.pull:+.1f} sigma"
        lines.append(f"    {name:<9} {value}".rstrip())
    return lines


def found_by_line(polish: PolishSummary) -> str:
    """One line: which search found the stage's optimum, and how many restarts reached it."""
    how = polish.found_by
    if not how:  # results written before the restarts
        return ""
    line = f"  optimum found by: {how}"
    rs = polish.restarts
    if rs:
        where = f" on {rs.landmarks} landmarks" if rs.landmarks else ""
        line += (f"; {rs.reached_result} of {rs.starts} LM restarts{where} ended within "
                 "1e-4 mm of it")  # fmt: skip
    replaced = polish.replaced_F_mm
    if replaced:
        F = polish.F_after_mm if polish.F_after_mm is not None else replaced[-1]
        line += (f"; it replaced the fit's first optimum (F = "
                 f"{', then '.join(f'{f:.6f}' for f in replaced)} mm, "
                 f"{replaced[0] - F:.2g} mm above it)")  # fmt: skip
    return line


def format_summary(
    result: CalibrationResult,
    *,
    verbose: bool = False,
    quiet: bool = False,
    saved: str | None = None,
) -> str:
    """The summary the command line prints, one screen whatever the number of landmarks:
    the verdict (stage to deploy, expected touching error, camera and pen on the flange,
    whether the result was saved), then the checks that failed with their fixes, then the fit
    in brief. ``verbose`` adds the optimisers' and the diagnostics' detail; ``quiet`` prints
    the verdict alone (and how many checks failed).

    Args:
        result: the calibration (with its diagnostics, for the verdict's numbers).
        verbose: add every stage's search, parameters, residuals and diagnostics.
        quiet: the verdict alone.
        saved: the file the result was written to, or ``None`` (nothing saved).
    """
    lines = [_title(result), ""]
    lines += verdict_lines(result, saved)
    checks = failed_checks(result)
    if quiet:
        if checks:
            lines.append(f"CHECKS FAILED  {len(checks)} (run without --quiet to see them)")
        return "\n".join(lines)
    lines += ["", *checks_lines(checks), *alternatives_lines(result), "", *_fit_lines(result)]
    if verbose:
        lines += ["", *_head(result), *search_lines(result)[1:]]
        lines += _stage1_block(result)
        lines.append("")
        lines += _stage2_block(result)
        lines += _ambiguity_lines(result)
    lines += ["", _time_line(result.timings_s, verbose)]
    return "\n".join(lines)


def _time_line(t: dict[str, float], verbose: bool) -> str:
    """The seconds taken: the fit (its parts: the search's ranges, each stage's DE and LM),
    then each step that ran after it, so that the first figure is their sum."""
    ranges = f"search ranges {t['plan']:.2f} s; " if "plan" in t else ""
    fit = (f"the fit {t['total']:.2f} s ({ranges}stage 1: DE {t['stage1_de']:.2f} s, LM "
           f"{t['stage1_polish']:.2f} s; stage 2: DE {t['stage2_de']:.2f} s, LM "
           f"{t['stage2_polish']:.2f} s)")  # fmt: skip
    after = [name for name in ("diagnostics", "bootstrap") if name in t]
    whole = t["total"] + sum(t[name] for name in after)
    line = f"time: {whole:.2f} s: {fit}" + "".join(f", {n} {t[n]:.2f} s" for n in after)
    line += "; includes JIT compilation"
    if not verbose:
        line += "; --verbose: the optimisers, parameters, residuals and diagnostics"
    return line


def _title(result: CalibrationResult) -> str:
    data = result.data
    what = ""
    if data is not None:
        caps = len(data.captures)
        what = (f", {data.n_touches} touches, {caps} capture{'s' if caps > 1 else ''}"
                + (", hand heights" if result.heights is not None else ""))  # fmt: skip
    loss = result.settings.loss
    how = (f"maximum likelihood under the {result.settings.noise!r} noise model, its scales "
           "estimated from the data" if loss == "ml" else f"loss {loss}")  # fmt: skip
    return (f"handeye-jax calibration of {result.dataset_name!r}: {result.model_name.upper()} "
            f"model{what}; {how}")  # fmt: skip


def _fit_lines(result: CalibrationResult) -> list[str]:
    """The fit in brief: each stage's F (the paper's measure) and the noise it found."""
    lines = ["FIT"]
    for key, title in (("stage1", "stage 1"), ("stage2", "stage 2")):
        s: StageResult = getattr(result, key)
        line = (f"  {title}: F = {s.F:.4f} mm (f1 = {s.f1:.4f}, f2 = {s.f2:.4f} mm; the paper's "
                "mean error lengths)")  # fmt: skip
        if s.noise is not None and result.data is not None:
            e = s.noise.noise.effective(result.data.mm_per_tablet_px)
            line += (f"; noise found: image {e['image_px']:.2g} px, depth {e['depth_mm']:.2g} "
                     f"mm, touch {e['touch_mm']:.2g} mm per axis ({s.noise.dof:.0f} dof)")
        lines.append(line)
    if result.recalibration is not None:
        recal = result.recalibration
        others = ("held at its values" if recal.others == "fixed"
                  else "given its posterior as their prior")  # fmt: skip
        lines.append(f"  recalibrated from {recal.previous}: refitted "
                     f"{', '.join(recal.refit)}; the other parameters {others}")  # fmt: skip
        if recal.rig_changes:
            lines.append(change_line(recal.rig_changes))
    lines += [f"  {line.strip()}" for line in search_lines(result)[:1]]
    return lines


def _ambiguity_lines(result: CalibrationResult) -> list[str]:
    d = result.diagnostics
    if d is None or not d.ambiguities:
        return []
    lines = ["", "fits the data cannot tell from this one:"]
    for a in d.ambiguities:
        lines.append(f"  {ambiguity_line(a)}; separated by {a.separate_by}")
    return lines


def _head(result: CalibrationResult) -> list[str]:
    """The settings' line."""
    settings = result.settings
    return [
        f"settings: model {result.model_name}, seed {settings.seed}, population "
        f"{settings.population}, at most {settings.generations} generations"
        + ("" if settings.early_stop else " (no early stop)") + f", loss {settings.loss}",
    ]


def _spread(diag, key: str) -> tuple[dict | None, dict | None]:
    """A stage's σ and their degrees of freedom, each ``None`` if the diagnostics lack them."""
    d = None if diag is None else getattr(diag, key)
    return (None, None) if d is None else (d.std, d.std_dof)


def _stage1_block(result: CalibrationResult) -> list[str]:
    """Stage 1: its fit, the sign twin, its diagnostics, the scope and the heights."""
    model_cls = type(result.model)
    diag = result.diagnostics
    std, dof = _spread(diag, "stage1")
    lines = _stage_lines("stage 1", result.stage1, model_cls, result.settings.early_stop, std,
                         dof)  # fmt: skip
    twin = result.sign_twin
    if twin is not None:
        found = ", ".join(f"{k} = {v:+.4f}" for k, v in twin.found.items())
        lines.append(
            f"  sign twin found: {found}; the mirror twin (both signs flipped) has "
            f"F = {twin.F_flipped_mm:.6f} mm"
        )
    if diag is not None:
        lines += diagnostic_lines(diag, "stage1", _units(model_cls), _by_rows(result))
    return lines + scope_lines(None if diag is None else diag.scope, result.heights)


def _stage2_block(result: CalibrationResult) -> list[str]:
    """Stage 2: its fit, the centres of rotation, its diagnostics and the convention check."""
    diag = result.diagnostics
    std, dof = _spread(diag, "stage2")
    lines = _stage_lines("stage 2", result.stage2, AffinePair, result.settings.early_stop, std,
                         dof)  # fmt: skip
    c1, c2 = result.centres_mm
    lines.append(
        f"  centres of rotation (landmark {result.centre_index}): A1 ({c1[0]:.3f}, {c1[1]:.3f}) mm,"
        f" A2 ({c2[0]:.3f}, {c2[1]:.3f}) mm"
    )
    if diag is not None:
        lines += diagnostic_lines(diag, "stage2", _units(AffinePair), _by_rows(result))
        lines += convention_lines(diag.convention)
    return lines


def _units(cls) -> dict[str, str]:
    return dict(zip(cls.param_names, cls.param_units, strict=True))


def _by_rows(result: CalibrationResult) -> bool:
    """The data came from several captures: each m is a row (a view and its touch)."""
    return result.data is not None and not result.data.is_simple()


def _modes_line(label: str, modes: Sequence[Mode], units: dict[str, str]) -> list[str]:
    if not modes:
        return []
    out = [f"  {label}: {len(modes)}"]
    for m in modes:
        if m.differs_from_fit is not None:
            diff = ", ".join(
                f"{n} {d:+.3g}{_unit(units.get(n, '1'))}" for n, d in m.differs_from_fit.items()
            )
            what = f"differs from the fit by {diff}" if diff else "the fit (within 1 % of range)"
        else:  # older results compared with the population's best member
            diff = ", ".join(f"{n} {d:+.3g}" for n, d in (m.differs_from_best or {}).items())
            what = f"differs from the best by {diff}" if diff else "the best"
        twin = " (the sign twin)" if m.sign_twin else ""
        out.append(f"    F = {m.F_mm:.6f} mm, {m.members} member(s): {what}{twin}")
    return out


def diagnostic_lines(
    diag: Diagnostics, stage: str, units: dict[str, str], rows: bool = False
) -> list[str]:
    """The diagnostics of one stage: weak directions, optima, bounds, LOO, outliers.

    ``units`` maps the stage's parameter names to their units; ``rows``: the data came from
    several captures, and each m is a row (a view paired with a touch), not a landmark.
    """
    d: StageDiagnostics | None = getattr(diag, stage)
    if d is None:
        return []
    lines = [f"  diagnostics (residual std {d.sigma_mm:.4f} mm, {d.dof} dof):"]
    sv = d.singular_values
    if sv and sv[0] > 0:
        rel = " ".join(f"{v / sv[0]:.2g}" for v in sv)
        lines.append(
            f"  singular values of the column-scaled Jacobian, relative to the largest: {rel}"
        )
    weak = d.weak_directions
    if weak:
        lines.append("  weak directions (singular value relative to the largest):")
        for w in weak:
            lines.append(f"    {w.relative_singular_value:.1e}: {w.note}")
    else:
        lines.append("  weak directions: none (every parameter is determined by the data)")
    lines += _modes_line("distinct optima in the final DE population", d.modes, units)
    lines += _modes_line("local optima of the multi-start LM refits", d.local_optima or (), units)
    lines += bound_lines(d.bound_hits)
    loo = d.loo
    if loo is not None:
        what = "stage 1 refitted" if stage == "stage1" else "stages 1 and 2 refitted"
        unit = "touch m (each of its views)" if rows else "landmark m"
        lines.append(
            f"  leave-one-out ({what} without {unit}, m predicted): held-out F = "
            f"{loo.F_mm:.4f} mm (f1 = {loo.f1_mm:.4f}, f2 = {loo.f2_mm:.4f} mm); in-sample "
            f"F = {loo.in_sample_F_mm:.4f} mm"
        )
        method = d.loo_method or ""
        if method and not method.startswith("exact"):
            lines.append(f"    refits approximated: {method}")
        held = sorted(loo.held_out_mm, key=lambda r: -r.hand_mm)[:MAX_ROWS]
        per = "  ".join(f"{r.m}: {r.image_vs_tablet_mm:.2f}/{r.hand_mm:.2f}"
                        for r in sorted(held, key=lambda r: r.m))  # fmt: skip
        more = (f" (the {len(held)} largest of {len(loo.held_out_mm)})"
                if len(held) < len(loo.held_out_mm) else "")  # fmt: skip
        lines.append(f"    held out |image - tablet|/|hand - target| mm{more}, m: {per}")
    out = d.outliers
    threshold = diag.outlier_threshold_mm
    threshold = float("nan") if threshold is None else threshold
    lines.append(
        f"  outlier landmarks (an error > {threshold:g} mm): "
        + (f"m = {some(out)}" if out else "none")
    )
    return lines


def convention_lines(conv: ConventionCheck | None) -> list[str]:
    """The hand-angle convention check, one line per convention."""
    if conv is None:
        return []
    dec = conv.declared
    lines = [
        f"convention check (F1st refitted under each hand-angle convention; declared "
        f"zero = {dec.zero_deg:g} deg, sign = {dec.sign:+d}): "
        + ("passed" if conv.passed else "FAILED")
    ]
    for c in sorted(conv.fits, key=lambda c: c.F_mm):
        mark = "  <- declared" if (c.zero_deg, c.sign) == (dec.zero_deg, dec.sign) else ""
        fit = f"zero {c.zero_deg:>5g} deg, sign {c.sign:+d}: F1st = {c.F_mm:.4f} mm"
        lines.append(f"    {fit}{mark}")
    return lines
