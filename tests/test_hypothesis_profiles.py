"""Property tests draw the same examples on every clone (the "ci" profile, the default), and
new ones when asked (HYPOTHESIS_PROFILE=explore), with ten times the examples."""

import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import hypothesis
from hypothesis import given
from hypothesis import strategies as st

TESTS = Path(__file__).resolve().parent


def _draws() -> list[int]:
    seen = []

    @given(st.integers())
    def record(x):
        seen.append(x)

    record()
    return seen


def test_the_profile_draws_the_same_examples_every_time_unless_exploring():
    profile = os.environ.get("HYPOTHESIS_PROFILE", "ci")
    assert hypothesis.settings.get_current_profile_name() == profile
    if profile == "explore":
        assert _draws() != _draws()
    else:
        assert hypothesis.settings.default.database is None  # nothing replayed from the past
        assert _draws() == _draws()


def test_the_explore_profile_draws_new_examples_and_ten_times_as_many(tmp_path):
    """In a separate pytest run, as the README's exploration command runs it."""
    test = tmp_path / "test_probe.py"
    test.write_text(textwrap.dedent("""
        from hypothesis import given, settings, strategies as st

        DRAWS = []

        @settings(max_examples=7)
        @given(st.integers())
        def test_probe(x):
            DRAWS.append(x)

        def test_count():
            print("DRAWS", len(DRAWS), sorted(set(DRAWS))[:5])
    """))
    (tmp_path / "conftest.py").write_text((TESTS / "conftest.py").read_text())

    def run(profile):
        env = {**os.environ, "HYPOTHESIS_PROFILE": profile}
        p = subprocess.run([sys.executable, "-m", "pytest", "-q", "-s", "-n", "0", "-p",
                            "no:cacheprovider", str(test)], cwd=tmp_path, env=env,
                           capture_output=True, text=True, timeout=300)  # fmt: skip
        assert p.returncode == 0, p.stdout + p.stderr
        return re.search(r"DRAWS .*", p.stdout).group(0)

    assert run("ci").startswith("DRAWS 7 ")
    first, second = run("explore"), run("explore")
    assert first.startswith("DRAWS 70 ") and second.startswith("DRAWS 70 ") and first != second
