"""Check GRT's imports: no import cycle, no import from a lower layer to a higher one, Hydra only on top.

Builds the import graph of the package from its source (``ast``, nothing is imported): every ``import``
and ``from ... import`` of a ``grt`` module, function-local ones included, except those under
``if TYPE_CHECKING:`` (they never run). Each module is placed in a layer by :data:`LAYERS`; a module the
table does not place is an error, so a new module has to be given its layer. Hydra and OmegaConf
(:data:`CONFIG_LIBRARIES`) may be imported only by the app layer (the top one: ``grt.cli``, ``grt.bench``
and the ``python -m`` shims) and by :data:`CONFIG_OWNERS` (``grt.config``, which turns the config into
the run's plan, and ``grt.targets``, which makes the objects a config node names): the library below reads
plain, typed settings. When the checked tree has ``docs/architecture.md``, its layer map
(the table of the "Map" section) must name exactly the layers and modules of :data:`LAYERS`.

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
# longest entry that is itself or one of its parent packages; ``python -m`` shims (``__main__`` modules and
# :data:`SHIMS`) and the command-line apps sit on top.
LAYERS: dict[str, int] = {
    "grt": 0, "grt.errors": 0, "grt.fileio": 0, "grt.console": 0,
    "grt.policy_server": 0,  # imports no GRT module: it is copied alone into a policy's own environment
    "grt.objects": 1,
    "grt.geometry": 2,
    "grt.optimizers": 3, "grt.metrics": 3, "grt.scores": 3, "grt.racing": 3, "grt.noise_floor": 3, "grt.ranking": 3,
    "grt.agreement": 3,
    "grt.config": 4, "grt.plan": 4, "grt.targets": 4,
    "grt.selectors": 5, "grt.policies": 5,
    "grt.tasks": 6,
    "grt.evaluators": 7,
    "grt.journal": 8, "grt.runfolder.record": 8, "grt.loggers": 8,
    "grt.redteam": 9, "grt.confirm": 9, "grt.outputs": 9, "grt.runner": 9, "grt.report": 9, "grt.rerun": 9,
    "grt.runfolder": 9, "grt.sequential": 9, "grt.shrink": 9, "grt.profile": 9, "grt.swapcheck": 9,
    "grt.rl": 10, "grt.blueteam": 10,
    "grt.bench": 11, "grt.cli": 11,
}
TOP = 11  # the app layer: grt.cli, the benchmarks (``python -m grt.bench NAME``), every ``__main__`` module and
# :data:`SHIMS`
# ``python -m grt.<verb>`` shims: one module each, calling its app in grt.cli.
SHIMS = ("grt.run", "grt.evaluate", "grt.select", "grt.deform", "grt.train", "grt.serve", "grt.replay",
         "grt.calibrate", "grt.setup")
# Libraries that read the composed config (Hydra and OmegaConf), and the modules below the app layer that may
# import them: the one package that turns the config into the run's plan, and the module that makes the
# objects a config node names (``_target_``, with Hydra's instantiate) for the library and its workers.
CONFIG_LIBRARIES = ("hydra", "omegaconf")
CONFIG_OWNERS = ("grt.config", "grt.targets")
DOCS_MAP = Path("docs") / "architecture.md"


@dataclass(frozen=True)
class Edge:
    """``source`` imports ``target`` at ``path:line``."""

    source: str
    target: str
    path: Path
    line: int


def layer_of(module: str, layers: dict[str, int] = LAYERS) -> int | None:
    """The layer of ``module`` (the longest placed prefix), or ``None`` if the table does not place it."""
    if module.rsplit(".", 1)[-1] == "__main__" or module in SHIMS:
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


def config_imports(path: Path, libraries: tuple[str, ...] = CONFIG_LIBRARIES) -> list[tuple[str, int]]:
    """``(name, line)`` of every import of ``libraries`` (``hydra.utils``, ``omegaconf``) in the file ``path``."""
    found = []
    for node in _nodes(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level:
            names = [node.module or ""]
        else:
            continue
        found += [(name, node.lineno) for name in names if name.split(".")[0] in libraries]
    return found


def may_read_config(module: str, layers: dict[str, int] = LAYERS) -> bool:
    """Whether ``module`` may import Hydra or OmegaConf: it is in the app layer or in :data:`CONFIG_OWNERS`."""
    owned = any(module == owner or module.startswith(f"{owner}.") for owner in CONFIG_OWNERS)
    return owned or layer_of(module, layers) == TOP


def documented_layers(text: str) -> dict[str, int] | None:
    """The layer of each module the layer map of ``docs/architecture.md`` names (the table of its "Map"
    section: ``| L4 | `grt.config`, `grt.plan` | ...``), or ``None`` when the page has no such table."""
    section = text.split("\n## Map", 1)[-1].split("\n## ", 1)[0] if "\n## Map" in text else ""
    found: dict[str, int] = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 2 or not cells[0].startswith("L") or not cells[0][1:].isdigit():
            continue
        for name in cells[1].split("`")[1::2]:
            if name == PACKAGE or name.startswith(f"{PACKAGE}."):
                found[name] = int(cells[0][1:])
    return found or None


def docs_problems(root: Path, layers: dict[str, int] = LAYERS) -> list[str]:
    """Where ``root/docs/architecture.md``'s layer map and :data:`LAYERS` differ (nothing without the page)."""
    page = root / DOCS_MAP
    if not page.is_file():
        return []
    documented = documented_layers(page.read_text())
    if documented is None:
        return [f"{DOCS_MAP}: no layer map (a table of `| L<n> | `grt.module`, ... |` rows under '## Map')"]
    measured = {name: layer for name, layer in layers.items() if name != PACKAGE}
    problems = [f"{DOCS_MAP}: {name} is in L{layer} of scripts/check_layers.py but not in the layer map"
                for name, layer in sorted(measured.items()) if name not in documented]
    problems += [f"{DOCS_MAP}: the layer map puts {name} in L{layer}, scripts/check_layers.py in "
                 f"{'no layer' if name not in measured else f'L{measured[name]}'}"
                 for name, layer in sorted(documented.items()) if measured.get(name) != layer]
    return problems


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
    for module, path in modules.items():
        if layer_of(module, layers) is not None and not may_read_config(module, layers):
            problems += [f"{_where(path, line, root)}: {module} imports {name}: Hydra and OmegaConf belong to the "
                         "app layer (grt.cli, grt.bench, the python -m shims), grt.config, which turns the config "
                         "into the run's plan, and grt.targets, which makes the objects a config names"
                         for name, line in config_imports(path)]
    problems += docs_problems(root, layers)
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
    print(f"OK: {n_modules} modules, {n_edges} import edges, no cycle, no upward import, Hydra and OmegaConf "
          f"only in the app layer and {', '.join(CONFIG_OWNERS)}, {DOCS_MAP}'s layer map as measured")
    return 0


if __name__ == "__main__":
    sys.exit(main())
