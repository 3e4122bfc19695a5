"""The README's examples run as written, its set-up commands are the CI's and work on Debian's
own Python, and what it says agrees with the code (the paper it cites, the stage to deploy)."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
SETUP = README[README.index("## Set-up") : README.index("## What you get")]


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
    assert "shared/seed" not in README


def test_the_macos_and_fedora_notes_name_the_variable_the_tests_read():
    notes = SETUP[SETUP.index("**macOS and Fedora.**") :]
    assert "HANDEYE_JAX_CHROMIUM" in notes and "dnf install" in notes and "brew" in notes
    assert "HANDEYE_JAX_CHROMIUM" in (ROOT / "tests" / "test_tablet_page.py").read_text()
    assert "HANDEYE_JAX_CHROMIUM" in (ROOT / ".ci" / "install-chromium").read_text()


def test_the_stage_to_deploy_is_the_calibrations_and_predict_defaults_to_it():
    from handeye_jax.cli import build_parser

    assert not re.findall(r"[Dd]eploy stage (\d)", README)  # no fixed advice: it is chosen
    predict = build_parser().parse_args(["predict", "r.json", "p.csv"])
    export = build_parser().parse_args(["export", "r.json", "--format", "json"])
    assert predict.stage is None and export.stage is None  # the result's own choice
    assert "the stage the calibration chose to deploy" in " ".join(README.split())
    assert "--stage 1" in README and "--stage 2" in README  # and how to send either


def test_the_command_line_block_lists_every_calibrate_option():
    from handeye_jax.cli import build_parser

    block = README[README.index("## Command line"):]
    block = block[: block.index("```", block.index("```text") + 7)]
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    options = [o for a in sub.choices["calibrate"]._actions for o in a.option_strings
               if o.startswith("--") and o != "--help"]  # fmt: skip
    assert len(options) > 10
    for option in options:
        assert option in block, option


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
    """The README's "Layout": one paragraph per layer, the first of its own docstring, in the
    layers' order."""
    from tests.test_layers import LAYERS

    text = (ROOT / "README.md").read_text()
    block = text.split("<!-- folders:")[1].split("<!-- end folders -->")[0]
    want = []
    for layer in LAYERS[:-1]:  # the root's own __init__ is the API, not a folder
        name = f"{layer}.py" if layer == "geometry" else f"{layer}/"
        path = ROOT / "handeye_jax" / (name if layer == "geometry" else f"{layer}/__init__.py")
        want.append(f"**`{name}`** {_first_paragraph(path)}")
    got = [" ".join(p.split()) for p in block.split("-->", 1)[1].strip().split("\n\n")]
    assert got == want
