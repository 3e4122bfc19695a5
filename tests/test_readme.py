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


@pytest.mark.slow
def test_python_examples_run(tmp_path, monkeypatch):
    blocks = re.findall(r"```python\n(.*?)```", README, flags=re.S)
    assert len(blocks) >= 2
    monkeypatch.chdir(ROOT)
    ns: dict = {}
    code = "\n".join(blocks).replace('"paper.result.json"', repr(str(tmp_path / "r.json")))
    exec(compile(code, "README.md", "exec"), ns)
    assert ns["result"].stage1.F <= 1.675
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


def test_one_stage_to_deploy_and_predict_and_the_page_default_to_it():
    from handeye_jax.cli import build_parser

    advice = set(re.findall(r"[Dd]eploy stage (\d)", README))
    assert len(advice) == 1, advice
    (stage,) = advice
    predict = build_parser().parse_args(["predict", "r.json", "p.csv"])
    assert predict.stage == int(stage)
    page = (ROOT / "handeye_jax" / "tablet" / "static" / "index.html").read_text()
    assert re.search(rf'id="trial-label"[^>]*value="stage {stage}"', page)
    assert f"--stage {3 - int(stage)}" in README  # and how to send the other one


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


def _command_line_entries() -> dict[str, str]:
    """The "Command line" synopsis block: each command's entry (its lines) by its name."""
    section = README[README.index("## Command line") :]
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
        restarts: int = 4

    monkeypatch.setattr(calibration, "Settings", Budget)

    section = README[README.index("Try it without a robot") :]
    block = re.search(r"```text\n(.*?)```", section, flags=re.S).group(1)
    lines = [line for line in block.splitlines() if line and not line.startswith("#")]
    assert lines[-1].startswith("handeye-jax evaluate")
    monkeypatch.chdir(tmp_path)
    for line in lines:
        assert main(shlex.split(line)[1:]) == 0, line
    rows = [r for r in capsys.readouterr().out.splitlines() if r.startswith("| stage 2")]
    assert len(rows) == 1 and float(rows[0].split("|")[2]) < 1.5  # mm: a pen recalibrated
