"""The codebase's shape, kept by tests: no import cycles in dpr/ (module sizes: tests/test_document_sizes.py).

The layering itself (sim -> envs -> policies -> datasets -> imitation -> rl, viz and cli on top) is an
import-linter contract in pyproject.toml, checked by `make lint`.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "dpr"


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict[str, set[str]]:
    """Module -> the dpr modules it imports anywhere in its body (lazy imports inside functions count too:
    a cycle hidden in a function is still a cycle a reader must untangle)."""
    modules = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(
                        package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else [])
                    )
                # `from pkg import sub` imports the submodule pkg.sub when there is one, else a name of pkg
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
            else:
                continue
            for target in targets:
                while target and target not in modules:  # `import dpr.sim.constants as C` -> dpr.sim.constants
                    target = target.rpartition(".")[0]
                if target and target != name:
                    graph[name].add(target)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for other in graph[node]:
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in on_stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_no_import_cycles_in_dpr():
    assert cycles(import_graph()) == []


def test_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


# The envs' constructors take the public gym.make keyword arguments, as Gymnasium's own envs do.
ENV_CONSTRUCTORS = {("dpr/envs/particle_env.py", "__init__")}


def test_functions_stay_short_and_take_few_parameters():
    from helpers import load_tool

    rows = list(load_tool("function_sizes").functions(PACKAGE))
    over_100 = [(where, name, lines) for lines, _, where, name in rows if lines > 100]
    over_60 = [(where, name, lines) for lines, _, where, name in rows if lines > 60]
    many = [
        (where, name, count)
        for _, count, where, name in rows
        if count > 8 and (str(Path(where.split(":")[0]).relative_to(PACKAGE.parent)), name) not in ENV_CONSTRUCTORS
    ]
    assert over_100 == [], f"functions over 100 lines: {over_100}"
    assert len(over_60) <= 8, f"{len(over_60)} functions over 60 lines, at most 8 allowed: {over_60}"
    assert many == [], f"functions over 8 parameters: {many}"
