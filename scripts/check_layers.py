"""Check that GRT's imports only point down: no import cycle, no import from a lower layer to a higher one.

Builds the import graph of the package from its source (``ast``, nothing is imported): every ``import``
and ``from ... import`` of a ``grt`` module, function-local ones included, except those under
``if TYPE_CHECKING:`` (they never run). Each module is placed in a layer by :data:`LAYERS`; a module the
table does not place is an error, so a new module has to be given its layer.

Usage::

    python scripts/check_layers.py            # the grt package beside this script
    python scripts/check_layers.py --root DIR  # the package in DIR (DIR/grt)

Prints one line per violation and exits 1, or one ``OK`` line with the module and edge counts.
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

PACKAGE = "grt"

# Low to high: a module may import modules of its own layer or lower ones. A module is placed by the
# longest entry that is itself or one of its parent packages; ``python -m`` shims (``__main__`` modules)
# and the command-line apps sit on top.
LAYERS: dict[str, int] = {
    "grt": 0, "grt.errors": 0, "grt.fileio": 0, "grt.console": 0,
    "grt.policy_server": 0,  # imports no GRT module: it is copied alone into a policy's own environment
    "grt.objects": 1,
    "grt.geometry": 2,
    "grt.optimizers": 3, "grt.metrics": 3, "grt.scores": 3, "grt.racing": 3, "grt.noise_floor": 3, "grt.ranking": 3,
    "grt.agreement": 3,
    "grt.config": 4, "grt.settings": 4, "grt.targets": 4, "grt.plan": 4,
    "grt.selectors": 5, "grt.policies": 5,
    "grt.tasks": 6,
    "grt.evaluators": 7,
    "grt.journal": 8, "grt.redteam": 8, "grt.confirm": 8, "grt.outputs": 8, "grt.runfolder": 8,
    "grt.loggers": 8, "grt.runner": 8, "grt.report": 8, "grt.rerun": 8, "grt.shrink": 8,
    "grt.sequential": 8, "grt.profile": 8, "grt.swapcheck": 8,
    "grt.rl": 9, "grt.blueteam": 9,
    "grt.bench": 10,
    "grt.cli": 11, "grt.run": 11, "grt.evaluate": 11, "grt.select": 11, "grt.deform": 11, "grt.train": 11,
    "grt.serve": 11, "grt.replay": 11, "grt.calibrate": 11, "grt.setup": 11,
}
TOP = 11  # every ``__main__`` module (a ``python -m`` shim)


@dataclass(frozen=True)
class Edge:
    """``source`` imports ``target`` at ``path:line``."""

    source: str
    target: str
    path: Path
    line: int


def layer_of(module: str, layers: dict[str, int] = LAYERS) -> int | None:
    """The layer of ``module`` (the longest placed prefix), or ``None`` if the table does not place it."""
    if module.rsplit(".", 1)[-1] == "__main__":
        return TOP
    parts = module.split(".")
    for end in range(len(parts), 0, -1):
        name = ".".join(parts[:end])
        if name in layers:
            if end == 1 and len(parts) > 1:
                return None  # only the package itself is placed by its name, not everything in it
            return layers[name]
    return None


def find_modules(root: Path, package: str = PACKAGE) -> dict[str, Path]:
    """Every module of ``package`` under ``root`` (``root/package``), by dotted name."""
    modules = {}
    for path in sorted((root / package).rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        modules[".".join(parts)] = path
    return modules


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _nodes(tree: ast.AST) -> Iterator[ast.AST]:
    """Every node of ``tree`` except the bodies of ``if TYPE_CHECKING:``."""
    stack = [tree]
    while stack:
        node = stack.pop()
        yield node
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            stack.extend(node.orelse)
            continue
        stack.extend(ast.iter_child_nodes(node))


def imports_of(module: str, path: Path, modules: dict[str, Path], package: str = PACKAGE) -> list[Edge]:
    """The imports of ``package`` modules that ``module`` (the file ``path``) makes."""
    tree = ast.parse(path.read_text(), filename=str(path))
    is_package = path.name == "__init__.py"
    edges = []
    for node in _nodes(tree):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = module.split(".")
                anchor = anchor[: len(anchor) - node.level + (1 if is_package else 0)]
                base = ".".join(anchor + ([base] if base else []))
            for alias in node.names:
                full = f"{base}.{alias.name}"
                names.append(full if full in modules else base)
        for name in names:
            if name == package or name.startswith(package + "."):
                edge = Edge(module, name, path, node.lineno)
                if edge.target != module and edge not in edges:
                    edges.append(edge)
    return edges


def find_cycles(modules: Iterable[str], edges: Iterable[Edge]) -> list[list[str]]:
    """One shortest cycle through each strongly connected component of more than one module."""
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for e in edges:
        graph.setdefault(e.source, set()).add(e.target)
        graph.setdefault(e.target, set())
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    components: list[list[str]] = []
    counter = 0
    for start in sorted(graph):  # Tarjan's algorithm, iterative (no recursion limit)
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        components.append(sorted(component))
            elif child not in index:
                index[child] = low[child] = counter
                counter += 1
                stack.append(child)
                on_stack.add(child)
                work.append((child, iter(sorted(graph[child]))))
            elif child in on_stack:
                low[node] = min(low[node], index[child])
    return [_shortest_cycle(c, graph) for c in sorted(components)]


def _shortest_cycle(component: list[str], graph: dict[str, set[str]]) -> list[str]:
    """A shortest cycle through the first module of ``component`` (breadth-first, inside it)."""
    start, members = component[0], set(component)
    previous: dict[str, str] = {}
    queue = [start]
    while queue:
        node = queue.pop(0)
        for child in sorted(graph[node] & members):
            if child == start:
                path = [node]
                while path[-1] != start:
                    path.append(previous[path[-1]])
                return [*reversed(path), start]
            if child not in previous:
                previous[child] = node
                queue.append(child)
    return component  # not reached: a component of two or more modules has a cycle through each


def check(root: Path, package: str = PACKAGE, layers: dict[str, int] = LAYERS) -> tuple[list[str], int, int]:
    """The violations in ``root/package`` (one line each), the number of modules and of import edges."""
    modules = find_modules(root, package)
    edges = [e for m, p in modules.items() for e in imports_of(m, p, modules, package)]
    edges.sort(key=lambda e: (str(e.path), e.line, e.target))
    problems = []
    for module, path in modules.items():
        if layer_of(module, layers) is None:
            problems.append(f"{_where(path, 1, root)}: module {module} has no layer; "
                            "place it in LAYERS in scripts/check_layers.py")
    for e in edges:
        if e.target not in modules:
            problems.append(f"{_where(e.path, e.line, root)}: {e.source} imports {e.target}, "
                            "which is not a module of the package")
            continue
        low, high = layer_of(e.source, layers), layer_of(e.target, layers)
        if low is not None and high is not None and high > low:
            problems.append(f"{_where(e.path, e.line, root)}: upward import: {e.source} (L{low}) imports "
                            f"{e.target} (L{high})")
    for cycle in find_cycles(modules, edges):
        problems.append("import cycle: " + " -> ".join(cycle))
    unique_edges = {(e.source, e.target) for e in edges}
    return problems, len(modules), len(unique_edges)


def _where(path: Path, line: int, root: Path) -> str:
    return f"{path.relative_to(root)}:{line}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", type=Path, default=Path(__file__).resolve().parent.parent,
                        help=f"folder holding the {PACKAGE} package (default: this repository)")
    args = parser.parse_args(argv)
    if not (args.root / PACKAGE).is_dir():
        print(f"error: no {PACKAGE} package in {args.root}", file=sys.stderr)
        return 2
    problems, n_modules, n_edges = check(args.root)
    for line in problems:
        print(line)
    if problems:
        print(f"{len(problems)} layer violation(s) in {n_modules} modules", file=sys.stderr)
        return 1
    print(f"OK: {n_modules} modules, {n_edges} import edges, no cycle, no upward import")
    return 0


if __name__ == "__main__":
    sys.exit(main())
