"""The research notebooks: stored as built by notebooks/build.py, executed, true to the code: each runs
clean top to bottom in a fresh kernel (nbclient), its figures saved as PNG, and its stored text
outputs are those of the fresh run up to float noise; its prose names the default calibration and
units of the default semantics."""

import base64
import importlib.util
import json
import re
from pathlib import Path

import jax
import nbformat
import pytest
from nbclient.exceptions import CellExecutionError
from tolerances import LM_SETTLE_RTOL

from sgc_jax.calibration import BUILTIN, default_calibration

NOTEBOOKS_DIR = Path(__file__).resolve().parent.parent / "notebooks"
_spec = importlib.util.spec_from_file_location("notebook_build", NOTEBOOKS_DIR / "build.py")
build = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(build)
NAMES = list(build.NOTEBOOKS)
DOCUMENTED_NOTEBOOKS = ["01_quickstart", "02_sensitivity", "03_calibration", "04_diagnostics", "05_best_of_n", "06_gradients"]
PRIVATE = ("sgc_jax._", "sgc_jax.engines", "sgc_jax.kernels",
           "plot._", "diagnostics._")


def _figure_cells(nb):
    return [c for c in nb.cells if c.cell_type == "code" and "fig = plot." in c.source]


def _images(cell):
    return [o["data"]["image/png"] for o in cell.get("outputs", []) if "image/png" in o.get("data", {})]


def test_the_notebooks_the_readme_lists_exist_and_are_built():
    assert NAMES == DOCUMENTED_NOTEBOOKS
    assert sorted(p.stem for p in NOTEBOOKS_DIR.glob("*.ipynb")) == DOCUMENTED_NOTEBOOKS


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


CALIBRATION_NAME = re.compile(r"sgc-[a-z]+-\d{4}")
DEFAULT_CLAIM = re.compile(r"(?:default|shipped) calibration\W+([a-z0-9-]+)")
# The units of compat="authors"; the default semantics are scale-free (docs/semantics.md §4), so a
# notebook speaks of these only where it speaks of compat="authors".
AUTHORS_UNITS = ("depth units", "pose units")


def _text(cell) -> str:
    """A cell's prose (markdown) or its text outputs (code; stdout and results, not stderr)."""
    if cell.cell_type == "markdown":
        return cell.source
    return "".join(o.get("text", "") if o["output_type"] == "stream" else o.get("data", {}).get("text/plain", "")
                   for o in cell.get("outputs", []) if o["output_type"] != "error" and o.get("name") != "stderr")


@pytest.mark.parametrize("name", NAMES)
def test_notebook_names_the_default_calibration_and_units(name):
    stored = nbformat.read(NOTEBOOKS_DIR / f"{name}.ipynb", as_version=4)
    for cell in stored.cells:
        text = " ".join(_text(cell).split())
        assert set(CALIBRATION_NAME.findall(text)) <= set(BUILTIN), text[:200]
        for claimed in DEFAULT_CLAIM.findall(text.replace("`", "").replace("(", " ")):
            assert claimed == default_calibration("spec"), f"{name}: {text[:200]}"
        if any(unit in text for unit in AUTHORS_UNITS):
            assert "authors" in text, f"{name} speaks of the authors' units outside compat='authors': {text[:200]}"


# A number of a stored output and of a fresh run agree up to float noise: one unit in the last digit
# shown (pandas shows 4), NOISE_RTOL of the value, or NOISE_ATOL. Another CPU fuses float32 sums
# otherwise, and two roundings of one fit settle up to LM_SETTLE_RTOL apart in the pose, more in a
# variance of differences between poses, most where a severe warp leaves RANSAC near-tied optima
# (measured between an Intel Xeon and an AMD EPYC box: at most 8.6e-3, notebook 02's local
# rotation variance of 129 deg^2 at warp 1; NOISE_RTOL leaves 2.3x). A rigid clip's variances
# (~1e-10 deg^2) and its local-global gaps (~1e-6 px, differences of float32 values of order 1)
# are that noise itself.
NOISE_RTOL, NOISE_ATOL = 20 * LM_SETTLE_RTOL, 1e-5
# A rank statistic moves in steps: noise that swaps two near-tied scores of n rows moves Spearman's
# rho by 12 / (n (n^2 - 1)) (2e-4 for notebook 03's 40 rows); a few swaps per fold, with the folds'
# std, stay within RANK_ATOL (measured across two CPUs: 6e-4).
RANK_ATOL = 2e-3
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")


def _last_digit(number: str) -> float:
    mantissa, _, exponent = number.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    return 10.0 ** (-decimals + (int(exponent) if exponent else 0))


def assert_same_up_to_float_noise(stored: str, fresh: str, where: str) -> None:
    words = lambda text: " ".join(NUMBER.sub("#", text).split())  # noqa: E731
    assert words(stored) == words(fresh), f"{where}: the text differs\nstored: {stored[:300]}\nfresh: {fresh[:300]}"
    for stored_line, fresh_line in zip(stored.splitlines(), fresh.splitlines()):
        atol = RANK_ATOL if "Spearman" in stored_line else NOISE_ATOL
        for a, b in zip(NUMBER.findall(stored_line), NUMBER.findall(fresh_line)):
            x, y = float(a), float(b)
            # one unit in the last digit, with room for the binary rounding of the decimal difference
            allowed = max(_last_digit(a), _last_digit(b), NOISE_RTOL * abs(x), atol) * (1 + 1e-9)
            assert abs(x - y) <= allowed, f"{where}: {a} stored, {b} now"


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
    stored = nbformat.read(NOTEBOOKS_DIR / f"{name}.ipynb", as_version=4)
    for i, (old, new) in enumerate(zip(stored.cells, nb.cells)):
        # a time differs run to run; a long descent ends where the CPU's rounding takes it
        if new.cell_type == "code" and not {"timing", "cpu-rounding"} & set(new.metadata.get("tags", [])):
            assert_same_up_to_float_noise(_text(old), _text(new), f"{name}.ipynb cell {i} (rebuild it: "
                                          f"python notebooks/build.py {name})")
    figures = _figure_cells(nb)
    assert figures, f"{name} draws no figure"
    for i, cell in enumerate(figures):
        images = _images(cell)
        assert len(images) == 1, f"{name}: expected one figure from {cell.source[:80]}"
        png = base64.b64decode(images[0])
        assert png[:8] == b"\x89PNG\r\n\x1a\n"
        (tmp_path / f"{name}-{i}.png").write_bytes(png)
    (tmp_path / f"{name}.ipynb").write_text(json.dumps(nb))
