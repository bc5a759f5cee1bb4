"""The layer diagram in docs/ARCHITECTURE.md, generated from the code.

    .venv/bin/python scripts/architecture.py          # rewrite the diagram in docs/ARCHITECTURE.md
    .venv/bin/python scripts/architecture.py --check  # exit 1 if it is out of date (the tests run this)

Layers are import-linter's ``layers`` contract in pyproject.toml (top imports bottom, never the
reverse); the arrows are the imports actually found in ``specsynth/`` (any ``import`` statement,
in functions too), between the layers of the modules that make them, labelled with their count.
"""

from __future__ import annotations

import argparse
import ast
import sys
import tomllib
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "ARCHITECTURE.md"
BEGIN, END = "<!-- begin generated: scripts/architecture.py -->", "<!-- end generated -->"


def layers() -> list[list[str]]:
    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    spec = next(c for c in contracts if c.get("type") == "layers")
    return [[m.strip() for m in layer.split("|")] for layer in spec["layers"]]


def _top(module: str) -> str:
    """specsynth.scenes.random_room -> specsynth.scenes"""
    return ".".join(module.split(".")[:2])


def imports() -> Counter:
    """(importing top module, imported top module) -> number of import statements."""
    edges: Counter = Counter()
    pkg = ROOT / "specsynth"
    for path in sorted(pkg.rglob("*.py")):
        rel = path.relative_to(ROOT).with_suffix("")
        module = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        package = module if rel.name == "__init__" else module.rsplit(".", 1)[0]
        for node in ast.walk(ast.parse(path.read_text())):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    stem = ".".join(base + ([node.module] if node.module else []))
                    targets = [stem] if node.module else [f"{stem}.{a.name}" for a in node.names]
                else:
                    targets = [node.module or ""]
            for t in targets:
                if t.startswith("specsynth.") and _top(t) != _top(module):
                    edges[(_top(module), _top(t))] += 1
    return edges


def diagram() -> str:
    order = layers()
    layer_of = {m: i for i, layer in enumerate(order) for m in layer}
    between: Counter = Counter()
    for (a, b), n in imports().items():
        if a in layer_of and b in layer_of and layer_of[a] != layer_of[b]:
            between[(layer_of[a], layer_of[b])] += n
    lines = ["```mermaid", "flowchart TD"]
    for i, layer in enumerate(order):
        names = "<br/>".join(m.removeprefix("specsynth.") for m in layer)
        lines.append(f'  L{i}["{names}"]')
    for (a, b), n in sorted(between.items()):
        lines.append(f"  L{a} -->|{n}| L{b}")
    lines.append("```")
    return "\n".join(lines)


def render(doc: str) -> str:
    head, rest = doc.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{diagram()}\n{END}{tail}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true")
    args = ap.parse_args()
    current = DOC.read_text()
    wanted = render(current)
    if args.check:
        if wanted != current:
            print(f"{DOC} is out of date: run python scripts/architecture.py", file=sys.stderr)
            return 1
        return 0
    DOC.write_text(wanted)
    print(f"wrote the diagram into {DOC}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
