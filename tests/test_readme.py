"""The README's examples run as written, its set-up commands are the CI's and work on Debian's
own Python, and what it says agrees with the code (the paper it cites, the stage to deploy)."""

import argparse
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
SETUP = README[README.index("## Set-up") : README.index("## What you get")]
DOCS = {p.name: p.read_text() for p in sorted((ROOT / "docs").glob("*.md"))}
#: The README and every page of docs/: what a user reads.
EVERYTHING = README + "".join(DOCS.values())


@pytest.mark.slow
def test_python_examples_run(tmp_path, monkeypatch):
    blocks = re.findall(r"```python\n(.*?)```", README, flags=re.S)
    assert len(blocks) >= 2
    monkeypatch.chdir(ROOT)
    ns: dict = {}
    code = "\n".join(blocks).replace('"paper.result.json"', repr(str(tmp_path / "r.json")))
    exec(compile(code, "README.md", "exec"), ns)
    result = ns["result"]  # the default fit: maximum likelihood under the noise model
    assert result.stage1.noise is not None and result.deploy_stage in (1, 2)
    assert 0 < result.diagnostics.expected.mean_mm < result.diagnostics.expected.p95_mm
    assert ns["hand_xy_mm"].shape == (1, 2)
    assert float(ns["dx_dparams"].xc) != 0.0


def _setup_commands():
    return re.findall(r"```sh\n(.*?)\n```", SETUP, flags=re.S)


def test_three_setup_commands_and_ci_runs_the_test_one():
    venv, calibrate, tests = _setup_commands()
    assert venv.startswith("python3 -m venv ")
    assert "handeye-jax calibrate data/paper2023.toml" in calibrate
    ci = (ROOT / ".ci" / "run").read_text()
    chromium, install, test = tests.split(" && ")
    assert chromium in ci
    assert install.replace('"', "") in ci.replace('"', "") or '-e ".[test]"' in ci
    assert test in ci
    assert os.access(ROOT / ".ci" / "run", os.X_OK)


def test_the_venv_step_gives_a_pip_of_its_own_on_debians_python(tmp_path):
    # Debian's /usr/bin/python3 refuses `pip install` outside a virtual environment (PEP 668).
    debian = Path("/usr/bin/python3")
    python = debian if (debian.exists() and sys.platform == "linux") else Path(sys.executable)
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "python3").symlink_to(python)
    venv = _setup_commands()[0]
    check = "python3 -c 'import sys; print(sys.prefix != sys.base_prefix)' && python3 -m pip -V"
    env = {"PATH": f"{bin_dir}{os.pathsep}/usr/bin:/bin", "HOME": str(tmp_path)}
    p = subprocess.run(["sh", "-c", f"{venv} && {check}"], cwd=tmp_path, env=env,
                       capture_output=True, text=True)  # fmt: skip
    assert p.returncode == 0, p.stderr
    is_venv, pip = p.stdout.splitlines()
    assert is_venv == "True" and str(tmp_path / ".venv") in pip


def test_the_paper_is_cited_not_a_path_outside_the_repository():
    assert "Hand–Eye Calibration Using a Tablet Computer" in README
    assert "*Math. Comput. Appl.* **2023**, 28(1), 22" in README
    assert "https://doi.org/10.3390/mca28010022" in README
    assert "shared/seed" not in EVERYTHING


def _anchor(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(text: str) -> set[str]:
    text = re.sub(r"```.*?```", "", text, flags=re.S)
    return {_anchor(h) for h in re.findall(r"(?m)^#+ (.*)$", text)}


def test_every_link_between_the_readme_and_docs_resolves():
    """Each relative link of README.md and docs/*.md names a file of the repository, and each
    #anchor a heading of that page."""
    pages = {ROOT / "README.md": README, **{ROOT / "docs" / n: t for n, t in DOCS.items()}}
    checked = 0
    for page, text in pages.items():
        for target in re.findall(r"\]\(([^)\s]+)\)", re.sub(r"```.*?```", "", text, flags=re.S)):
            if re.match(r"[a-z]+:", target):
                continue
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            assert dest.exists(), (page.name, target)
            if anchor:
                assert anchor in _anchors(dest.read_text()), (page.name, target)
            checked += 1
    assert checked >= 20  # the README's index and the pages' cross-references


def test_the_readme_is_a_ten_minute_read_that_indexes_every_page():
    """About 2,000 words a user reads in ten minutes; the rest is in docs/, every page linked."""
    prose = re.sub(r"```.*?```", "", README, flags=re.S)
    assert len(prose.split()) <= 2600, len(prose.split())
    for name in DOCS:
        assert f"(docs/{name})" in README, name


def test_the_macos_and_fedora_notes_name_the_variable_the_tests_read():
    notes = SETUP[SETUP.index("**macOS and Fedora.**") :]
    assert "HANDEYE_JAX_CHROMIUM" in notes and "dnf install" in notes and "brew" in notes
    assert "HANDEYE_JAX_CHROMIUM" in (ROOT / "tests" / "test_tablet_page.py").read_text()
    assert "HANDEYE_JAX_CHROMIUM" in (ROOT / ".ci" / "install-chromium").read_text()


def test_the_stage_to_deploy_is_the_calibrations_and_predict_defaults_to_it():
    from handeye_jax.cli import build_parser

    assert not re.findall(r"[Dd]eploy stage (\d)", EVERYTHING)  # no fixed advice: chosen
    predict = build_parser().parse_args(["predict", "r.json", "p.csv"])
    export = build_parser().parse_args(["export", "r.json", "--format", "json"])
    assert predict.stage is None and export.stage is None  # the result's own choice
    assert "the stage the calibration chose to deploy" in " ".join(EVERYTHING.split())
    assert "--stage 1" in EVERYTHING and "--stage 2" in EVERYTHING  # and how to send either


def test_the_suite_time_is_stated_with_its_conditions():
    m = re.search(r"The suite took (.*?)\.\n", SETUP, flags=re.S)
    assert m and re.search(r"\d+(\.\d+)? min", m.group(1)) and "core" in m.group(1)


def _first_paragraph(path: Path) -> str:
    import ast

    doc = ast.get_docstring(ast.parse(path.read_text()))
    text = " ".join(doc.split("\n\n")[0].split())
    text = re.sub(r":\w+:`~?([^`]+)`", r"`\1`", text)  # Sphinx roles as Markdown code
    return text.replace("``", "`")


def test_the_layout_says_what_each_folder_says_of_itself():
    """docs/layout.md: one paragraph per layer, the first of its own docstring, in the
    layers' order."""
    from tests.test_layers import LAYERS

    text = DOCS["layout.md"]
    block = text.split("<!-- folders:")[1].split("<!-- end folders -->")[0]
    want = []
    for layer in LAYERS[:-1]:  # the root's own __init__ is the API, not a folder
        name = f"{layer}.py" if layer == "geometry" else f"{layer}/"
        path = ROOT / "handeye_jax" / (name if layer == "geometry" else f"{layer}/__init__.py")
        want.append(f"**`{name}`** {_first_paragraph(path)}")
    got = [" ".join(p.split()) for p in block.split("-->", 1)[1].strip().split("\n\n")]
    assert got == want


def _command_line_entries() -> dict[str, str]:
    """The "Command line" synopsis block: each command's entry (its lines) by its name."""
    section = DOCS["command-line.md"]
    block = re.search(r"```text\n(.*?)```", section, flags=re.S).group(1)
    entries: dict[str, str] = {}
    for line in block.splitlines():
        if line.startswith("handeye-jax "):
            name = line.split()[1]
            entries[name] = line
        else:
            entries[name] += "\n" + line
    return entries


def test_the_command_line_block_lists_every_command_and_option():
    from handeye_jax.cli import build_parser

    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    entries = _command_line_entries()
    assert set(sub.choices) <= set(entries), set(sub.choices) - set(entries)
    for name, command in sub.choices.items():
        options = {o for a in command._actions for o in a.option_strings if o.startswith("--")}
        missing = {o for o in options - {"--help"} if o not in entries[name]}
        assert not missing, (name, missing)


@pytest.mark.slow
def test_the_recalibration_walkthrough_runs_as_written(tmp_path, monkeypatch, capsys):
    """Every command of "Try it without a robot", as printed, in a folder of its own (with a
    smaller DE budget as the commands' defaults, to keep the suite's time)."""
    import dataclasses

    import handeye_jax.calibration as calibration
    from handeye_jax.cli import main

    @dataclasses.dataclass(frozen=True)
    class Budget(calibration.Settings):
        population: int = 200
        generations: int = 400

    monkeypatch.setattr(calibration, "Settings", Budget)

    section = DOCS["recalibration.md"]
    section = section[section.index("Try it without a robot") :]
    block = re.search(r"```text\n(.*?)```", section, flags=re.S).group(1)
    lines = [line for line in block.splitlines() if line and not line.startswith("#")]
    assert lines[-1].startswith("handeye-jax evaluate")
    monkeypatch.chdir(tmp_path)
    for line in lines:
        assert main(shlex.split(line)[1:]) == 0, line
    rows = [r for r in capsys.readouterr().out.splitlines() if r.startswith("| stage 2")]
    assert len(rows) == 1 and float(rows[0].split("|")[2]) < 1.5  # mm: a pen recalibrated
# -- "Your own robot in 30 minutes", run on a twin ------------------------------------------

OWN = README[README.index("## Your own robot in 30 minutes") :]
OWN = OWN[: OWN.index("\n## ", 10)]


def _own_blocks() -> list[list[str]]:
    return [b.strip().splitlines() for b in re.findall(r"```sh\n(.*?)```", OWN, flags=re.S)]


def test_own_robot_section_has_the_six_steps_in_order():
    steps = re.findall(r"\*\*(\d)\. ", OWN)
    assert steps == ["0", "1", "2", "3", "4", "5", "6"]
    commands = [c for block in _own_blocks() for c in block]
    assert all(c.startswith(("handeye-jax ", "cp ")) for c in commands)
    assert not any("[search]" in c or "--search" in c for c in commands)  # no ranges to guess


class _RobotTwin:
    """The robot, camera, tablet and operator of the README's section, simulated: a twin rig
    with a RealSense-like lens, `paper` noise, tool0 poses reported with 0.2 deg of tilt."""

    def __init__(self, folder: Path, seed: int = 2):
        import dataclasses

        from handeye_jax import PRESETS, draw_truth
        from handeye_jax.twin import REALSENSE_LIKE

        self.folder, self.seed = folder, seed
        self.truth = dataclasses.replace(draw_truth(seed, dot_px=2.0), distortion=REALSENSE_LIKE)
        self.preset = PRESETS["paper"]
        self.rng = __import__("numpy").random.default_rng(seed)
        self.rows: list = []

    def camera_info(self) -> None:
        import yaml

        fx, fy, cx, cy = self.truth.camera_tuple_px
        w, h = self.truth.image_size_px
        (self.folder / "camera_info.yaml").write_text(yaml.safe_dump({
            "height": h, "width": w, "distortion_model": "plumb_bob",
            "d": list(self.truth.distortion), "k": [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        }))  # fmt: skip

    def set_tablet(self) -> None:
        path = self.folder / "myrig.toml"
        text = path.read_text().replace("ppi = 267.0", f"ppi = {self.truth.ppi!r}")
        assert "scale = 2.0" in text and self.truth.scale == 2.0
        path.write_text(text)

    def _pose(self, kind: str, index: int, position, phi_deg: float):
        import numpy as np

        from handeye_jax.data import ToolPose, rotation_from_rotvec, tool_pose_of_hand

        R, t = tool_pose_of_hand(position, phi_deg, 0.0, 1)
        tilt = np.radians(self.rng.normal(0.0, 0.2, 2))
        R = rotation_from_rotvec([tilt[0], tilt[1], 0.0]) @ R
        self.rows.append(ToolPose(kind, index, R, np.asarray(t, float), 0))
        self._write()

    def _write(self) -> None:
        from handeye_jax.data import poses_csv_text

        (self.folder / "poses.csv").write_text(poses_csv_text(self.rows))

    def phi(self, theta: float) -> float:
        return self.truth.hand_angle_zero_deg + self.truth.hand_angle_sign * theta

    def first_capture(self) -> None:
        t = self.truth
        self._pose("capture", 0, t.capture_position_mm, self.phi(t.capture_angle_deg))

    def pictures(self) -> None:
        """Drive to each capture of the dataset, photograph, report the pose."""
        import cv2

        from handeye_jax import load_dataset
        from handeye_jax.twin import render_capture, render_depth

        ds = load_dataset(self.folder / "myrig.toml")
        zero, sign = ds.hand_angle_zero_deg, ds.hand_angle_sign
        for k, c in enumerate(ds.captures):
            phi = zero + sign * c.hand_angle_deg
            theta = self.truth.hand_angle_sign * (phi - self.truth.hand_angle_zero_deg)
            at = self.truth.at_capture(c.hand_position_mm, theta)
            cv2.imwrite(str(self.folder / f"CAP{k}.png"),
                        render_capture(at, self.preset.imaging, self.rng))
            cv2.imwrite(str(self.folder / f"DEP{k}.png"),
                        render_depth(at, self.preset.depth, self.rng))  # fmt: skip
            if k:
                self._pose("capture", k, c.hand_position_mm, phi)

    def touches(self) -> None:
        """Touch each landmark (the operator misses by the preset's σ; the tablet reports it
        in whole px) and report the flange pose; the page's Send writes the errors."""
        import numpy as np

        from handeye_jax import load_dataset, update_dataset

        t = self.truth
        ds = load_dataset(self.folder / "myrig.toml")
        err_px = self.rng.normal(0.0, self.preset.touch_sigma_mm, (ds.n_touches, 2))
        err_px /= t.mm_per_tablet_px
        theta = t.landmarks_hand_angle_deg[ds.touch_landmark]
        hand = t.true_command(t.surface_points(ds.tablet_px[ds.touch_landmark] + err_px), theta)
        for i in range(ds.n_touches):
            self._pose("touch", i, np.round(hand[i]), self.phi(theta[i]))
        update_dataset(self.folder / "myrig.toml", ds.replace(touch_error_px=np.round(err_px)))


@pytest.mark.slow
def test_own_robot_section_runs_on_a_twin(tmp_path, monkeypatch, capsys):
    import shutil
    import signal

    import numpy as np
    import yaml

    from handeye_jax import Predictor
    from handeye_jax.cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "data").mkdir()
    shutil.copy(ROOT / "data" / "paper2023.toml", tmp_path / "data")
    robot = _RobotTwin(tmp_path)
    robot.camera_info()
    before = {  # what the robot, camera and operator do before each command
        "handeye-jax convert": lambda: None,
        "handeye-jax tablet": robot.set_tablet,  # the user's one hand edit, [tablet] ppi
        "handeye-jax detect CAP0.png": robot.pictures,
    }
    poses_done = 0
    for block in _own_blocks():
        for command in block:
            for start, act in before.items():
                if command.startswith(start):
                    act()
            if command.startswith("handeye-jax poses"):  # the first capture's pose, then touches
                (robot.touches if poses_done else robot.first_capture)()
            if command.startswith("cp "):
                _, src, dst = command.split()
                shutil.copy(src, dst)
                continue
            argv = command.split()[1:]
            if argv[0] == "tablet":  # serves until stopped: loopback, a free port, then stop it
                argv = [a if a != "0.0.0.0" else "127.0.0.1" for a in argv] + ["--port", "0"]
                p = subprocess.Popen([sys.executable, "-m", "handeye_jax.cli", *argv],
                                     stdout=subprocess.PIPE, text=True,
                                     env={**os.environ, "PYTHONPATH": str(ROOT)})  # fmt: skip
                assert p.stdout.readline().startswith("tablet page: http://127.0.0.1:")
                p.send_signal(signal.SIGTERM)
                p.wait(timeout=30)
                continue
            assert main(argv) == 0, (command, capsys.readouterr().err)
            poses_done += argv[0] == "poses"
    assert poses_done == 2
    # The calibration: its commands touch held-out points within a fraction of a millimetre.
    t = robot.truth
    pred = Predictor.from_result(tmp_path / "myrig.result.json")
    assert pred.frames.distortion == t.distortion and pred.axes == "xyz"
    rng = np.random.default_rng(7)
    lo, hi = t.landmark_area_px()
    targets = rng.uniform(lo, hi, (20, 2))
    uv, depth = t.project(targets)
    theta = rng.uniform(0.0, 180.0, 20)
    got = pred.hand_command(uv, depth, _dataset_angle(tmp_path, t, theta),
                            capture_position_mm=t.capture_position_mm,
                            capture_hand_angle_deg=_dataset_angle(tmp_path, t,
                                                                  t.capture_angle_deg),
                            axes="xyz")  # fmt: skip
    want = t.true_command(t.surface_points(targets), theta)
    assert np.linalg.norm(got[:, :2] - want[:, :2], axis=1).mean() < 0.5
    # The exports: the camera's z as given, the pen's by the determined difference.
    urdf = (tmp_path / "end_effector.urdf.xacro").read_text()
    d = pred.frames.pen_minus_camera_z_mm
    assert 'xyz="' in urdf and f" {0.045!r}\"" in urdf and repr((45.0 + d) / 1000) in urdf
    eih = yaml.safe_load((tmp_path / "myrig_eye_on_hand.yaml").read_text())
    assert eih["transformation"]["z"] == 0.045 and eih["parameters"]["eye_on_hand"] is True
    assert (tmp_path / "handeye_calibration.py").exists()
    assert any((tmp_path / "myrig_report").iterdir())


def _dataset_angle(folder: Path, truth, theta):
    """Hand angles in the twin's convention as the dataset's convention gives them."""
    from handeye_jax import load_dataset

    ds = load_dataset(folder / "myrig.toml")
    phi = truth.hand_angle_zero_deg + truth.hand_angle_sign * theta
    return ds.hand_angle_sign * (phi - ds.hand_angle_zero_deg)
