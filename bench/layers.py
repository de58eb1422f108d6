"""The layer check: no module imports a higher layer, and no module is in an import cycle.

    python bench/layers.py            # per layer: modules, imports; then every violation and cycle

Every ``.py`` file under calibration/, drivers/, simulators/ and station/ is parsed with ``ast``;
every import statement counts (top level, inside functions, under ``TYPE_CHECKING``), relative
imports resolved, and ``from pkg import name`` imports the submodule ``pkg.name`` when there is
one. A string naming a module (the driver registry's table) is not an import. Exit status 1 when
a module imports a layer it may not, or belongs to no layer, or when modules import each other
in a cycle (a strongly connected component of the import graph). ``tests/test_layers.py`` runs
it on the repository.
"""

from __future__ import annotations

import ast
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("calibration", "drivers", "simulators", "station")  # parsed and checked
SCRIPT_DIRS = ("tests", "bench")  # never imported by the packages (their files by plain name too)

# The layers, lowest first. "pkg.*" covers pkg and every module under it; a plain name covers
# that one module. Our packages, each with the packages it may import besides itself:
PACKAGE_LAYERS = [
    ("calibration", ("calibration.*",), ()),
    ("drivers", ("drivers.*",), ()),
    ("simulators", ("simulators.*",), ("calibration", "drivers")),
]
# The station may import calibration and drivers, and inside it a module may import its own
# layer and the layers above it in this list (so the 2-D rim stage never sees the 3-D wheel):
STATION_USES = ("calibration", "drivers")
STATION_LAYERS = [
    ("foundation", ("station", "station.errors", "station.config", "station.compute.*")),
    ("stages", ("station.capture.*", "station.rim.*", "station.alignment", "station.odometry.*",
                "station.records.*", "station.operator", "station.sequencer", "station.result")),
    ("3-D wheel", ("station.wheel.*",)),
    ("measurement", ("station.measure", "station.stated_uncertainty")),
    ("cycle", ("station.cycle", "station.live", "station.procedures.*")),
    ("plc", ("station.plc.*",)),
    ("commands", ("station.commands.*", "station.cli", "station.ui.*")),
]
# (layer, its modules, the layers it may import besides its own)
LAYERS = PACKAGE_LAYERS + [(name, modules, (*STATION_USES, *(n for n, _ in STATION_LAYERS[:k])))
                           for k, (name, modules) in enumerate(STATION_LAYERS)]


@dataclass(frozen=True)
class Import:
    """One import of one of our modules: ``source`` imports ``target`` at file:line."""

    source: str
    target: str
    file: str
    line: int

    def where(self) -> str:
        return f"{self.file}:{self.line}"


@dataclass
class Report:
    """What the check found: the modules, their imports of ours, the violations, the cycles."""

    modules: dict[str, str] = field(default_factory=dict)        # module -> file
    imports: list[Import] = field(default_factory=list)
    violations: list[tuple[Import, str]] = field(default_factory=list)  # (import, why)
    cycles: list[list[Import]] = field(default_factory=list)     # each closes on its first source

    @property
    def ok(self) -> bool:
        return not self.violations and not self.cycles


def layer_of(module: str) -> str | None:
    """The layer a module belongs to (the first that covers it), or None."""
    for name, patterns, _ in LAYERS:
        for p in patterns:
            if module == p or (p.endswith(".*") and (module == p[:-2] or module.startswith(p[:-1]))):
                return name
    return None


def module_files(root: Path) -> dict[str, Path]:
    """{dotted module name: file} of every .py file under the checked packages."""
    out = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


def script_names(root: Path) -> dict[str, str]:
    """{plain module name: "tests" or "bench"}: the scripts' files, importable by plain name when
    their folder is on sys.path (tests import each other so)."""
    return {p.stem: d for d in SCRIPT_DIRS for p in (root / d).glob("*.py") if p.stem != "__init__"}


def imported_names(tree: ast.AST, module: str, is_package: bool):
    """(line, dotted name, from-names) of every import statement in ``tree``, anywhere in it;
    a relative one resolved against ``module``."""
    package = module if is_package else module.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, ()
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parts = parts[:len(parts) - (node.level - 1)]
                base = ".".join(parts + ([node.module] if node.module else []))
            yield node.lineno, base, tuple(a.name for a in node.names)


def resolve(name: str, scripts: dict) -> str | None:
    """The module of ours that ``name`` refers to ("tests.x" / "bench.x" for a script's file
    imported by plain name), or None for a third-party or standard module."""
    top = name.split(".")[0]
    if top in PACKAGES or top in SCRIPT_DIRS:
        return name
    if top in scripts:
        return f"{scripts[top]}.{name}"
    return None


def collect(root: Path) -> Report:
    """Parse every module under ``root``'s packages: their imports of our own modules."""
    files = module_files(root)
    scripts = script_names(root)
    report = Report(modules={m: str(p.relative_to(root)) for m, p in files.items()})
    for module, path in files.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        for line, name, names in imported_names(tree, module, path.name == "__init__.py"):
            targets = [f"{name}.{n}" if f"{name}.{n}" in files else name for n in names] or [name]
            for target in dict.fromkeys(resolve(t, scripts) for t in targets):
                if target is not None and target != module:
                    report.imports.append(Import(module, target, report.modules[module], line))
    return report


def check_layers(report: Report) -> None:
    """A violation for every module in no layer and every import of a layer it may not use."""
    allowed = {name: {name, *may} for name, _, may in LAYERS}
    for module, file in report.modules.items():
        if layer_of(module) is None:
            report.violations.append((Import(module, module, file, 1), f"{module} is in no layer of bench/layers.py"))
    for imp in report.imports:
        src, dst = layer_of(imp.source), layer_of(imp.target)
        if src is not None and dst not in allowed[src]:
            top = imp.target.split(".")[0]
            label = dst or (top if top in SCRIPT_DIRS else "no layer")
            report.violations.append((imp, f"{imp.source} ({src}) imports {imp.target} ({label})"))


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components with more than one module, iteratively."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    m = stack.pop()
                    on_stack.discard(m)
                    component.append(m)
                    if m == node:
                        break
                if len(component) > 1:
                    out.append(sorted(component))
    return out


def check_cycles(report: Report) -> None:
    """One cycle per strongly connected component: the shortest way back to its first module."""
    edges: dict[tuple[str, str], Import] = {}
    for imp in report.imports:
        edges.setdefault((imp.source, imp.target), imp)
    graph: dict[str, set[str]] = {m: set() for m in report.modules}
    for src, dst in edges:
        if dst in graph:
            graph[src].add(dst)
    for component in strongly_connected(graph):
        members, first = set(component), component[0]
        came_from: dict[str, str] = {}
        frontier = [first]
        while first not in came_from:
            nxt = []
            for m in frontier:
                for d in sorted(graph[m] & members):
                    if d not in came_from:
                        came_from[d] = m
                        nxt.append(d)
            frontier = nxt
        path, m = [], first
        while True:
            path.append(edges[(came_from[m], m)])
            m = came_from[m]
            if m == first:
                break
        report.cycles.append(path[::-1])


def check(root: Path = ROOT) -> Report:
    """The layer violations and import cycles of the packages under ``root``."""
    report = collect(root)
    check_layers(report)
    check_cycles(report)
    return report


def print_report(report: Report) -> None:
    """Per layer its modules and their imports of ours; then every violation and cycle."""
    counts: dict[str, list[int]] = {name: [0, 0] for name, _, _ in LAYERS}
    for module in report.modules:
        if (layer := layer_of(module)) is not None:
            counts[layer][0] += 1
    for imp in report.imports:
        if (layer := layer_of(imp.source)) is not None:
            counts[layer][1] += 1
    print(f"{'layer':<12} {'modules':>7} {'imports':>7}")
    for name, (n_modules, n_imports) in counts.items():
        print(f"{name:<12} {n_modules:>7} {n_imports:>7}")
    for imp, why in report.violations:
        print(f"{imp.where()}: layer violation: {why}")
    for cycle in report.cycles:
        print("import cycle: " + " -> ".join([cycle[0].source] + [i.target for i in cycle]))
        for imp in cycle:
            print(f"  {imp.where()}: {imp.source} imports {imp.target}")
    print("ok: no layer violation, no import cycle" if report.ok else
          f"{len(report.violations)} layer violation(s), {len(report.cycles)} import cycle(s)")


def main() -> int:
    report = check(ROOT)
    print_report(report)
    return 0 if report.ok else 1


if __name__ == "__main__":
    sys.exit(main())
