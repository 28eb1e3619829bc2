"""The package layout: each layer imports only the layers below it, with no import cycles (function-local
imports included), no private name used across modules, every subpackage shipped.

Layers, bottom up (docs/semantics.md names the formulas; STYLE.md draws the layout):
- base: ``config`` (SGCConfig and the semantics' constants), ``codes``, ``stats``, ``version``;
- ``calibration/``: the score formula, calibration files and fitting;
- ``io/``: clip files and tables, read, validated, written; nothing that computes a score;
- ``kernels/``: pure JAX on arrays; they import each other, ``codes``, ``config``'s constants (never SGCConfig)
  and ``stats``' means written for NumPy and jax.numpy;
- ``engines/``: the JAX engine (its stages, programs and dispatch) and the NumPy reference -> per-pair arrays;
- ``scoring/``: a run: entry points, streaming, readers, Ray, the result model;
- ``adapters/``: estimator outputs -> clip files;
- ``research/``: synthetic scenes, perturbations, studies, tables, diagnostics, plots;
- ``cli``, ``torch`` (the PyTorch bridge over the Scorer) and the public ``sgc_jax`` namespace on top.
The source is read, not imported, so the test needs neither JAX nor matplotlib.
"""

import ast
import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "sgc_jax"

BASE = {"sgc_jax.config", "sgc_jax.codes", "sgc_jax.stats", "sgc_jax.version"}
# layer -> the layers it may import besides its own
ALLOWED = {
    "base": set(),
    "calibration": {"base"},
    "io": {"calibration", "base"},
    "kernels": {"base"},
    "engines": {"kernels", "io", "calibration", "base"},
    "scoring": {"engines", "io", "calibration", "base"},
    "adapters": {"io", "base"},
    "research": {"scoring", "engines", "kernels", "io", "calibration", "base"},
    "cli": {"public", "research", "adapters", "scoring", "engines", "io", "calibration", "base"},
    "torch": {"scoring", "io", "calibration", "base"},
    "public": {"research", "adapters", "scoring", "engines", "io", "calibration", "base"},
}
SUBPACKAGES = ("calibration", "io", "kernels", "engines", "scoring", "adapters", "research")
# what the kernels may take from the base layer: status codes, and config's constants (not SGCConfig)
KERNEL_BASE = {"sgc_jax.codes": None, "sgc_jax.config": str.isupper, "sgc_jax.stats": None}


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
    if parts[1] in (*SUBPACKAGES, "cli", "torch"):
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
        wrong += [f"{name} ({layer(name)}) imports {t} ({layer(t)})" for t in targets if layer(t) not in allowed]
    assert not wrong, "\n".join(wrong)


def test_kernels_take_only_codes_and_constants_from_the_base():
    wrong = []
    for name in (n for n in MODULES if layer(n) == "kernels"):
        for target, names, line in imports(name):
            if layer(target) != "base":
                continue
            if target not in KERNEL_BASE:
                wrong.append(f"{name}:{line} imports {target}")
            elif KERNEL_BASE[target] is not None:
                wrong += [f"{name}:{line} imports {target}.{n}" for n in names if not KERNEL_BASE[target](n)]
    assert not wrong, "\n".join(wrong)


NAMEDTUPLE_API = {"_fields", "_asdict", "_replace", "_make"}  # public despite the underscore


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
                    and node.attr.startswith("_") and not node.attr.startswith("__") and node.attr not in NAMEDTUPLE_API):
                private.append(f"{name}:{node.lineno} uses {node.value.id}.{node.attr}")
    assert not private, "\n".join(private)


@pytest.mark.parametrize("package", sorted(name for name in MODULES if is_package(name) and name != "sgc_jax"))
def test_subpackage_init_holds_a_docstring_and_at_most_re_exports(package):
    """Either only a docstring (importing one module of a layer imports nothing else of it), or
    explicit re-exports of its own modules with ``__all__`` (a public face: adapters, calibration)."""
    tree = ast.parse(MODULES[package].read_text())
    assert ast.get_docstring(tree)
    for node in tree.body[1:]:
        if isinstance(node, ast.ImportFrom):
            assert node.level == 1 and node.module, f"{package} re-exports from outside the package"
        else:
            assert isinstance(node, ast.Assign) and node.targets[0].id == "__all__", ast.dump(node)


def test_the_readme_lists_every_public_name():
    tree = ast.parse((PACKAGE / "__init__.py").read_text())
    (names,) = [ast.literal_eval(node.value) for node in tree.body
                if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", None) == "__all__"]
    readme = (ROOT / "README.md").read_text()
    assert [name for name in names if name != "__version__" and f"`{name}`" not in readme] == []


def test_pyproject_ships_every_subpackage_and_the_calibrations():
    """CI installs non-editable (pip install ".[dev]"): a package missing from the explicit list is not installed."""
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    packages = {name for name in MODULES if is_package(name)}
    assert set(setuptools["packages"]) == packages
    assert list((PACKAGE / "calibration").glob("*.json"))
    assert setuptools["package-data"]["sgc_jax.calibration"] == ["*.json"]


# the most a function may hold for a newcomer to read it at once
MAX_FUNCTION_LINES = 80
MAX_PARAMETERS = 12


def test_no_function_is_longer_than_80_lines_or_takes_more_than_12_parameters():
    """Lines from ``def`` to the last line of the body; parameters counted without ``self``/``cls``,
    ``*args`` and ``**kwargs`` as one each."""
    too_big = []
    for name, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            args = node.args
            params = [*args.posonlyargs, *args.args, *args.kwonlyargs, args.vararg, args.kwarg]
            params = [p for p in params if p is not None and p.arg not in ("self", "cls")]
            lines = node.end_lineno - node.lineno + 1
            if lines > MAX_FUNCTION_LINES or len(params) > MAX_PARAMETERS:
                too_big.append(f"{name}:{node.lineno} {node.name}: {lines} lines, {len(params)} parameters")
    assert not too_big, "\n".join(too_big)


CITATION = re.compile(r'bench/history/([\w.-]+\.md)(?:,\s*(?:#\s*)?"([^"]+)")?')


def test_every_cited_benchmark_section_exists():
    """Code, tests and docs cite a measurement by a file of bench/history/ and, in quotes, the
    first words of its section's title: the file must exist and one of its sections start so."""
    sources = [*PACKAGE.rglob("*.py"), *(ROOT / "tests").glob("*.py"), *(ROOT / "bench").glob("*.py"),
               ROOT / "README.md", ROOT / "bench" / "README.md", ROOT / "bench" / "RESULTS.md", *(ROOT / "docs").glob("*.md")]
    missing = []
    for source in sources:
        for match in CITATION.finditer(source.read_text()):
            path = ROOT / "bench" / "history" / match.group(1)
            if not path.exists():
                missing.append(f"{source.name}: {match.group(1)}")
                continue
            if match.group(2):
                quoted = re.sub(r"\s*\n\s*#?\s*", " ", match.group(2)).strip()
                titles = [line[3:] for line in path.read_text().splitlines() if line.startswith("## ")]
                if not any(title.startswith(quoted) for title in titles):
                    missing.append(f"{source.name}: {match.group(1)}, {quoted!r}")
    assert not missing, "\n".join(missing)
