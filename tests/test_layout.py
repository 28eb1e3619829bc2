"""The package layout: layers that import only the layers below them, no import cycles
(function-local imports included), no private name used across modules, every subpackage shipped.

Layers, bottom up:
- base: ``config``, ``codes`` (status and reason codes), ``stats`` (our conventions over scipy.stats),
  ``version``,
  then ``calibration`` (the score formula; the result tables compute their ``sgc`` with it);
- ``kernels/``: JAX kernels, pure functions of arrays; they import only each other, config and codes;
- ``io/``: clip schema, loading, validation, result tables;
- ``engines/``: the JAX and reference engines (kernels -> per-pair arrays of io.result);
- ``api``: score_clip / score_batch, ``streaming``, ``readers`` and ``cluster`` (their scoring loops and
  readers, in one process or over Ray); ``adapters/``: estimator outputs -> clips;
- ``research/``: synthetic scenes, perturbations, studies, tables, diagnostics, plots;
- ``cli`` and the public ``sgc_jax`` namespace on top.
The source is read, not imported, so the test needs neither JAX nor matplotlib.
"""

import ast
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "sgc_jax"

BASE = {"sgc_jax.config", "sgc_jax.codes", "sgc_jax.stats", "sgc_jax.version"}
# layer -> what it may import: layer names, or module names for single modules of a layer
ALLOWED = {
    "base": set(),
    "calibration": {"base"},
    "kernels": {"kernels", "sgc_jax.config", "sgc_jax.codes"},
    "io": {"io", "base", "calibration"},
    "engines": {"engines", "kernels", "io", "base"},
    "api": {"engines", "io", "base", "calibration"},
    "adapters": {"adapters", "io", "base"},
    "research": {"research", "api", "engines", "kernels", "io", "base", "calibration"},
    "cli": {"public", "research", "adapters", "api", "engines", "io", "base", "calibration"},
    "public": {"research", "adapters", "api", "engines", "io", "base", "calibration"},
}
SUBPACKAGES = ("kernels", "engines", "io", "research")  # layers whose __init__ holds only a docstring


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def is_package(name: str) -> bool:
    return MODULES[name].name == "__init__.py"


def layer(name: str) -> str:
    if name in BASE:
        return "base"
    parts = name.split(".")
    if len(parts) == 1:
        return "public"
    if parts[1] in ("calibration", "api", "cli"):
        return parts[1]
    if parts[1] in ("streaming", "readers", "cluster"):  # the scoring loops under score_batch
        return "api"
    if parts[1] in (*SUBPACKAGES, "adapters"):
        return parts[1]
    raise KeyError(f"{name} belongs to no layer: add it to tests/test_layout.py")


def imports(name: str) -> list[tuple[str, list[str], int]]:
    """Every sgc_jax import of a module, at any depth (function-local and TYPE_CHECKING ones
    included): (imported module, names taken from it, line)."""
    tree = ast.parse(MODULES[name].read_text())
    package = name if is_package(name) else name.rpartition(".")[0]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(a.name, [], node.lineno) for a in node.names if a.name.split(".")[0] == "sgc_jax"]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            if source.split(".")[0] != "sgc_jax":
                continue
            names = [a.name for a in node.names]
            # `from package import module` imports the module; other names come from the package
            modules = [n for n in names if f"{source}.{n}" in MODULES]
            found += [(f"{source}.{n}", [], node.lineno) for n in modules]
            rest = [n for n in names if n not in modules]
            if rest:
                found.append((source, rest, node.lineno))
    return found


GRAPH = {name: sorted({target for target, _, _ in imports(name)}) for name in MODULES}


def test_every_import_names_a_module_of_the_package():
    missing = [(name, t) for name, targets in GRAPH.items() for t in targets if t not in MODULES]
    assert not missing


def test_every_module_belongs_to_a_layer():
    for name in MODULES:
        layer(name)


def test_the_package_has_no_import_cycles():
    """Tarjan's strongly connected components over all imports, function-local ones included."""
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in GRAPH.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1 or node in GRAPH.get(node, ()):
                cycles.append(sorted(component))

    for name in GRAPH:
        if name not in index:
            visit(name)
    assert not cycles, f"import cycles: {cycles}"


def test_each_layer_imports_only_the_layers_below_it():
    wrong = []
    for name, targets in GRAPH.items():
        allowed = ALLOWED[layer(name)] | {layer(name)}
        wrong += [f"{name} ({layer(name)}) imports {t} ({layer(t)})" for t in targets
                  if layer(t) not in allowed and t not in allowed]
    assert not wrong, "\n".join(wrong)


def test_no_module_imports_another_modules_private_names():
    """Neither ``from module import _name`` nor ``module._name`` across modules of the package."""
    private = []
    for name, path in MODULES.items():
        tree = ast.parse(path.read_text())
        bound = set()  # local names bound to sgc_jax modules
        for target, names, line in imports(name):
            private += [f"{name}:{line} imports {target}.{n}" for n in names
                        if n.startswith("_") and not n.startswith("__")]
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                bound |= {a.asname or a.name for a in node.names}
            elif isinstance(node, ast.Import):
                bound |= {(a.asname or a.name).split(".")[0] for a in node.names}
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in bound
                    and node.attr.startswith("_") and not node.attr.startswith("__")):
                private.append(f"{name}:{node.lineno} uses {node.value.id}.{node.attr}")
    assert not private, "\n".join(private)


@pytest.mark.parametrize("subpackage", SUBPACKAGES)
def test_subpackage_init_holds_only_a_docstring(subpackage):
    """So importing one module of a layer imports nothing else of it."""
    tree = ast.parse((PACKAGE / subpackage / "__init__.py").read_text())
    assert ast.get_docstring(tree)
    assert len(tree.body) == 1


def test_pyproject_ships_every_subpackage_and_the_calibrations():
    """CI installs non-editable (pip install ".[dev]"): a package missing from the explicit list is not installed."""
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    packages = {name for name in MODULES if is_package(name)}
    assert set(setuptools["packages"]) == packages
    assert list((PACKAGE / "calibration").glob("*.json"))
    assert setuptools["package-data"]["sgc_jax"] == ["calibration/*.json"]
