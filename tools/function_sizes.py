"""Functions in dpr/ by length and by parameter count (self/cls not counted; *args and **kwargs count one each),
read with ast: the ones over 60 lines, over 100, and over 8 parameters.

    python tools/function_sizes.py [dpr]
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path


def functions(root: Path):
    """(lines, parameters, "path:line", name) of every function and method below ``root``."""
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                args = node.args
                positional = [*args.posonlyargs, *args.args]
                count = len(positional) + len(args.kwonlyargs) + (args.vararg is not None) + (args.kwarg is not None)
                if positional and positional[0].arg in ("self", "cls"):
                    count -= 1
                yield node.end_lineno - node.lineno + 1, count, f"{path}:{node.lineno}", node.name


def main(argv: list[str]) -> int:
    rows = list(functions(Path(argv[0] if argv else "dpr")))
    long = sorted((row for row in rows if row[0] > 60), reverse=True)
    many = sorted((row for row in rows if row[1] > 8), key=lambda row: -row[1])
    print(f"{len(rows)} functions; over 60 lines: {len(long)} (over 100: {sum(row[0] > 100 for row in long)})")
    for lines, _, where, name in long:
        print(f"  {lines:4d} lines  {where} {name}")
    print(f"over 8 parameters: {len(many)}")
    for _, count, where, name in many:
        print(f"  {count:4d} params {where} {name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
