"""The tutorials in notebooks/ (jupytext percent files) execute end to end as notebooks."""

from pathlib import Path

import pytest
from conftest import data_dir

NEEDS_DATA = {"02_benchmark", "03_gfcs"}  # the panda_mbm robot reads the reference collision spheres from FABRAX_DATA
NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.py"))


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path):
    if path.stem in NEEDS_DATA and data_dir() is None:
        pytest.skip("FABRAX_DATA is not set to the shared data folder (../shared/data)")
    jupytext = pytest.importorskip("jupytext", reason="needs the dev extra (jupytext, nbclient, ipykernel)")
    nbclient = pytest.importorskip("nbclient", reason="needs the dev extra (jupytext, nbclient, ipykernel)")
    nb = jupytext.read(path)
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.get("output_type") == "error"]
    assert not errors
