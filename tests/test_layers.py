"""The package's layers: every module imports only from its own layer or below, and no private name crosses a
file. Layers, from the bottom: errors; config and the file formats; physics; geometry; the multiple-scattering
table; what the integrators share (render); the point-based method; the dipole (which takes the point-based method's
light surface samples and octree); the pipeline's stages; the command line."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "pbvol_cli"
LAYERS = [
    {"__version__", "errors", "jit", "kernel_cache"},
    {"config", "config_reference", "imageio"},
    {"physics"},
    {"geometry"},
    {"multiple_scattering"},
    {"render"},
    {"vpl"},
    {"pointbased"},
    {"dipole"},
    {"pipeline"},
    {"main"},
]


def _layer(module: str) -> int:
    """The layer of a module path relative to the package ('physics.phase', 'main')."""
    top = module.split(".")[0]
    for k, names in enumerate(LAYERS):
        if top in names:
            return k
    raise AssertionError(f"{module}: in no layer; add it to LAYERS")


def _imports(path: Path):
    """(imported module, imported names, line) of every pbvol_cli import in a file, lazy imports included."""
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("pbvol_cli"):
            yield node.module.removeprefix("pbvol_cli").lstrip("."), [a.name for a in node.names], node.lineno
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("pbvol_cli."):
                    yield a.name.removeprefix("pbvol_cli."), [], node.lineno


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).with_suffix("")
        name = ".".join(p for p in rel.parts if p != "__init__")
        if name:
            yield name, path


def test_no_module_imports_from_a_layer_above_its_own():
    bad = []
    for name, path in _modules():
        for module, names, line in _imports(path):
            targets = [module] if module else names  # "from pbvol_cli import config" names the module
            for target in targets:
                if _layer(target) > _layer(name):
                    bad.append(f"{name}:{line} imports {target}")
    assert not bad, bad


def test_no_private_name_is_imported_from_another_file():
    bad = [f"{name}:{line} imports {n} from {module}" for name, path in _modules()
           for module, names, line in _imports(path) for n in names if n.startswith("_") and n != "__version__"]
    assert not bad, bad


def test_tests_use_no_private_names_of_the_package():
    tests = Path(__file__).resolve().parent
    bad = [f"{p.relative_to(tests)}:{line} imports {n}" for p in sorted(tests.rglob("*.py"))
           for module, names, line in _imports(p) for n in names if n.startswith("_")]
    assert not bad, bad


def test_no_import_cycles_between_modules():
    graph = {name: set() for name, _ in _modules()}
    for name, path in _modules():
        for module, names, _ in _imports(path):
            for target in ([module] if module else names):
                if target in graph and target != name:
                    graph[name].add(target)
    state = {}

    def visit(node, stack):
        state[node] = 1
        for nxt in graph[node]:
            if state.get(nxt) == 1:
                raise AssertionError(" -> ".join(stack + [node, nxt]))
            if nxt not in state:
                visit(nxt, stack + [node])
        state[node] = 2

    for node in graph:
        if node not in state:
            visit(node, [])
