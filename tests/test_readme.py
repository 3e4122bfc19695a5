"""The README's Python examples run as written, and its set-up commands are the CI's."""

import os
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


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


def test_exactly_two_setup_commands_and_ci_runs_the_test_one():
    commands = re.findall(r"```sh\n(.*?)\n```", README, flags=re.S)
    assert len(commands) == 2
    assert "handeye-jax calibrate data/paper2023.toml" in commands[0]
    ci = (ROOT / ".ci" / "run").read_text()
    chromium, install, test = commands[1].split(" && ")
    assert chromium in ci
    assert install.replace('"', "") in ci.replace('"', "") or '-e ".[test]"' in ci
    assert test in ci
    assert os.access(ROOT / ".ci" / "run", os.X_OK)
