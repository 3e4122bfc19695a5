"""The package's folders are its layers: the rules of docs/layout.md, read from the code.

Every import of every module (at the top, inside functions and under ``TYPE_CHECKING``) is
read with :mod:`ast`, and the test fails on

* a folder importing one above it (:data:`LAYERS`, lowest first);
* an import cycle between modules (imports that run: one under ``TYPE_CHECKING`` names a type
  for the checker and never runs, so two classes of one folder may name each other);
* a private name imported from another folder: across folders, a module imports only what
  the other folder's ``__init__`` exports (never ``_name``, never a private module);
* JAX or equinox imported, even transitively, by ``robot/`` or ``_core/`` (checked by
  importing each of their modules in a fresh interpreter and reading ``sys.modules``).
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "handeye_jax"
#: The layers, lowest first: a folder (or root module) imports only those listed before it.
LAYERS = (
    "_core", "_jax", "geometry", "optim", "models", "data", "robot", "problem",
    "calibration", "diagnostics", "vision", "twin", "report", "tablet", "cli", "__init__",
)  # fmt: skip
#: Folders that must run on a robot PC without JAX: not one of these may import them.
NUMPY_ONLY = ("_core", "robot")
JAX_STACK = ("jax", "jaxlib", "equinox", "optimistix", "lineax", "jaxlie", "jaxtyping")
#: The entries of pyproject's [project.scripts] and ``python -m``, the root's only modules.
ROOT_MODULES = {"__init__.py", "geometry.py"}


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def layer_of(module: str) -> str:
    """``handeye_jax.data._dataset`` → ``data``; the package itself → ``__init__``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def imports_of(path: Path, root: Path = ROOT) -> list[tuple[int, str, str | None]]:
    """Every import in ``path`` as ``(line, module, name)``: ``name`` is what a ``from``
    import takes from ``module`` (``None`` for a plain ``import``). Relative imports are
    resolved against the file's package."""
    module = module_name(path, root)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name, None) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parts = parts[: len(parts) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            out += [(node.lineno, base, a.name) for a in node.names]
    return out


def type_checking_lines(path: Path) -> set[int]:
    """The lines of the imports under ``if TYPE_CHECKING:`` in ``path``."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for inner in node.body:
                for sub in ast.walk(inner):
                    if isinstance(sub, ast.Import | ast.ImportFrom):
                        out.add(sub.lineno)
    return out


def package_modules(root: Path = ROOT) -> dict[str, Path]:
    return {module_name(p, root): p for p in (root / "handeye_jax").rglob("*.py")}


def is_module(name: str, modules: dict[str, Path]) -> bool:
    return name in modules


def targets(module: str, name: str | None, modules: dict[str, Path]) -> str:
    """The module an import reaches: ``from pkg import submodule`` reaches the submodule."""
    if name is not None and is_module(f"{module}.{name}", modules):
        return f"{module}.{name}"
    return module


def problems(root: Path = ROOT) -> list[str]:
    """Every broken rule of the layout, one line each (empty: the layout holds)."""
    modules = package_modules(root)
    found = []
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for module, path in modules.items():
        mine = layer_of(module)
        where = path.relative_to(root)
        typing_only = type_checking_lines(path)
        for line, imported, name in imports_of(path, root):
            if not imported.startswith("handeye_jax"):
                continue
            target = targets(imported, name, modules)
            if line not in typing_only:
                graph[module].add(target)
            theirs = layer_of(target)
            if theirs == mine or mine == "__init__" and module == "handeye_jax":
                continue
            if theirs not in LAYERS or mine not in LAYERS:
                found.append(f"{where}:{line}: {target}: folder not in the layer list")
                continue
            if LAYERS.index(theirs) > LAYERS.index(mine):
                found.append(f"{where}:{line}: {mine}/ imports {target} from the layer above")
            private = [p for p in target.split(".")[2:] if p.startswith("_")]
            if name is not None and name.startswith("_") and name != "__version__":
                private.append(name)
            if private and theirs != "__init__":
                found.append(f"{where}:{line}: imports private {'.'.join(private)} from "
                             f"{theirs}/ (import what its __init__ exports)")  # fmt: skip
    found += [f"import cycle: {' -> '.join(c)}" for c in cycles(graph)]
    return found


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle per strongly connected component of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in graph:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp) + [sorted(comp)[0]])

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_layers_hold():
    assert problems() == []


def test_the_root_holds_only_the_api_and_geometry():
    assert {p.name for p in PACKAGE.glob("*.py")} == ROOT_MODULES


def test_every_folder_is_a_layer():
    folders = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists()}
    assert folders <= set(LAYERS)


def _copy_with(tmp_path: Path, relative: str, extra: str) -> Path:
    """A copy of the package with ``extra`` appended to one module."""
    import shutil

    shutil.copytree(PACKAGE, tmp_path / "handeye_jax", ignore=shutil.ignore_patterns("static"))
    target = tmp_path / "handeye_jax" / relative
    target.write_text(target.read_text() + extra)
    return tmp_path


@pytest.mark.parametrize(
    ("module", "line", "complaint"),
    [
        ("data/_dataset.py", "from ..calibration import Settings\n", "from the layer above"),
        ("twin/_render.py", "from ..vision._detect import find_blobs\n", "private _detect"),
        ("report/_summary.py", "from ..calibration import _value\n", "private _value"),
        ("report/_summary.py", "from ._figures import chain_data\n", None),  # within a folder
    ],
)
def test_the_check_catches_a_wrong_import(tmp_path, module, line, complaint):
    found = problems(_copy_with(tmp_path, module, "\n" + line))
    if complaint is None:
        assert found == []
    else:
        assert any(complaint in p for p in found), found


def test_the_check_catches_a_cycle(tmp_path):
    found = problems(_copy_with(tmp_path, "data/_observations.py",
                                "\nfrom ._dataset import Dataset\n"))  # fmt: skip
    assert any(p.startswith("import cycle:") and "data._observations" in p for p in found), found


def _loaded_by(modules: list[str]) -> dict[str, list[str]]:
    """For each module, the JAX-stack modules that importing it in a fresh interpreter loads."""
    code = (
        "import importlib, json, sys\n"
        f"stack = {JAX_STACK!r}\n"
        "out = {}\n"
        "for m in sys.argv[1:]:\n"
        "    before = set(sys.modules)\n"
        "    importlib.import_module(m)\n"
        "    out[m] = sorted({n.split('.')[0] for n in sys.modules} & set(stack))\n"
        "print(json.dumps(out))\n"
    )
    out = {}
    for m in modules:  # one interpreter per module: nothing loaded by another counts
        run = subprocess.run([sys.executable, "-c", code, m], capture_output=True, text=True,
                             cwd=ROOT, check=True)  # fmt: skip
        out.update(json.loads(run.stdout))
    return out


def test_core_and_robot_import_no_jax():
    modules = [m for m in package_modules() if layer_of(m) in NUMPY_ONLY]
    assert len(modules) > 5
    assert {m: jax for m, jax in _loaded_by(modules).items() if jax} == {}


def test_the_jax_check_sees_a_transitive_import(tmp_path):
    # robot/ importing a folder whose module imports JAX: the subprocess sees it.
    root = _copy_with(tmp_path, "robot/_frames.py", "\nfrom ..problem._losses import get_loss\n")
    code = "import sys, handeye_jax.robot._frames; print('jax' in sys.modules)"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root,
                         env={"PYTHONPATH": str(root), "PATH": ""}, check=True)  # fmt: skip
    assert run.stdout.strip() == "True"
