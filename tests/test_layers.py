"""The architecture holds: layers import downwards only, errors is a leaf, the CLI starts light.

Layers (docs/architecture.md, data_specs/architecture.md):
core → applications (builder, detect, runtime, stereo, render) → evaluation, view → cli / the public API.
Within the applications only runtime may use another application (detect: video input); the viewer
(view: the page of `mocapdb view` and `live --view`) shows what render reads and runtime streams, and
only the CLI imports it.
"""
import ast
import os
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# package (second component of the module name) → the packages it may import
APPLICATIONS = {"builder": set(), "detect": set(), "runtime": {"detect"}, "stereo": set(), "render": set()}
ALLOWED = {"core": {"core"}}
ALLOWED |= {app: {"core", app} | uses for app, uses in APPLICATIONS.items()}
ALLOWED["evaluation"] = {"core", "evaluation", *APPLICATIONS}
ALLOWED["view"] = {"core", "render", "runtime", "view"}
ALLOWED["cli"] = {"core", "evaluation", "view", "cli", *APPLICATIONS}
ALLOWED["__init__"] = ALLOWED["cli"] - {"cli", "view"}  # the public API (mocapdb/__init__.py)
ALLOWED["__main__"] = {"cli"}


def _modules() -> dict[str, Path]:
    """Every module of the package ``mocapdb``, as a source checkout holds it (``runtime`` through its link)."""
    found = {}
    for folder, _, files in os.walk(ROOT / "mocapdb", followlinks=True):
        for name in files:
            if name.endswith(".py"):
                parts = (Path(folder) / name).relative_to(ROOT / "mocapdb").with_suffix("").parts
                found[".".join(("mocapdb", *parts))] = Path(folder) / name
    return found


def _imports(path: Path, module: str) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in the file, including those inside functions."""
    names = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the module's package
                base = module.split(".")[:-node.level]  # "a.b.c" or "a.b.__init__", level 1 → "a.b"
                names.append((node.lineno, ".".join(base + ([node.module] if node.module else []))))
            else:
                names.append((node.lineno, node.module))
    return names


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_layers_import_downwards_only():
    wrong = []
    for module, path in _modules().items():
        layer = _layer(module)
        for line, name in _imports(path, module):
            if name == "runtime" or name.startswith("runtime."):
                wrong.append(f"{path.relative_to(ROOT)}:{line} imports top-level {name}: use mocapdb.runtime")
            elif name.startswith("mocapdb.") and _layer(name) not in ALLOWED[layer]:
                wrong.append(f"{path.relative_to(ROOT)}:{line} ({layer}) imports {name} ({_layer(name)})")
    assert not wrong, "\n".join(wrong)


def test_runtime_algorithms_do_not_import_stream_input_and_output():
    """The engine's algorithms stay apart from sources, sinks, buffering and sessions (runtime/stream/)."""
    wrong = [f"{path.relative_to(ROOT)}:{line} imports {name}"
             for module, path in _modules().items()
             if module.startswith("mocapdb.runtime.") and not module.startswith("mocapdb.runtime.stream")
             for line, name in _imports(path, module) if name.startswith("mocapdb.runtime.stream")]
    assert not wrong, "\n".join(wrong)


def test_every_module_belongs_to_a_layer():
    assert {_layer(m) for m in _modules()} <= set(ALLOWED)


def test_errors_is_a_leaf():
    path = ROOT / "mocapdb" / "core" / "errors.py"
    assert not [name for _, name in _imports(path, "mocapdb.core.errors") if name.startswith("mocapdb")]


def test_runtime_imports_as_mocapdb_runtime_without_an_install():
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert "package-dir" not in setuptools and (ROOT / "mocapdb" / "runtime").resolve() == ROOT / "runtime"
    assert not [p for p in setuptools["packages"] if not p.startswith("mocapdb")]
    # -S: no site-packages, so no installed or editable mocapdb: the source checkout alone
    code = "import mocapdb.runtime as r; print(r.__file__)"
    out = subprocess.run([sys.executable, "-S", "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0 and out.stdout.strip() == str(ROOT / "mocapdb" / "runtime" / "__init__.py"), out.stderr
    python = {m.removesuffix(".__init__") for m in _modules() if m.endswith(".__init__")}
    assert set(setuptools["packages"]) >= python
    # the rest are folders of data files (the viewer's page, vendored three.js), named so setuptools ships them
    data_folders = [ROOT / Path(*name.split(".")) for name in set(setuptools["packages"]) - python]
    assert all(folder.is_dir() and not list(folder.glob("*.py")) for folder in data_folders), data_folders


def test_help_loads_no_heavy_library():
    code = ("import sys\nfrom mocapdb.cli.main import parser\nparser()\n"
            "print(sorted({m.split('.')[0] for m in sys.modules} & "
            "{'numba', 'cv2', 'scipy', 'pyarrow', 'onnxruntime', 'sklearn', 'tqdm', 'matplotlib'}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]"


def _import_graph() -> dict[str, set[str]]:
    """Module → the mocapdb modules it imports anywhere (top level, in functions, for type checking)."""
    modules = {m.removesuffix(".__init__"): p for m, p in _modules().items()}
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for module, path in _modules().items():
        source = module.removesuffix(".__init__")
        for _, name in _imports(path, module):
            while name and name not in modules:
                name = name.rpartition(".")[0]
            if name and name not in (source, "mocapdb"):
                graph[source].add(name)
    return graph


def test_no_import_circles():
    """No module reaches itself through imports (Tarjan's strongly connected components)."""
    graph, index, low, stack, circles = _import_graph(), {}, {}, [], []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = stack[stack.index(v):]
            del stack[stack.index(v):]
            if len(component) > 1:
                circles.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    assert not circles, circles


MAX_PUBLIC_METHODS = 12   # a class with more does several jobs


def test_no_class_has_more_than_twelve_public_methods():
    crowded = []
    for module, path in _modules().items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef):
                public = [f.name for f in node.body
                          if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef)) and not f.name.startswith("_")]
                if len(public) > MAX_PUBLIC_METHODS:
                    crowded.append(f"{module}.{node.name}: {len(public)} public methods")
    assert not crowded, crowded


MAX_MODULE_LINES = 500   # a longer module holds more than one concern


def test_no_module_is_longer_than_five_hundred_lines():
    long = [f"{module}: {n} lines" for module, path in _modules().items()
            if (n := len(path.read_text().splitlines())) > MAX_MODULE_LINES]
    assert not long, long
