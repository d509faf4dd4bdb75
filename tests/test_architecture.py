"""Layout of the package: no import cycle, no private name imported across subpackages.

Static (``ast``): every ``import``/``from ... import`` of ``thsa_control`` and
``linearization``, also inside functions (an import that runs later still
ties the modules); blocks under ``if TYPE_CHECKING:`` are ignored (they never
run).  A *subpackage* is the first level below the top package
(``thsa_control.model``, ``thsa_control.fit``, ...; a top-level module such as
``thsa_control.cli`` is one of its own).

One kind of edge is not part of the import graph: a result's lazy pass-through
to the report package (STYLE.md rule 5, python-control's
``TimeResponseData.plot`` -> ``timeplot``): an import of a
``thsa_control.report`` module inside a method named ``report``, ``to_dict`` or
``plot`` of a module outside ``report/``.  It runs only when a user asks a
result to print or draw itself, never at import; any other import, at module
level or in any other function, counts.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("thsa_control", "linearization")


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            out[_module_name(path)] = path
    return out


MODULES = _modules()


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def _walk(tree):
    """``(node, name of the innermost enclosing function or None)`` of every node except those under
    ``if TYPE_CHECKING:``."""
    stack = [(tree, None)]
    while stack:
        node, func = stack.pop()
        if isinstance(node, ast.If) and _is_type_checking(node):
            stack.extend((n, func) for n in node.orelse)
            continue
        yield node, func
        inner = node.name if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) else func
        stack.extend((n, inner) for n in ast.iter_child_nodes(node))


#: Methods through which a result prints or draws itself (lazy pass-throughs to ``thsa_control.report``).
PASS_THROUGH_METHODS = ("report", "to_dict", "plot")


def is_pass_through(module: str, target: str, func: str | None) -> bool:
    """An import of a report module inside a result's ``report``/``to_dict``/``plot`` method."""
    return (func in PASS_THROUGH_METHODS and target.startswith("thsa_control.report")
            and not module.startswith("thsa_control.report"))


def _resolve(module: str, is_package: bool, level: int, name: str | None) -> str:
    if level == 0:
        return name or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (level - 1)]
    return ".".join(base + ([name] if name else []))


def _known(name: str) -> str | None:
    """The longest module of the packages that ``name`` is or lies in."""
    while name:
        if name in MODULES:
            return name
        name = name.rpartition(".")[0]
    return None


@functools.lru_cache(maxsize=None)
def _tree(path: str, mtime_ns: int) -> ast.Module:
    """The parsed file (once per file and modification time: both layout tests walk every module; the walk
    does not change the tree)."""
    return ast.parse(Path(path).read_text(encoding="utf-8"), path)


def imports(module: str, *, with_function: bool = False) -> list[tuple]:
    """``(target module, imported name or None, line)`` of every import of the packages in ``module``
    (with ``with_function``: and the innermost enclosing function's name, or None at module level)."""
    path = MODULES[module]
    tree = _tree(str(path), path.stat().st_mtime_ns)
    is_pkg = path.name == "__init__.py"
    out = []
    for node, func in _walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                target = _known(a.name)
                if target:
                    out.append((target, None, node.lineno, func))
        elif isinstance(node, ast.ImportFrom):
            base = _resolve(module, is_pkg, node.level, node.module)
            for a in node.names:
                sub = f"{base}.{a.name}"
                if sub in MODULES:  # "from pkg import submodule"
                    out.append((sub, None, node.lineno, func))
                else:
                    target = _known(base)
                    if target:
                        out.append((target, a.name, node.lineno, func))
    return out if with_function else [o[:3] for o in out]


def subpackage(module: str) -> str:
    parts = module.split(".")
    return ".".join(parts[:2])


def private_crossings() -> list[str]:
    bad = []
    for m in MODULES:
        for target, name, line in imports(m):
            if subpackage(target) == subpackage(m):
                continue
            private_module = any(p.startswith("_") and not p.startswith("__")
                                 for p in target.split(".")[len(subpackage(target).split(".")):])
            if (name is not None and name.startswith("_") and not name.startswith("__")) or private_module:
                what = f"{target}.{name}" if name else target
                bad.append(f"{m}:{line} imports private {what}")
    return bad


def _graph() -> dict[str, set[str]]:
    g: dict[str, set[str]] = {m: set() for m in MODULES}
    for m in MODULES:
        for target, _, _, func in imports(m, with_function=True):
            if target != m and not is_pass_through(m, target, func):
                g[m].add(target)
    return g


def import_cycles() -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), each listed sorted."""
    g = _graph()
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on, stack, out = set(), [], []
    counter = [0]

    def visit(v):
        work = [(v, iter(sorted(g[v])))]
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        while work:
            node, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(g[w]))))
                    break
                if w in on:
                    low[node] = min(low[node], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == node:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            visit(v)
    return sorted(out)


# ----------------------------------------------------------------------------- the checker checks
def test_checker_sees_imports_inside_functions_and_relative_ones():
    found = {(t, n) for t, n, _ in imports("thsa_control.loops.design")}
    assert ("thsa_control.model", "build_plant") in found  # imported inside reflected_inertia
    assert ("thsa_control.model.laws", "kinematic_ratio") in found


def test_checker_exempts_only_result_pass_throughs_to_report():
    found = {(t, f) for t, _, _, f in imports("thsa_control.sim.simulate", with_function=True)}
    assert ("thsa_control.report.plots", "plot") in found  # SimulationResult.plot draws through report/
    assert is_pass_through("thsa_control.sim.simulate", "thsa_control.report.plots", "plot")
    assert not is_pass_through("thsa_control.sim.simulate", "thsa_control.report.plots", "run")  # any other function
    assert not is_pass_through("thsa_control.sim.simulate", "thsa_control.report.plots", None)  # module level
    assert not is_pass_through("thsa_control.sim.simulate", "thsa_control.fit.replay", "plot")  # not into report
    assert not is_pass_through("thsa_control.report.trace", "thsa_control.report.build", "plot")  # report itself


def test_checker_finds_a_cycle(monkeypatch):
    import sys

    mod = sys.modules[__name__]
    g = {"a.x": {"a.y"}, "a.y": {"a.z"}, "a.z": {"a.x"}, "a.w": {"a.x"}, "a.v": set()}
    monkeypatch.setattr(mod, "_graph", lambda: g)
    assert mod.import_cycles() == [["a.x", "a.y", "a.z"]]


def test_checker_finds_a_private_crossing(tmp_path, monkeypatch):
    import sys

    mod = sys.modules[__name__]
    pkg = tmp_path / "thsa_control"
    (pkg / "a").mkdir(parents=True)
    (pkg / "b").mkdir()
    for f in ("__init__.py", "a/__init__.py", "b/__init__.py", "a/m.py"):
        (pkg / f).write_text("")
    (pkg / "a" / "n.py").write_text("from .m import _private_ok\n")  # same subpackage: allowed
    (pkg / "b" / "k.py").write_text("def f():\n    from ..a.m import _helper\n")  # inside a function: counted
    monkeypatch.setattr(mod, "ROOT", tmp_path)
    monkeypatch.setattr(mod, "PACKAGES", ("thsa_control",))
    monkeypatch.setattr(mod, "MODULES", mod._modules())
    assert mod.private_crossings() == ["thsa_control.b.k:2 imports private thsa_control.a.m._helper"]


# ----------------------------------------------------------------------------- the layout
def test_no_private_name_imported_across_subpackages():
    bad = private_crossings()
    assert not bad, "\n".join(bad)


def test_package_import_graph_has_no_cycle():
    cycles = import_cycles()
    assert not cycles, "\n".join(" <-> ".join(c) for c in cycles)
