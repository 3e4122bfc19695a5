"""Recalibration after a change of the rig (issue 17): twins of a changed rig, the
recalibration command end to end, the objective's properties, priors right and wrong."""

import functools
import json
import math
import re
from dataclasses import replace
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_objective import RIG, YawOnlyModel

from handeye_jax import (
    PRESETS,
    Diagnostics,
    GaussianObjective,
    HTMModel,
    InputError,
    L1Loss,
    LossObjective,
    ParameterSpace,
    Plan,
    Prior,
    PriorObjective,
    Recalibration,
    Settings,
    Stage1Objective,
    calibrate,
    chain_points,
    change_truth,
    diagnose,
    draw_truth,
    errors_of,
    evaluate,
    fit,
    fitness,
    format_summary,
    load_dataset,
    load_heldout,
    load_result,
    load_truth,
    recalibrate,
    recalibrate_batch,
    save_dataset,
    save_result,
    simulate,
    snake_grid_px,
    synthesize_dataset,
)
from handeye_jax._core import Stages
from handeye_jax.calibration import all_warnings, recalibration_plan
from handeye_jax.cli import main
from handeye_jax.models import AffinePair
from handeye_jax.problem import stage1_errors
from handeye_jax.twin._truth import CHANGE_MARGIN, CHANGES, RANGES
from tests.common import FAST, FAST_SETTINGS

#: The suite's budget (tests/common.py) for every fit here, so that they share compiled
#: programs with each other and with the rest of the suite.
BUDGET = dict(population=FAST_SETTINGS.population, generations=FAST_SETTINGS.generations)
#: The landmarks of a recalibration on four touches: the grid's corners.
CORNERS = (0, 2, 6, 8)
LANDMARK_FIELDS = ("tablet_px", "image_px", "depth_mm", "hand_xy_mm", "hand_angle_deg",
                   "touch_error_px")  # fmt: skip


def subset(ds, idx):
    i = np.asarray(idx)
    return ds.replace(**{f: getattr(ds, f)[i] for f in LANDMARK_FIELDS})


def one_line(capsys, *needles) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error: " in err and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, (needle, err)
    return err


# -- twins of a changed rig ------------------------------------------------------------------


@settings(max_examples=12, deadline=None)
@given(st.integers(0, 10**6), st.integers(0, 2**32), st.sampled_from(sorted(CHANGES)))
def test_a_changed_twin_differs_only_in_that_part_within_the_ranges(old_seed, seed, part):
    truth = draw_truth(old_seed)
    new = change_truth(truth, part, seed)
    assert change_truth(truth, part, seed) == new  # the seed gives the same change
    group = HTMModel.groups[part]
    changed = {n for n in HTMModel.param_names if new.model[n] != truth.model[n]}
    assert changed and changed <= set(group)
    r = CHANGES[part]

    def moved(x, y):
        return math.hypot(new.model[x] - truth.model[x], new.model[y] - truth.model[y])

    def turned(name):
        return abs(new.model[name] - truth.model[name])

    if part == "pen":
        assert r["tip_move_mm"][0] <= moved("xp", "yp") <= r["tip_move_mm"][1]
    elif part == "tablet":
        assert r["move_mm"][0] <= moved("xt", "yt") <= r["move_mm"][1]
        assert r["turn_deg"][0] <= turned("gamma_t") <= r["turn_deg"][1]
        for name in ("alpha_t", "beta_t"):
            assert RANGES[name][0] <= new.model[name] <= RANGES[name][1]
    else:
        assert r["move_mm"][0] <= moved("xc", "yc") <= r["move_mm"][1]
        for name in ("alpha_c", "beta_c", "gamma_c"):
            assert r["turn_deg"][0] <= turned(name) <= r["turn_deg"][1]
    for name in group:  # inside the search range, off its bounds
        lo, hi = HTMModel.default_ranges[name]
        margin = CHANGE_MARGIN * (hi - lo)
        assert lo + margin <= new.model[name] <= hi - margin
    # Everything but the model and (after a tablet or camera change) the capture pose stays.
    a, b = truth.to_dict(), new.to_dict()
    moved_too = {"model"} | ({"capture_position_mm"} if part != "pen" else set())
    assert {k for k in a if a[k] != b[k]} <= moved_too
    uv, z = new.project(new.landmarks_tablet_px)  # the camera still sees every landmark
    assert (z > 0).all() and (uv > 0).all() and (uv < new.image_size_px).all()


def test_simulate_change_writes_the_changed_twin_and_refuses_bad_requests(tmp_path, capsys):
    old, new = tmp_path / "old", tmp_path / "new"
    small = ["--exact", "--preset", "none", "--heldout", "2"]
    assert main(["simulate", str(old), "--seed", "3", *small]) == 0
    truth = old / "truth.json"
    capsys.readouterr()
    assert main(["simulate", str(new), "--truth", str(truth), "--change", "pen", "--seed", "4",
                 *small]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert load_truth(new / "truth.json") == change_truth(load_truth(truth), "pen", 4)
    assert "the pen of" in out and " xp " in out and " yp " in out and "xc" not in out
    assert main(["simulate", str(tmp_path / "a"), "--change", "pen", *small]) == 2
    one_line(capsys, "--change: needs --truth")
    with pytest.raises(SystemExit) as e:
        main(["simulate", str(tmp_path / "b"), "--truth", str(truth), "--change", "wheel"])
    assert e.value.code == 2
    one_line(capsys, "argument --change: invalid choice: 'wheel'")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    with pytest.raises(ValueError, match="unknown part 'wheel'"):
        change_truth(load_truth(truth), "wheel", 1)


# -- the recalibration command ---------------------------------------------------------------


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """An old twin calibrated, the pen changed, the new twin's four corners: (folder, paths)."""
    d = tmp_path_factory.mktemp("recal")
    noisy = ["--exact", "--preset", "paper", "--heldout", "20", "--quiet"][:-1]
    assert main(["simulate", str(d / "old"), "--seed", "2", *noisy]) == 0
    assert main(["calibrate", str(d / "old" / "dataset.toml"), "--out", str(d / "old.json"),
                 "--no-diagnostics", *FAST]) == 0  # fmt: skip
    assert main(["simulate", str(d / "new"), "--truth", str(d / "old" / "truth.json"),
                 "--change", "pen", "--seed", "12", *noisy]) == 0  # fmt: skip
    ds = load_dataset(d / "new" / "dataset.toml")
    save_dataset(subset(ds, CORNERS), d / "new4.toml")
    save_dataset(subset(ds, (0, 8)), d / "new2.toml")
    return d


def _touching_mm(result, folder: Path) -> tuple[float, float]:
    rows = evaluate(result, load_truth(folder / "truth.json"), load_heldout(folder / "heldout.csv"))
    return rows[0].mean_mm, rows[1].mean_mm


@pytest.mark.slow
@pytest.mark.parametrize("fix", [False, True])
def test_recalibrate_on_four_touches_end_to_end(rig, capsys, fix):
    out = rig / f"recal-{fix}.json"
    fixed = ["--fix"] if fix else []
    argv = ["calibrate", str(rig / "new4.toml"), "--prior", str(rig / "old.json"), "--refit",
            "pen", "--out", str(out), "--no-diagnostics", "--verbose", *FAST, *fixed]  # fmt: skip
    capsys.readouterr()
    assert main(argv) == 0
    summary = capsys.readouterr().out
    doc = json.loads(out.read_text())  # what the file says
    others = "fixed" if fix else "prior"
    assert doc["stage1"]["status"] == {n: "free" if n in ("xp", "yp") else others
                                       for n in HTMModel.param_names}  # fmt: skip
    assert set(doc["stage2"]["status"].values()) == {others}
    assert doc["recalibration"] == {"previous": "old.json", "refit": ["pen"], "others": others}
    if fix:
        assert set(doc["stage1"]["fixed_source"].values()) == {"old.json"}
    else:
        assert doc["stage1"]["prior"]["source"] == doc["stage2"]["prior"]["source"] == "old.json"
        # The old fit's noise, which the new data were weighed with, is written and checked.
        sigma = doc["stage1"]["prior"]["data_sigma_mm"]
        assert 0.0 < sigma < 1.0 and f"{sigma:.3g} mm per component" in summary
        doc["stage1"]["prior"]["data_sigma_mm"] = -1.0
        bad = rig / "bad-sigma.json"
        bad.write_text(json.dumps(doc))
        with pytest.raises(InputError, match="stage1.prior.data_sigma_mm"):
            load_result(bad)
    r = load_result(out)
    assert "stage 1: F = " in summary and f"saved: {out}" in summary
    # It predicts, and far better on the changed rig than the old result does.
    old = load_result(rig / "old.json")
    new_s1, new_s2 = _touching_mm(r, rig / "new")
    old_s1, old_s2 = _touching_mm(old, rig / "new")
    assert new_s1 < 1.0 and new_s2 < 1.0 and old_s1 > 2.0 and old_s2 > 2.0
    points = rig / "points.csv"
    points.write_text((rig / "new" / "heldout.csv").read_text())
    assert main(["predict", str(out), str(points), "--out", str(rig / "cmd.csv")]) == 0
    held = load_heldout(points)
    cmd = np.loadtxt(rig / "cmd.csv", delimiter=",", skiprows=1)[:, -2:]
    np.testing.assert_allclose(cmd, r.predict(held.image_px, held.depth_mm,
                                              held.hand_angle_deg), atol=6e-7)  # fmt: skip


@pytest.mark.parametrize(
    "args,needles",
    [
        (["--refit", "pen"], ["--refit: needs --prior OLD.result.json"]),
        (["--fix"], ["--fix: needs --prior"]),
        (["--prior", "{old}"], ["--refit: name what changed"]),
        (["--prior", "{old}", "--refit", "wheel"],
         ["--refit: unknown group or parameter 'wheel'", "camera, tablet, pen"]),
        (["--prior", "{old}", "--refit", "pen", "--model", "dh"],
         ["old.json: model: is 'htm'; --model says 'dh'"]),
    ],
)  # fmt: skip
def test_recalibrate_refuses_bad_requests_in_one_line(rig, capsys, args, needles):
    out = rig / "refused.json"
    args = [a.replace("{old}", str(rig / "old.json")) for a in args]
    capsys.readouterr()
    assert main(["calibrate", str(rig / "new4.toml"), *args, "--out", str(out), *FAST]) == 2
    one_line(capsys, *needles)
    assert not out.exists()


@pytest.mark.slow
def test_too_few_landmarks_for_a_fit_from_scratch_suggest_a_prior(rig, capsys):
    capsys.readouterr()
    assert main(["calibrate", str(rig / "new2.toml"), *FAST]) == 2
    one_line(capsys, "new2.toml: landmarks: stage 1 has 12 free parameters but only 8 "
             "residuals", "needs at least 3 landmarks", "--prior and --refit")  # fmt: skip
    # ... which two touches are enough for, with the pen refitted:
    assert main(["calibrate", str(rig / "new2.toml"), "--prior", str(rig / "old.json"),
                 "--refit", "pen", "--no-diagnostics", *FAST]) == 0  # fmt: skip
    # A tablet has five parameters: one touch cannot give them (4 residuals + 7 from the prior).
    save_dataset(subset(load_dataset(rig / "new2.toml"), (0,)), rig / "new1.toml")
    capsys.readouterr()
    assert main(["calibrate", str(rig / "new1.toml"), "--prior", str(rig / "old.json"),
                 "--refit", "tablet", *FAST]) == 2  # fmt: skip
    one_line(capsys, "new1.toml: landmarks: stage 1 has 12 free parameters but only 11 residuals")


@pytest.mark.slow
def test_a_fit_with_no_residuals_to_spare_warns(rig):
    three = subset(load_dataset(rig / "new" / "dataset.toml"), (0, 2, 6))
    r = calibrate(three, Settings(**BUDGET))
    said = [w for w in map(str, r.warnings) if "as many residuals (12: 3 landmarks x 4)" in w]
    assert said and "stage 1" in said[0] and "touch more landmarks" in said[0]
    assert not any(w.startswith("stage 2 has as many") for w in map(str, r.warnings))


# -- priors right and wrong ------------------------------------------------------------------


@pytest.mark.slow
def test_a_prior_wrong_by_five_sigma_is_flagged_naming_the_parameter(rig):
    """The pen changed and, unannounced, the tablet moved 5 prior sigmas along x: a
    recalibration of the pen names xt in a warning with how many sigma the data pull it; the
    right prior (the tablet did not move) does not."""
    old = load_result(rig / "old.json")
    post = old.posterior("stage1")
    prior = post.marginal([n for n in post.names if n not in ("xp", "yp")])
    sigma = float(prior.sigma[prior.names.index("xt")])
    truth = load_truth(rig / "new" / "truth.json")
    moved = replace(truth, model={**truth.model, "xt": truth.model["xt"] + 5.0 * sigma})
    budget = Settings(**BUDGET)
    right = recalibrate(load_dataset(rig / "new" / "dataset.toml"), old, ("pen",), budget,
                        source="old.json")  # fmt: skip
    wrong = recalibrate(simulate(moved, PRESETS["paper"], 12, exact=True).dataset, old,
                        ("pen",), budget, source="old.json")  # fmt: skip
    pulls = {p.param: p.pull for p in wrong.stage1.prior.pulls}
    assert pulls["xt"] > 3.0  # towards where the tablet went
    # The same two in one recalibrate_batch (one problem a wave: the programs above serve):
    # each is its own recalibration, bit for bit, in order.
    both = recalibrate_batch([right.data, wrong.data], old, ("pen",), budget, wave=1)
    for one, batched in zip((right, wrong), both, strict=True):
        assert [batched.stage1.F, batched.stage2.F] == [one.stage1.F, one.stage2.F]
        assert batched.stage1.params == one.stage1.params
        assert batched.stage2.params == one.stage2.params
    # xt alone is flagged: the parameters the wrong prior dragged along follow it.
    checks = [w for w in wrong.warnings if w.kind == "prior"]
    assert [w.param for w in checks] == ["xt"]
    assert {p.param: p.follows for p in wrong.stage1.prior.pulls}["yt"] == "xt"
    # Stage 2's prior, fitted on the old stage 1, is pulled too when stage 1's is: its checks
    # are one line that follows stage 1's, not flags of their own.
    plan = recalibration_plan(wrong.data, old, ("pen",), source="old.json")
    spaces = Stages(plan.space1, plan.space2)
    pulled = replace(wrong.stage2.prior, pulls=tuple(
        replace(q, pull=9.0 - i, follows=None) for i, q in enumerate(wrong.stage2.prior.pulls)))
    stages = Stages(wrong.stage1, replace(wrong.stage2, prior=pulled))
    checks = [w for w in all_warnings(9, spaces, stages, None) if w.kind == "prior"]
    assert [w.param for w in checks] == ["xt", None]
    assert checks[1].text.startswith(f"stage 2: the data pull its prior too ({pulled.names[0]} 9.0")
    assert "follows stage 1's prior check" in checks[1].text
    alone = Stages(replace(wrong.stage1, prior=None), stages.stage2)
    assert [w.param for w in all_warnings(9, spaces, alone, None)
            if w.kind == "prior"] == list(pulled.names[:6])  # fmt: skip
    text = format_summary(wrong)
    said = [line for line in text.splitlines() if "the data pull xt " in line]
    assert len(said) == 1 and re.match(r"  \d+\. stage 1: the data pull xt ", said[0])
    assert f"xt {abs(pulls['xt']):.1f} sigma from its prior (old.json" in said[0]
    assert not any("pull xt " in w for w in map(str, right.warnings))


@pytest.mark.slow
def test_a_prior_is_tested_against_the_fits_its_old_data_could_not_exclude(rig):
    """The tablet moved 5 prior sigmas along x, and the old result is told that a fit with xt
    moved as far (say, a mirror mount) fitted its data as well: the rig may have been there all
    along, so the data pull nothing from that fit and nothing is flagged. With that fit on the
    other side, xt is flagged and named first, as without one. And the alternative survives a
    marginal and a conditional of the prior, and the result file, exactly.

    With the tablet's yaw moved too, to where an alternative says the rig may have been, the
    yaw and the tilt it drags follow xt: from that alternative, once xt moves, they are not
    pulled. Told of no alternative, the yaw is flagged beside xt (it moved too), and the tilt
    follows the yaw: once both move, it is not pulled."""
    from handeye_jax.calibration import Ambiguity

    old = load_result(rig / "old.json")
    prior = old.posterior("stage1")
    sigma = float(prior.marginal(["xt"]).sigma[0])
    truth = load_truth(rig / "new" / "truth.json")
    moved = replace(truth, model={**truth.model, "xt": truth.model["xt"] + 5.0 * sigma})
    data = simulate(moved, PRESETS["paper"], 12, exact=True).dataset  # the test above's

    def told(untested=("xt",), **differs: float):
        alternative = Ambiguity(kind="mirror camera mount", differs=differs,
                                delta_F_mm=0.0, here_mm=0.0, elsewhere_mm=(0.0, 0.0))  # fmt: skip
        return replace(old, diagnostics=Diagnostics(ambiguities=(alternative,) if differs else (),
                                                    untested_params=untested))  # fmt: skip

    budget = Settings(**BUDGET)
    yaw = 5.0 * float(prior.marginal(["gamma_t"]).sigma[0])
    turned = replace(moved, model={**moved.model, "gamma_t": moved.model["gamma_t"] + yaw})
    turned_data = simulate(turned, PRESETS["paper"], 12, exact=True).dataset
    for old_said, beside, tilt_follows in ((told(untested=(), gamma_t=yaw), [], "xt"),
                                           (told(untested=()), ["gamma_t"], "gamma_t")):
        r = recalibrate(turned_data, old_said, ("pen",), budget, source="old.json")
        flagged = [w.param for w in r.warnings if w.kind == "prior" and w.param is not None]
        assert flagged == ["xt", *beside]
        follows = {p.param: p.follows for p in r.stage1.prior.pulls}
        assert follows["gamma_t"] == (None if beside else "xt")
        assert follows["beta_t"] == tilt_follows

    there, opposite = told(xt=5.0 * sigma), told(xt=-5.0 * sigma)
    post = there.posterior("stage1")
    assert "xt" not in post.untested and post.alternatives == ({"xt": 5.0 * sigma},)
    others = [n for n in post.names if n not in ("xp", "yp")]
    assert post.marginal(others).alternatives == post.alternatives
    assert post.conditional(others, {"xp": 0.0, "yp": 0.0}).alternatives == post.alternatives
    near = recalibrate(data, there, ("pen",), budget, source="old.json")
    far = recalibrate(data, opposite, ("pen",), budget, source="old.json")
    assert not [w for w in near.warnings if w.kind == "prior"]
    pulls = {p.param: p.pull for p in near.stage1.prior.pulls}
    assert abs(pulls["xt"]) < 3.0
    checks = [w for w in far.warnings if w.kind == "prior"]
    assert checks and checks[0].param == "xt"
    assert far.stage1.prior.alternatives == ({"xt": -5.0 * sigma},)
    path = rig / "far.json"
    save_result(far, path)
    assert load_result(path).stage1.prior == far.stage1.prior


@pytest.mark.slow
def test_a_moved_parameter_the_linear_pull_misses_is_named_first():
    """``benchmarks/wrong_prior.py``'s seed 5 at the suite's budget: the pen changed and the
    tablet moved 5 prior sigmas along y, recalibrated on the four corners. At the fit the
    wrong prior dragged, the linear w-test puts yt at 1.0 sigma and the tilt alpha_t at 4.0;
    refitted with each tested parameter's prior mean free, the data pull yt most, and the
    tilt follows it."""
    seed = 5
    truth = draw_truth(seed, dot_px=1.0)
    budget = replace(FAST_SETTINGS, seed=seed)
    old = diagnose(calibrate(simulate(truth, PRESETS["paper"], seed).dataset, budget))
    post = old.posterior("stage1")
    prior = post.marginal([n for n in post.names if n not in HTMModel.groups["pen"]])
    sigma = float(prior.sigma[prior.names.index("yt")])
    changed = change_truth(truth, "pen", seed)
    moved = replace(changed, model={**changed.model, "yt": changed.model["yt"] + 5.0 * sigma})
    new = simulate(moved, PRESETS["paper"], 1000 + seed).dataset.landmark_subset(CORNERS)
    r = recalibrate(new, old, ("pen",), budget)
    checks = [w for w in r.warnings if w.kind == "prior"]
    assert checks and checks[0].param == "yt"
    pulls = {p.param: p for p in r.stage1.prior.pulls}
    assert pulls["yt"].pull > 5.0
    assert pulls["alpha_t"].follows == "yt"


# -- properties of the objective -------------------------------------------------------------


@functools.cache
def _obs():
    """A noise-free twin's observations (made at first use: collection, which every test
    process does, stays free of JAX's computations)."""
    t = draw_truth(5)
    return synthesize_dataset(t.htm(), t.rig(), snake_grid_px(), 22.5 * np.arange(9)).observations()


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_every_parameter_free_and_no_prior_is_the_papers_objective(seed):
    rng = np.random.default_rng(seed)
    lo, hi = HTMModel.search_bounds()
    theta = rng.uniform(lo, hi)
    template = HTMModel.from_vector(jnp.asarray(rng.uniform(lo, hi)))  # its values do not matter
    space = ParameterSpace.all_free(template)
    assert space.free == HTMModel.param_names and space.prior is None
    from handeye_jax.calibration import with_prior

    obs = _obs()
    objective = with_prior(Stage1Objective(space.template, obs, space.free), space, 9)
    F, f1, f2 = fitness(stage1_errors(chain_points(HTMModel.from_vector(jnp.asarray(theta)), obs)))
    terms = objective.terms(jnp.asarray(theta))
    assert set(terms) == {"f1", "f2"}
    assert float(objective(jnp.asarray(theta))) == pytest.approx(float(F), rel=1e-12)
    assert float(terms["f1"]) == pytest.approx(float(f1), rel=1e-12)
    assert float(terms["f2"]) == pytest.approx(float(f2), rel=1e-12)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 5))
def test_prior_residual_squares_are_the_negative_log_density(seed, k):
    rng = np.random.default_rng(seed)
    names = tuple(rng.choice(HTMModel.param_names, k, replace=False))
    A = rng.normal(size=(k, k))
    precision = A @ A.T + 0.1 * np.eye(k)
    prior = Prior(names, rng.normal(size=k) * 10, precision)
    free = HTMModel.param_names
    index = tuple(free.index(n) for n in names)
    weight = float(rng.uniform(0.01, 2.0))
    objective = PriorObjective(Stage1Objective(HTMModel, _obs(), free), index,
                               jnp.asarray(prior.mean), jnp.asarray(prior.whitener()),
                               jnp.asarray(weight))  # fmt: skip
    theta = rng.uniform(*HTMModel.search_bounds())
    at = theta[list(index)]
    constant = 0.5 * (k * math.log(2 * math.pi) - np.linalg.slogdet(precision)[1])
    nll = prior.neg_log_density(at) - constant
    r = np.asarray(objective.nll_residuals(jnp.asarray(theta)))
    assert float(np.sum(r**2)) == pytest.approx(nll, rel=1e-9, abs=1e-12)
    assert float(0.5 * (at - prior.mean) @ precision @ (at - prior.mean)) == pytest.approx(nll)
    value = float(objective.terms(jnp.asarray(theta))["prior"])
    assert value == pytest.approx(weight * nll, rel=1e-9, abs=1e-12)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.01, 10.0), st.integers(0, 8))
def test_a_map_fits_data_term_is_gaussian_and_takes_leave_one_out_weights(seed, c, left_out):
    """GaussianObjective: each length block becomes c times the mean squared length, its
    residuals' squares sum to it, and a zero weight leaves a landmark out exactly."""
    theta = jnp.asarray(np.random.default_rng(seed).uniform(*HTMModel.search_bounds()))
    base = Stage1Objective(HTMModel, _obs())
    gauss = GaussianObjective(base, jnp.asarray(c))
    e = errors_of(base, theta)
    want = c * (np.mean(np.sum(np.asarray(e.image_vs_tablet) ** 2, axis=1))
                + np.mean(np.sum(np.asarray(e.hand) ** 2, axis=1)))  # fmt: skip
    assert float(gauss(theta)) == pytest.approx(want, rel=1e-12)
    assert float(jnp.sum(gauss.residuals(theta) ** 2)) == pytest.approx(want, rel=1e-12)
    keep = np.array([m for m in range(9) if m != left_out])
    weights = jnp.ones(9).at[left_out].set(0.0)
    loo = LossObjective(gauss, L1Loss(), weights)
    assert float(loo(theta)) == pytest.approx(float(gauss.on_landmarks(keep)(theta)), rel=1e-12)
    wrapped = errors_of(PriorObjective(gauss, (0,), jnp.zeros(1), jnp.eye(1), jnp.asarray(1.0)),
                        theta)  # fmt: skip
    np.testing.assert_array_equal(wrapped.hand, e.hand)  # the paper's errors inside


@functools.cache
def _exact_twin():
    """A twin truth and its noise-free data: at its own targets and hand angles, and at 12
    held-out ones (made at first use, as :func:`_obs`)."""
    t = draw_truth(8)

    def exact(tablet_px, angles_deg):
        return synthesize_dataset(t.htm(), t.rig(), tablet_px, angles_deg, scene=t.scene())

    held = exact(np.random.default_rng(0).uniform(*t.landmark_area_px(), (12, 2)),
                 np.random.default_rng(1).uniform(0.0, 180.0, 12))  # fmt: skip
    return t, exact(t.landmarks_tablet_px, t.landmarks_hand_angle_deg), held


@pytest.mark.slow
@settings(max_examples=2, deadline=None)
@given(st.sampled_from(HTMModel.param_names))
def test_fixing_a_parameter_at_its_truth_recovers_the_rest(name):
    """Noise-free data, one parameter held at its true value, every other one searched: the
    fit sends the hand where the truth does, to 1e-6 mm (held-out targets)."""
    truth, exact, held = _exact_twin()
    free = tuple(n for n in HTMModel.param_names if n != name)
    lo, hi = HTMModel.search_bounds()
    keep = [HTMModel.param_names.index(n) for n in free]
    space1 = ParameterSpace(truth.htm(), free, lo[keep], hi[keep], None, {name: "the truth"})
    identity = AffinePair.from_dict(dict(X1=0.0, Y1=0.0, theta1=0.0, Sx1=1.0, Sy1=1.0,
                                         X2=0.0, Y2=0.0, theta2=0.0, Sx2=1.0, Sy2=1.0))  # fmt: skip
    space2 = ParameterSpace(identity, (), [], [])
    r = fit(exact, Plan(space1, space2, free, ()), Settings(seed=1, **BUDGET))
    assert r.stage1.status[name] == "fixed" and r.stage1.fixed_source[name] == "the truth"
    assert r.stage1.params[name] == truth.model[name] and r.stage1.F < 1e-6
    sent = r.predict(held.image_px, held.depth_mm, held.hand_angle_deg, stage=1)
    assert np.max(np.linalg.norm(sent - held.hand_xy_mm, axis=1)) < 1e-6


# -- a third model ---------------------------------------------------------------------------


@pytest.mark.slow
def test_a_model_defined_in_a_test_recalibrates_its_pen():
    """YawOnlyModel (tests/test_objective.py) declares its groups and nothing else: moving its
    pen in noise-free data, a refit of the pen on three touches from the old fit finds it."""
    values = dict(xc=1.0, yc=30.0, gamma_c=3.0, xt=150.0, yt=40.0, gamma_t=-2.0, xp=2.0, yp=-20.0)
    angles = 22.5 * np.arange(9)
    old = synthesize_dataset(YawOnlyModel.from_dict(values), RIG, snake_grid_px(), angles)
    s = Settings(model="yaw-only-test", seed=0, **BUDGET)
    before = calibrate(old, s)
    assert before.stage1.F < 1e-6
    moved = {**values, "xp": -4.0, "yp": -28.0}
    new = synthesize_dataset(YawOnlyModel.from_dict(moved), RIG, snake_grid_px(), angles)
    after = recalibrate(subset(new, (0, 2, 6)), before, ("pen",), s)
    assert after.stage1.status["xp"] == "free" and after.stage1.status["xc"] == "prior"
    for n, v in moved.items():
        assert abs(after.stage1.params[n] - v) < 1e-6, n
    assert after.recalibration == Recalibration("previous result (synthetic)", ("pen",), "prior")
