"""Every notebook runs top to bottom (nbclient, the notebooks' small budget) and shows its plots."""

import os
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

pytestmark = pytest.mark.slow  # subprocesses and whole scripts

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


def test_the_four_notebooks_exist():
    assert [p.name for p in NOTEBOOKS] == [
        "01_quickstart.ipynb", "02_loss_landscape.ipynb", "03_de_vs_gradient.ipynb",
        "04_plan_an_acquisition.ipynb",
    ]  # fmt: skip


@pytest.fixture(scope="module")
def kernel():
    """One kernel for the four notebooks, each run from an emptied namespace (``%reset -f``):
    JAX's import and the programs the notebooks share are paid once."""
    with pytest.MonkeyPatch.context() as env:
        env.setenv("HANDEYE_JAX_NOTEBOOK_QUICK", "1")
        env.setenv("PYTHONPATH", os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
        env.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")
        # The kernel shares the suite's XLA cache (tests/conftest.py), so programs the CLI tests
        # compiled are not compiled again.
        env.setenv("JAX_COMPILATION_CACHE_DIR", os.environ["HANDEYE_JAX_CACHE_DIR"])
        env.setenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
        env.setenv("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")
        clients: list[NotebookClient] = []
        yield clients
        if clients:
            clients[0]._cleanup_kernel()  # the first client started (owns) the kernel


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_runs(path, kernel):
    committed = nbformat.read(path, as_version=4)
    code = [c for c in committed.cells if c.cell_type == "code"]
    with_output = sum(bool(c.get("outputs")) for c in code)
    assert with_output >= len(code) - 2, "commit notebooks with their outputs (only set-up cells"
    " may be silent)"
    nb = nbformat.read(path, as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "code":
            cell.outputs = []
    # An emptied namespace, then the suite's stored programs (tests/conftest.py): a program a
    # test process already traced is loaded, not traced and lowered again in the kernel.
    nb.cells.insert(0, nbformat.v4.new_code_cell(
        "%reset -f\nimport os as _os, handeye_jax as _hj\n"
        "_hj.store_programs(_os.path.join(_os.environ['HANDEYE_JAX_CACHE_DIR'], 'programs'))\n"
        "del _os, _hj"
    ))  # fmt: skip
    client = NotebookClient(nb, timeout=600, kernel_name="python3",
                            km=kernel[0].km if kernel else None,
                            resources={"metadata": {"path": str(path.parent)}})  # fmt: skip
    try:
        client.execute(cleanup_kc=False)
    finally:
        if not kernel:
            kernel.append(client)
        elif client.kc is not None:
            client.kc.stop_channels()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    assert len(images) >= 2
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    want = {
        "01_quickstart": "convention check passed: True",
        "02_loss_landscape": "theta_c1 + gamma_c",
        "03_de_vs_gradient": "of starts reach the target",
        "04_plan_an_acquisition": "linearised and Monte Carlo agree within 50 %: True",
    }[path.stem]
    assert want in text
