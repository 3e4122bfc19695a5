"""The summary a robot engineer reads (issue 26): the verdict first, the failed checks with
their fixes, digits the σ supports, detail behind ``verbose``, the verdict alone with
``quiet``, and one screen whatever the number of landmarks."""

import re
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from handeye_jax import format_summary
from handeye_jax.cli import main
from handeye_jax.report._figures import verdict_title
from handeye_jax.report._verdict import MAX_CHECKS, decimals_for, with_sigma
from tests.common import FAST, PAPER

#: A screen: the default summary, and the verbose one, fit in this many lines.
SCREEN = 60
VERBOSE_SCREEN = 160


@pytest.mark.parametrize(("value", "sigma", "want"), [
    (12.34567, 0.054, "12.346 ± 0.054 mm"),
    (-0.4623, 0.29, "-0.46 ± 0.29 mm"),
    (193.3349, 2.7, "193.3 ± 2.7 mm"),
    (1234.5, 37.0, "1234 ± 37 mm"),
    (0.1234567, None, "0.123 mm"),
])  # fmt: skip
def test_each_number_shows_the_digits_its_sigma_supports(value, sigma, want):
    assert with_sigma(value, sigma, "mm") == want


@settings(max_examples=50)
@given(st.floats(-1e4, 1e4), st.floats(1e-6, 1e3))
def test_a_value_and_its_sigma_share_their_decimals(value, sigma):
    """σ to two significant digits (at least), the value to the same decimals: the value is
    within half its last digit, σ within 5 %."""
    shown, _, spread = with_sigma(value, sigma).partition(" ± ")
    decimals = len(spread.partition(".")[2])
    assert len(shown.partition(".")[2]) == decimals == decimals_for(sigma)
    assert abs(float(shown) - value) <= 0.5 * 10.0**-decimals * (1 + 1e-9)
    assert abs(float(spread) - sigma) <= 0.05 * sigma


def test_the_verbose_parameters_show_the_digits_their_sigma_supports(paper_result):
    """Issue 26: "parameters print with five decimals on ±59 mm". Each σ to two significant
    digits, each value to the same decimals."""
    text = format_summary(paper_result, verbose=True)
    std = {**paper_result.diagnostics.stage1.std, **paper_result.diagnostics.stage2.std}
    rows = 0
    for name, sigma in std.items():
        if sigma is None:
            continue
        line = next(x for x in text.splitlines() if x.strip().startswith(f"{name} "))
        value, shown = re.match(rf"\s*{name}\s+(\S+) ± (\S+)", line).groups()
        assert shown == with_sigma(0.0, sigma).split(" ± ")[1], line
        decimals = len(shown.partition(".")[2])
        assert len(value.partition(".")[2]) == decimals, line
        assert float(shown) == pytest.approx(sigma, rel=0.05), line
        rows += 1
    assert rows >= 12


def test_the_verdict_comes_first_with_what_a_robot_engineer_needs(paper_result):
    text = format_summary(paper_result)
    lines = text.splitlines()
    verdict = lines.index(next(ln for ln in lines if ln.startswith("VERDICT")))
    assert verdict <= 2
    stage = paper_result.deploy_stage
    assert lines[verdict].startswith(f"VERDICT  deploy stage {stage}")
    head = "\n".join(lines[verdict:])
    e = paper_result.diagnostics.expected
    m = re.search(r"expected touching error: ([\d.]+) mm mean, ([\d.]+) mm 95th percentile", head)
    assert m and float(m.group(1)) == pytest.approx(e.mean_mm, rel=0.05)
    assert float(m.group(2)) == pytest.approx(e.p95_mm, rel=0.05) and e.p95_mm > e.mean_mm
    for phrase in ("T_tool0_camera", "xyz  x ", "rpy  roll ", "quaternion  x ",
                   "pen tip in the flange", "saved: nothing (no --out)"):  # fmt: skip
        assert phrase in head, phrase
    # The verdict, then the checks, then the fit in brief: no optimiser detail.
    order = [text.index(w) for w in ("VERDICT", "CHECKS", "FIT", "time:")]
    assert order == sorted(order)
    for detail in ("LM polish", "DE:", "singular values", "residuals per landmark"):
        assert detail not in text, detail
    assert "saved: r.json" in format_summary(paper_result, saved="r.json")


def test_what_the_data_leave_undetermined_is_said_once_each(paper_result):
    """The paper's one capture leaves two camera trade-offs; each is named once in the
    verdict's note on the mount, not again as an alternative fit (its far end)."""
    text = format_summary(paper_result)
    notes = re.findall(r"\(not determined by these data \((.*?)\); z:", text)
    assert notes, text
    for note in notes:
        reasons = note.split("; ")
        assert len(reasons) == len(set(reasons)), note
        assert "yc and alpha_c trade off" in reasons and "xc and beta_c trade off" in reasons
        assert not any("trade off fits as well" in r for r in reasons), note
    # ...while the list of alternative fits still names each far end, and the checks say
    # what it is.
    assert "  - yc and alpha_c trade off: commands from elsewhere move" in text
    assert "ambiguity: yc and alpha_c trade off: the valley's far end fits as well (" in text
    assert "ambiguity: yc and alpha_c trade off fits as well" not in text


def test_no_expected_error_is_printed_where_the_fits_own_touches_contradict_it(paper_result):
    """Touches that miss by more than the noise model allows (outliers of the deployed stage)
    contradict the covariance's prediction: the verdict says so instead of a number."""
    d = paper_result.diagnostics
    key = "stage2" if paper_result.deploy_stage == 2 else "stage1"
    assert d.expected is not None and getattr(d, key).outliers == ()
    bad = replace(paper_result, diagnostics=replace(d, **{key: replace(getattr(d, key),
                                                                        outliers=(2, 5))}))
    verdict = format_summary(bad).split("CHECKS")[0]
    assert "expected touching error: not given: touch(es) 2, 5 miss by more than" in verdict
    assert " mm mean" not in verdict
    assert "expected touching error" not in verdict_title(bad)
    assert "expected touching error" in verdict_title(paper_result)
    # The other stage's outliers say nothing about the deployed one's prediction.
    other = "stage1" if key == "stage2" else "stage2"
    fine = replace(paper_result, diagnostics=replace(d, **{other: replace(getattr(d, other),
                                                                         outliers=(2,))}))
    assert re.search(r"expected touching error: [\d.]+ mm mean", format_summary(fine))


def test_each_failed_check_says_what_fixes_it(paper_result):
    text = format_summary(paper_result)
    checks = [ln for ln in text.splitlines() if re.match(r"  \d+\. ", ln)]
    assert checks  # one capture, no hand heights: at least that check fails
    assert any("one capture" in c and "handeye-jax plan" in c for c in checks)
    for c in checks:
        assert "→" in c or "instead" in c or "check" in c.lower(), c


def test_verbose_adds_the_optimisers_and_quiet_prints_the_verdict_alone(paper_result):
    text = format_summary(paper_result)
    verbose = format_summary(paper_result, verbose=True)
    quiet = format_summary(paper_result, quiet=True)
    assert verbose.startswith(text.split("\ntime:")[0].rstrip())
    for detail in ("LM polish", "DE", "singular values", "leave-one-out", "sign twin"):
        assert detail in verbose, detail
    assert quiet.splitlines()[: len(quiet.splitlines()) - 1] == text.splitlines()[
        : len(quiet.splitlines()) - 1]  # the same verdict
    assert "FIT" not in quiet and "time:" not in quiet and "1. " not in quiet
    assert re.search(r"CHECKS FAILED  \d+ \(run without --quiet to see them\)", quiet)


def test_the_summary_fits_on_a_screen_whatever_the_number_of_landmarks(paper_result):
    """10,000 landmarks' residuals, held-out errors and outliers: the same few lines."""
    n = 10_000
    s1, s2, d = paper_result.stage1, paper_result.stage2, paper_result.diagnostics
    many = lambda rows: tuple(replace(rows[i % len(rows)], m=i) for i in range(n))  # noqa: E731
    loo = replace(d.stage1.loo, held_out_mm=many(d.stage1.loo.held_out_mm))
    big = replace(
        paper_result,
        stage1=replace(s1, residuals_mm=many(s1.residuals_mm)),
        stage2=replace(s2, residuals_mm=many(s2.residuals_mm)),
        diagnostics=replace(d, stage1=replace(d.stage1, loo=loo, outliers=tuple(range(n)))),
        warnings=paper_result.warnings * 40,
    )  # fmt: skip
    text, verbose = format_summary(big), format_summary(big, verbose=True)
    assert len(text.splitlines()) <= SCREEN
    assert len(verbose.splitlines()) <= VERBOSE_SCREEN
    assert max(map(len, verbose.splitlines())) < 2_000  # no line lists every landmark
    if len(paper_result.warnings) * 40 > MAX_CHECKS:
        assert "more (the result file's warnings list them)" in text


def test_calibrate_quiet_prints_the_verdict_and_says_nothing_was_saved(capsys):
    args = ["calibrate", str(PAPER), *FAST]
    assert main([*args, "--quiet"]) == 0
    io = capsys.readouterr()
    lines = io.out.splitlines()
    assert lines[2].startswith("VERDICT  deploy stage ")
    assert any(ln.startswith("  saved: nothing (no --out)") for ln in lines)
    assert "FIT" not in io.out and "time:" not in io.out
    assert len(lines) < 25 and io.err == ""
