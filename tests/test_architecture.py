"""The layers import only downward: no cycle, no forbidden import, imports at module level.

Every module of ``chargax_marl`` and ``baselines`` is parsed (function bodies included) and
each ``import`` of a project module becomes an edge of the import graph. The contracts:

- the graph has no cycle;
- ``chargax_marl`` imports nothing from ``baselines``;
- the trainers (``baselines.algos``) import only ``baselines.config``, each other and
  ``chargax_marl``: never evaluation, runs, analysis or experiments;
- ``baselines.eval`` does not import the pipeline, the CLI, analysis or experiments;
- nothing imports ``baselines.analysis`` or ``baselines.experiments`` (an experiment may
  import another experiment module);
- no import inside a function body, except of an optional dependency on a line whose
  comment says ``optional``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("chargax_marl", "baselines")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))}


def _imports(
    name: str, path: Path, modules: dict, packages: tuple[str, ...] = PACKAGES
) -> list[tuple[str, int, bool, str]]:
    """``(imported project module, line, inside a function, source line)`` of a module."""
    source = path.read_text()
    lines = source.splitlines()
    tree = ast.parse(source)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []

    def visit(node, in_function: bool):
        for child in ast.iter_child_nodes(node):
            inner = in_function or isinstance(
                child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)
            )
            targets = []
            if isinstance(child, ast.Import):
                targets = [a.name for a in child.names]
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    anchor = package.split(".")[: len(package.split(".")) - child.level + 1]
                    base = ".".join(anchor + ([base] if base else []))
                # `from pkg import module` is an edge to the module, not to the package
                targets = [
                    f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base
                    for a in child.names
                ]
            for target in targets:
                while target and target not in modules and "." in target:
                    target = target.rpartition(".")[0]
                if target.split(".")[0] in packages and target in modules:
                    out.append((target, child.lineno, in_function, lines[child.lineno - 1]))
                elif target and in_function:
                    out.append((target, child.lineno, in_function, lines[child.lineno - 1]))
            visit(child, inner)

    visit(tree, False)
    return out


@pytest.fixture(scope="module")
def graph() -> dict[str, list[tuple[str, int, bool, str]]]:
    modules = _modules()
    return {name: _imports(name, path, modules) for name, path in modules.items()}


def _edges(graph) -> dict[str, set[str]]:
    return {m: {t for t, *_ in imps if t in graph and t != m} for m, imps in graph.items()}


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            strong(v)
    return out


def _violations(
    graph, importer: str, forbidden: tuple[str, ...], allowed: tuple[str, ...] = ()
) -> list[str]:
    bad = []
    for mod, imps in graph.items():
        if not (mod == importer or mod.startswith(importer + ".")):
            continue
        for target, line, _, _ in imps:
            hit = any(target == f or target.startswith(f + ".") for f in forbidden)
            ok = any(target == a or target.startswith(a + ".") for a in allowed)
            if hit and not ok:
                bad.append(f"{mod}:{line} imports {target}")
    return bad


def test_the_import_graph_has_no_cycle(graph):
    assert _cycles(_edges(graph)) == []
    assert [m for m, imps in graph.items() if any(t == m for t, *_ in imps)] == []  # no self-import


def test_the_library_imports_nothing_from_baselines(graph):
    assert _violations(graph, "chargax_marl", ("baselines",)) == []


def test_the_trainers_import_only_config_and_the_library(graph):
    assert (
        _violations(
            graph, "baselines.algos", ("baselines",), ("baselines.algos", "baselines.config")
        )
        == []
    )


def test_evaluation_imports_no_pipeline_cli_analysis_or_experiments(graph):
    forbidden = (
        "baselines.pipeline",
        "baselines.train",
        "baselines.analysis",
        "baselines.experiments",
    )
    assert _violations(graph, "baselines.eval", forbidden) == []


def test_analysis_and_experiments_are_leaves(graph):
    bad = []
    for mod, imps in graph.items():
        for target, line, _, _ in imps:
            for leaf in ("baselines.analysis", "baselines.experiments"):
                if target.startswith(leaf) and not mod.startswith(leaf):
                    bad.append(f"{mod}:{line} imports {target}")
    assert bad == []


def test_imports_sit_at_module_level(graph):
    deferred = [
        f"{mod}:{line}: {text.strip()}"
        for mod, imps in graph.items()
        for _, line, inside, text in imps
        if inside and "optional" not in text
    ]
    assert deferred == []


def test_the_checks_catch_a_cycle_and_a_deferred_import(tmp_path):
    """The graph checks fail on a made-up package with a cycle and a deferred import."""
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from pkg import b\n")
    (pkg / "b.py").write_text("def f():\n    from pkg import a\n    return a\n")
    modules = {"pkg": pkg / "__init__.py", "pkg.a": pkg / "a.py", "pkg.b": pkg / "b.py"}
    graph = {name: _imports(name, path, modules, ("pkg",)) for name, path in modules.items()}
    assert _cycles(_edges(graph)) == [["pkg.a", "pkg.b"]]
    assert [(t, inside) for t, _, inside, _ in graph["pkg.b"]] == [("pkg.a", True)]
