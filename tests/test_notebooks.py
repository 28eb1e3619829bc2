"""The research notebooks: stored as built by notebooks/build.py, executed, and each runs clean top
to bottom in a fresh kernel (nbclient), with its figures saved as PNG."""

import base64
import importlib.util
import json
from pathlib import Path

import jax
import nbformat
import pytest
from nbclient.exceptions import CellExecutionError

NOTEBOOKS_DIR = Path(__file__).resolve().parent.parent / "notebooks"
_spec = importlib.util.spec_from_file_location("notebook_build", NOTEBOOKS_DIR / "build.py")
build = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(build)
NAMES = list(build.NOTEBOOKS)
ISSUE_NAMES = ["01_quickstart", "02_sensitivity", "03_calibration", "04_diagnostics"]
PRIVATE = ("sgc_jax._", "sgc_jax.engines", "sgc_jax.kernels",
           "plot._", "diagnostics._")


def _figure_cells(nb):
    return [c for c in nb.cells if c.cell_type == "code" and "fig = plot." in c.source]


def _images(cell):
    return [o["data"]["image/png"] for o in cell.get("outputs", []) if "image/png" in o.get("data", {})]


def test_the_four_notebooks_of_the_issue_exist():
    assert NAMES == ISSUE_NAMES
    assert sorted(p.stem for p in NOTEBOOKS_DIR.glob("*.ipynb")) == ISSUE_NAMES


@pytest.mark.parametrize("name", NAMES)
def test_stored_notebook_is_the_built_one_executed(name):
    stored = nbformat.read(NOTEBOOKS_DIR / f"{name}.ipynb", as_version=4)
    nbformat.validate(stored)
    built = build.build(name)
    assert [(c.cell_type, c.source) for c in stored.cells] == [(c.cell_type, c.source) for c in built.cells], (
        f"{name}.ipynb differs from notebooks/build.py: run `python notebooks/build.py {name}`")
    code = [c for c in stored.cells if c.cell_type == "code"]
    assert [c.execution_count for c in code] == list(range(1, len(code) + 1)), "not executed top to bottom"
    for cell in code:
        kinds = {o["output_type"] for o in cell.outputs}
        assert "error" not in kinds, cell.source
        assert not [o for o in cell.outputs if o["output_type"] == "stream" and o["name"] == "stderr"], (
            f"stderr output in {name}: {cell.source[:80]}")
    for cell in _figure_cells(stored):
        assert len(_images(cell)) == 1, f"{name}: expected one figure from {cell.source[:80]}"


@pytest.mark.parametrize("name", NAMES)
def test_notebook_uses_only_the_public_api(name):
    source = "\n".join(c.source for c in build.build(name).cells if c.cell_type == "code")
    assert "import sgc_jax" in source
    for private in PRIVATE:
        assert private not in source, f"{name} reaches into {private}"


@pytest.fixture(scope="session")
def jax_cache(tmp_path_factory):
    """The test run's compilation cache (tests/conftest.py), so the notebook kernels load the demo
    corpus's programs instead of compiling them; one of their own when it is off."""
    return jax.config.jax_compilation_cache_dir or tmp_path_factory.mktemp("jax-cache")


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_notebook_runs_clean_top_to_bottom(name, jax_cache, tmp_path, monkeypatch):
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(jax_cache))
    nb = build.build(name)
    try:
        build.execute(nb, timeout=900)
    except CellExecutionError as exc:  # the failing cell and its traceback
        pytest.fail(f"{name}.ipynb failed:\n{exc}")
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert not [o for o in cell.outputs if o["output_type"] == "error"]
    figures = _figure_cells(nb)
    assert figures, f"{name} draws no figure"
    for i, cell in enumerate(figures):
        images = _images(cell)
        assert len(images) == 1, f"{name}: expected one figure from {cell.source[:80]}"
        png = base64.b64decode(images[0])
        assert png[:8] == b"\x89PNG\r\n\x1a\n"
        (tmp_path / f"{name}-{i}.png").write_bytes(png)
    (tmp_path / f"{name}.ipynb").write_text(json.dumps(nb))
