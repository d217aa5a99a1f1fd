"""The learning code's imports point one way: policies (SB3 model building) below imitation below rl, no cycles.

Every import statement counts, those inside functions too (they are how the heavy libraries load lazily, and a
lazy import cycle is still a cycle)."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "dpr"
LEARNING = ("dpr.policies", "dpr.imitation", "dpr.rl", "dpr.evaluation", "dpr.pipeline")  # lowest first


def _modules() -> dict[str, Path]:
    modules = {}
    for path in PACKAGE.rglob("*.py"):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        modules[".".join(parts)] = path
    return modules


def _imports(module: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The dpr modules that ``module`` imports anywhere in its source (a name imported from a module counts as
    that module; its own package does not count)."""
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
            names = [base, *(f"{base}.{alias.name}" for alias in node.names)]
        else:
            continue
        for name in names:
            while name and name not in modules:
                name = name.rpartition(".")[0]
            if name and name != "dpr" and name != module and not module.startswith(name + "."):
                found.add(name)
    return found


def _layer(module: str) -> int | None:
    return next((i for i, layer in enumerate(LEARNING) if module == layer or module.startswith(layer + ".")), None)


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    modules = _modules()
    return {module: _imports(module, path, modules) for module, path in modules.items()}


def test_the_learning_layers_import_only_downwards(graph):
    upward = [
        (module, target)
        for module, targets in graph.items()
        for target in targets
        if _layer(module) is not None and _layer(target) is not None and _layer(target) > _layer(module)
    ]
    assert upward == []
    assert "dpr.policies.sb3" in graph["dpr.imitation.bc"] and "dpr.imitation.loss" in graph["dpr.rl.anchor"]


def test_no_import_cycle_through_the_learning_code(graph):
    def reaches(start: str, goal: str) -> bool:
        seen, todo = set(), [start]
        while todo:
            module = todo.pop()
            if module == goal:
                return True
            if module not in seen:
                seen.add(module)
                todo.extend(graph.get(module, ()))
        return False

    learning = [module for module in graph if _layer(module) is not None]
    cycles = [(module, target) for module in learning for target in graph[module] if reaches(target, module)]
    assert cycles == []
