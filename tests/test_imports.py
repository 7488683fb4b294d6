"""The modules of ``warpchain``, ``continuation`` and ``sweep`` import one another without a cycle, counting the
imports inside functions too (a lazy import hides a cycle from Python, not from a reader: the issue of lattices as data
found three, and the lattice module made a fourth). A package's ``__init__`` re-exports and is left out. The engine
package does not depend on the orchestration over it: no ``warpchain`` module imports ``sweep`` at module level."""

import ast
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _modules() -> dict:
    found = {}
    for package in ("warpchain", "continuation", "sweep"):
        for path in (ROOT / package).rglob("*.py"):
            name = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            found[name.removesuffix(".__init__")] = path
    return found


def _imports(name: str, path: pathlib.Path, modules: dict) -> set:
    here = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = here[: len(here) - node.level + 1] if node.level else []
            target = ".".join(base + ([node.module] if node.module else []))
            candidates = [f"{target}.{alias.name}" for alias in node.names] + [target]
        elif isinstance(node, ast.Import):
            candidates = [alias.name for alias in node.names]
        else:
            continue
        for candidate in candidates:
            while candidate and candidate not in modules:
                candidate = candidate.rpartition(".")[0]
            if candidate and candidate != name and modules[candidate].name != "__init__.py":
                out.add(candidate)
    return out


def test_no_import_cycles():
    modules = _modules()
    graph = {name: _imports(name, path, modules) for name, path in modules.items()}
    state, cycles = {}, []

    def visit(node, trail):
        state[node] = "open"
        for nxt in sorted(graph[node]):
            if state.get(nxt) == "open":
                cycles.append(trail[trail.index(nxt) :] + [nxt])
            elif nxt not in state:
                visit(nxt, trail + [nxt])
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)
    assert graph["continuation.slicing"] >= {"continuation.spectrum"}  # the check sees imports at all


def _run_at_import(tree: ast.Module):
    """The nodes Python runs when it imports the module: everything but the bodies of functions."""
    stack = list(tree.body)
    while stack:
        node = stack.pop()
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            yield node
            stack.extend(ast.iter_child_nodes(node))


def test_warpchain_does_not_import_sweep_at_module_level():
    """``sweep`` is orchestration over ``warpchain``: ``import warpchain`` never loads it (``warpchain.reader`` reads a
    sweep group's checksums through a deferred import, as it reads branches through ``continuation``)."""
    found = []
    for name, path in _modules().items():
        if name.split(".")[0] != "warpchain":
            continue
        for node in _run_at_import(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and not node.level:
                targets = [node.module or ""]
            elif isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            else:
                continue
            found += [f"{name}: {target}" for target in targets if target.split(".")[0] == "sweep"]
    assert not found, "warpchain imports sweep at module level: " + "; ".join(found)
