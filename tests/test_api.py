"""The public lists agree: the root's names, its lazy map and what type checkers see, and each
folder's interface and what it loads."""

import ast
import importlib
from pathlib import Path

import pytest

import handeye_jax

PACKAGE = Path(handeye_jax.__file__).parent
LAZY = ("_core", "_jax", "data", "robot", "problem", "calibration", "diagnostics", "vision",
        "twin", "report")  # fmt: skip
EAGER = ("models", "optim", "tablet", "cli")


def _type_checking_names(path: Path) -> set[str]:
    """The names ``if TYPE_CHECKING:`` imports in ``path``."""
    tree = ast.parse(path.read_text())
    for node in tree.body:
        if isinstance(node, ast.If) and getattr(node.test, "id", "") == "TYPE_CHECKING":
            return {a.asname or a.name for n in node.body if isinstance(n, ast.ImportFrom)
                    for a in n.names}  # fmt: skip
    return set()


def test_the_roots_lists_agree():
    public = set(handeye_jax.__all__)
    assert len(public) == len(handeye_jax.__all__)  # no name twice
    assert public == set(handeye_jax._EXPORTS) | set(handeye_jax._SUBMODULES)
    assert _type_checking_names(PACKAGE / "__init__.py") == public
    assert set(dir(handeye_jax)) >= public


def test_every_public_name_loads_and_is_the_one_its_map_names():
    for name in handeye_jax.__all__:
        value = getattr(handeye_jax, name)
        if name in handeye_jax._SUBMODULES:
            assert value.__name__ == f"handeye_jax.{name}"
            continue
        folder = importlib.import_module(f"handeye_jax.{handeye_jax._EXPORTS[name]}")
        assert getattr(folder, name) is value, name


@pytest.mark.parametrize("folder", LAZY)
def test_each_folders_interface_loads_what_it_lists(folder):
    module = importlib.import_module(f"handeye_jax.{folder}")
    listed = set(module.__all__)
    assert listed == {n for names in module._EXPORTS.values() for n in names} | (
        {"interrupts"} if folder == "_core" else set()
    )
    assert set(dir(module)) >= listed
    for name in listed:
        getattr(module, name)  # each loads from the module its map names
    assert not hasattr(module, "no_such_name")


@pytest.mark.parametrize("folder", EAGER)
def test_the_eager_folders_list_what_they_hold(folder):
    module = importlib.import_module(f"handeye_jax.{folder}")
    for name in module.__all__:
        assert hasattr(module, name), name
