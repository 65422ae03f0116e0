"""The floors of mpclab (docs/architecture.md): imports run down, never up, and never in a
circle.

Every module's imports are read with ``ast`` (module level and inside functions). A module
may import modules of its own floor and of the floors below. Known violations would be listed
in the allow-lists below (there are none); a new one fails. ``python
tests/test_architecture.py`` prints the import edges between the packages.
"""

from __future__ import annotations

import ast
import re
from collections import defaultdict
from pathlib import Path
from typing import NamedTuple

ROOT = Path(__file__).resolve().parent.parent
PKG = ROOT / "mpclab"
DOC = ROOT / "docs" / "architecture.md"

#: floor -> the packages on it (every module of a package is on its floor; the root package
#: ``mpclab`` holds only itself and ``__main__``); docs/architecture.md's table lists the same
FLOORS: dict[int, tuple[str, ...]] = {
    0: ("mpclab", "mpclab.core"),
    1: ("mpclab.config", "mpclab.record", "mpclab.codegen"),
    2: ("mpclab.plants", "mpclab.objectives", "mpclab.constraints", "mpclab.policy"),
    3: ("mpclab.controllers", "mpclab.world", "mpclab.supervisors", "mpclab.recorders"),
    4: ("mpclab.runner",),
    5: ("mpclab.tables",),
    6: ("mpclab.sweeps", "mpclab.approx"),
    7: ("mpclab.cli", "mpclab.__main__"),
}

# Known violations: none today (the sets stay, so that a new one is listed, not silent).
#: (importer, imported) going up a floor
ALLOWED_UP: set[tuple[str, str]] = set()
#: import cycles (module level and in functions together), as sets of modules
ALLOWED_CYCLES: list[set[str]] = []
#: modules above the components that composing a config imports
ALLOWED_REGISTRY_UP: set[str] = set()
#: a constructor takes at most this many parameters (options grouped in small dataclasses)
MAX_PARAMETERS = 12
#: constructors over the limit, with their count: to be grouped; none may grow or be added


class Edge(NamedTuple):
    importer: str
    imported: str
    in_function: bool
    line: int


def modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PKG.rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _resolve(name: str, mods: dict[str, Path]) -> str | None:
    """The mpclab module ``name`` is or is inside of (``mpclab.x.Name`` -> ``mpclab.x``)."""
    while name and name not in mods:
        name = name.rpartition(".")[0]
    return name or None


def edges() -> list[Edge]:
    mods = modules()
    out = []
    for mod, path in mods.items():
        tree = ast.parse(path.read_text(), str(path))
        package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        in_function = {id(n) for f in ast.walk(tree)
                       if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
                       for n in ast.walk(f)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:  # relative: from the package up level - 1
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*up, base] if base else up)
                # `from a import b`: b is a module of a, or a name defined in a
                names = [f"{base}.{a.name}" for a in node.names]
            else:
                continue
            for name in names:
                target = _resolve(name, mods) if name.startswith("mpclab") else None
                if target is not None and target != mod:
                    out.append(Edge(mod, target, id(node) in in_function, node.lineno))
    return out


def place(mod: str) -> str:
    """The longest entry of FLOORS that is ``mod`` or a package holding it (the root package
    ``mpclab`` holds only itself, so that a new top-level module must be placed)."""
    found = [p for prefixes in FLOORS.values() for p in prefixes
             if mod == p or (p != "mpclab" and mod.startswith(p + "."))]
    if not found:
        raise AssertionError(f"{mod} is on no floor: add it to FLOORS and docs/architecture.md")
    return max(found, key=len)


def floor(mod: str) -> int:
    p = place(mod)
    return next(n for n, prefixes in FLOORS.items() if p in prefixes)


def cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[set[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(comp)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_every_module_is_on_a_floor() -> None:
    for mod in modules():
        floor(mod)


def test_no_import_goes_up_a_floor() -> None:
    up = {(e.importer, e.imported) for e in edges() if floor(e.imported) > floor(e.importer)}
    new = sorted(up - ALLOWED_UP)
    assert not new, f"imports going up a floor (docs/architecture.md): {new}"
    gone = sorted(ALLOWED_UP - up)
    assert not gone, f"fixed, remove from ALLOWED_UP: {gone}"


def test_no_import_cycle() -> None:
    """No cycle among module-level imports, nor one closed by an import in a function (an
    import moved into a function to dodge a cycle is still a cycle)."""
    module_level: dict[str, set[str]] = defaultdict(set)
    every: dict[str, set[str]] = defaultdict(set)
    for e in edges():
        every[e.importer].add(e.imported)
        if not e.in_function:
            module_level[e.importer].add(e.imported)
    assert cycles(module_level) == [], "import cycle at module level"
    found = cycles(every)
    new = [c for c in found if c not in ALLOWED_CYCLES]
    assert not new, f"import cycles through imports inside functions: {new}"
    gone = [c for c in ALLOWED_CYCLES if c not in found]
    assert not gone, f"fixed, remove from ALLOWED_CYCLES: {gone}"


def test_composing_imports_only_components() -> None:
    """registry.register_all imports every module of its packages: they must be components
    (the controllers' floor or below), not the tools above the runner."""
    from mpclab.config.registry import COMPONENT_PACKAGES

    reached = {m for m in modules() for p in COMPONENT_PACKAGES
               if m.startswith(p + ".")}
    above = {m for m in reached if floor(m) > floor("mpclab.controllers")}
    new, gone = sorted(above - ALLOWED_REGISTRY_UP), sorted(ALLOWED_REGISTRY_UP - above)
    assert not new, f"register_all imports modules above the components: {new}"
    assert not gone, f"fixed, remove from ALLOWED_REGISTRY_UP: {gone}"


def test_no_private_field_is_read_across_modules() -> None:
    """``obj._name`` (not ``self``'s or ``cls``'s) is read only in the module that defines
    ``_name``: another module asks through a public name. Config keys such as ``_target_``
    are not fields, and the standard library's public names with an underscore (a named
    tuple's ``_replace``, ``os._exit``) are not private."""
    public = {"_replace", "_asdict", "_fields", "_make", "_exit"}
    found = []
    for mod, path in modules().items():
        tree = ast.parse(path.read_text(), str(path))
        own = {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)
               and isinstance(n.value, ast.Name) and n.value.id in ("self", "cls")}
        own |= {n.name for n in ast.walk(tree)
                if isinstance(n, ast.FunctionDef | ast.ClassDef | ast.AsyncFunctionDef)}
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)):
                continue
            name = node.attr
            if (name.startswith("_") and not name.endswith("_") and node.value.id
                    not in ("self", "cls") and name not in own | public):
                found.append(f"{mod}:{node.lineno}: {node.value.id}.{name}")
    assert not found, f"private fields read from another module: {found}"


def test_no_constructor_takes_more_than_twelve_parameters() -> None:
    long = {}
    for path in modules().values():
        tree = ast.parse(path.read_text())
        for cls in (n for n in ast.walk(tree) if isinstance(n, ast.ClassDef)):
            for f in cls.body:
                if isinstance(f, ast.FunctionDef) and f.name == "__init__":
                    a = f.args
                    n = len(a.args) - 1 + len(a.kwonlyargs) + bool(a.vararg) + bool(a.kwarg)
                    if n > MAX_PARAMETERS:
                        long[cls.name] = n
    assert not long, (f"constructors over {MAX_PARAMETERS} parameters (group related options "
                      f"into an option group, mpclab.core.options): {long}")


def test_doc_lists_the_floors() -> None:
    """docs/architecture.md's floor table (``| n | name | `mod`, ... |``) equals FLOORS."""
    rows = re.findall(r"^\| (\d) \| [^|]+ \| ([^|]+) \|", DOC.read_text(), re.M)
    doc = {int(n): tuple(re.findall(r"`([\w.]+)`", mods)) for n, mods in rows}
    assert doc == FLOORS


if __name__ == "__main__":
    by_unit: dict[tuple[str, str], set[str]] = defaultdict(set)
    for e in edges():
        a, b = place(e.importer), place(e.imported)
        if a != b:
            by_unit[(a, b)].add("function" if e.in_function else "module")
    for (a, b), kinds in sorted(by_unit.items(), key=lambda kv: (-floor(kv[0][0]), kv[0])):
        how = "" if kinds == {"module"} else " (in a function)" if kinds == {"function"} \
            else " (also in a function)"
        print(f"{a} [{floor(a)}] -> {b} [{floor(b)}]{how}")
