"""The packages' layering (DESIGN.md): evaluation -> neural -> morphable, never back, and no
import cycle between modules, counting the imports inside functions too."""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("morphable", "neural", "evaluation")


def _modules() -> dict:
    out = {}
    for pkg in PACKAGES:
        for f in (ROOT / pkg).rglob("*.py"):
            parts = f.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = f
    return out


def _imports(name: str, path: Path, modules: dict) -> set:
    """The project modules that ``name`` imports anywhere in its file."""
    base = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            m = node.module or ""
            if node.level:
                b = base
                for _ in range(node.level - 1):
                    b = b.rpartition(".")[0]
                m = f"{b}.{m}" if m else b
            found |= {m} | {f"{m}.{a.name}" for a in node.names}
    return {m for m in found if m in modules and m != name}


GRAPH = {n: _imports(n, f, _modules()) for n, f in _modules().items()}


def test_packages_import_only_downwards():
    allowed = {"morphable": {"morphable"}, "neural": {"morphable", "neural"},
               "evaluation": set(PACKAGES)}
    wrong = [(a, b) for a, deps in GRAPH.items() for b in deps
             if b.split(".")[0] not in allowed[a.split(".")[0]]]
    assert not wrong, wrong
    assert len(GRAPH) > 50 and any(GRAPH.values())        # the scan saw the code


def test_no_import_cycle():
    state = {}                     # module -> 1 while on the DFS path, 2 when done

    def visit(m, path):
        state[m] = 1
        for d in sorted(GRAPH[m]):
            assert state.get(d) != 1, " -> ".join(path[path.index(d):] + [d]) if d in path else d
            if d not in state:
                visit(d, path + [d])
        state[m] = 2

    for m in sorted(GRAPH):
        if m not in state:
            visit(m, [m])


def _neural_layer(module: str) -> str:
    """``gar``, ``landmarks`` or ``faces`` for a module of those subpackages, else ``shared``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 2 or (len(parts) == 2 and parts[1] in NEURAL_PRODUCTS) else "shared"


NEURAL_PRODUCTS = ("gar", "landmarks", "faces")


def test_neural_products_over_a_shared_layer():
    # the two products use the face data engine and the shared layer; the engine only the
    # shared layer; the shared layer (training loop, checkpoints, augmentation, GPU recipes)
    # none of them
    allowed = {"gar": {"gar", "faces", "shared"}, "landmarks": {"landmarks", "faces", "shared"},
               "faces": {"faces", "shared"}, "shared": {"shared"}}
    wrong = [(a, b) for a, deps in GRAPH.items() if a.startswith("neural")
             for b in deps if b.startswith("neural")
             and _neural_layer(b) not in allowed[_neural_layer(a)]]
    assert not wrong, wrong
    assert {_neural_layer(m) for m in GRAPH if m.startswith("neural")} == set(allowed)
