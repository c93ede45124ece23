"""The package's import graph, read from the source (function-local imports included)."""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"


def import_graph() -> dict[str, set[str]]:
    """Module -> the liquidgs modules it imports when it runs. `from package import module` counts
    as the module only, so a package __init__ re-exporting its modules makes no cycle."""
    files = {}
    for path in (SRC / "liquidgs").rglob("*.py"):
        parts = path.relative_to(SRC).with_suffix("").parts
        files[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    graph = {}
    for name, path in files.items():
        deps = set()
        tree = ast.parse(path.read_text())
        # Imports under `if TYPE_CHECKING:` never run (annotations only), so they make no circle.
        for block in [n for n in ast.walk(tree) if isinstance(n, ast.If) and ast.unparse(n.test) == "TYPE_CHECKING"]:
            block.body = []
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "liquidgs":
                submodules = {f"{node.module}.{alias.name}" for alias in node.names} & files.keys()
                deps |= submodules if len(submodules) == len(node.names) else submodules | {node.module}
            elif isinstance(node, ast.Import):
                deps |= {alias.name for alias in node.names if alias.name in files}
        graph[name] = deps - {name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    found, done, path = [], set(), []

    def visit(module: str) -> None:
        path.append(module)
        for dep in sorted(graph[module]):
            if dep in path:
                found.append([*path[path.index(dep) :], dep])
            elif dep not in done:
                visit(dep)
        path.pop()
        done.add(module)

    for module in sorted(graph):
        if module not in done:
            visit(module)
    return found


def test_no_module_imports_itself_back():
    """No import circle anywhere, e.g. between rasterize and a backend it dispatches to."""
    assert cycles(import_graph()) == []


def test_backends_and_the_shared_floor_stay_below_their_users():
    graph = import_graph()

    def imports_from(module: str, prefixes: tuple[str, ...]) -> set[str]:
        return {dep for dep in graph[module] if dep.startswith(prefixes)}

    for backend in ("torch_backend", "cpu_backend", "gsplat_backend", "contract"):
        assert "liquidgs.render.rasterize" not in graph[f"liquidgs.render.{backend}"], backend
    # cameras and sh sit under data/ and render/, which know nothing of each other or of training.
    for module in ("liquidgs.cameras", "liquidgs.sh"):
        assert imports_from(module, ("liquidgs.",)) == set(), module
    for module in graph:
        if module.startswith("liquidgs.data"):
            assert imports_from(module, ("liquidgs.render", "liquidgs.train", "liquidgs.gaussians")) == set(), module
        if module.startswith(("liquidgs.render", "liquidgs.gaussians")):
            assert imports_from(module, ("liquidgs.data", "liquidgs.train")) == set(), module
