"""The project's import layering, read from the source with ``ast`` (nothing is imported).

Graph: one node per module of ``talar_jax/``, ``envs/``, ``experiments/`` and ``benchmarks/`` (a package is its
``__init__``), one edge per import statement naming another project module, wherever it stands: at the top, inside a
function, or under ``if TYPE_CHECKING:``. Type-checking imports count: they tie the modules together for every reader
and type checker, and are the usual way a real loop is kept from failing at run time, so they must not hide a cycle.

An import edge goes to the module the statement names, not to the packages above it: ``from a.b import c`` is an
edge to ``a.b.c`` when that is a module, else to ``a.b``; that Python runs ``a/__init__`` first is not a dependency
of the importing module. So a package whose ``__init__`` imports its submodules, which import their siblings, has no
cycle; it has one only when a submodule imports the package itself (a name of its ``__init__``) and so loops back.

Rules:
    * ``talar_jax`` imports no ``experiments``, ``benchmarks``, ``scripts`` or ``tests`` module and no concrete env: of
      ``envs`` it may import the package itself and its top-level modules (``envs/<name>.py``: base, registry,
      wrappers, instructions, ...), never a module inside an env subpackage (``envs/<name>/``: clevr, kitchen and any
      env added later).
    * ``envs`` imports nothing of ``talar_jax``, ``experiments``, ``benchmarks``, ``scripts`` or ``tests``.
    * No import cycle among project modules (a strongly connected component of more than one module, or a module
      importing itself), except those named in ``KNOWN_CYCLES``.
"""

from __future__ import annotations

import ast
import warnings
from collections.abc import Iterable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("talar_jax", "envs", "experiments", "benchmarks")
OUTSIDE = ("experiments", "benchmarks", "scripts", "tests")  # never imported by the libraries

# Cycles tolerated for now, each the set of its modules, e.g. frozenset({"experiments.pipeline", "experiments.methods"})
# (the TYPE_CHECKING loop the pipeline / methods split removed). Empty: no cycle is tolerated.
KNOWN_CYCLES: frozenset[frozenset[str]] = frozenset()

Graph = dict[str, set[str]]


def module_name(path: Path, root: Path) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def discover(root: Path, packages: Iterable[str]) -> dict[str, Path]:
    """``{module name: file}`` of every .py file under the given top-level packages of ``root``."""
    modules = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            if not any(part.startswith(".") or part == "__pycache__" for part in path.relative_to(root).parts):
                modules[module_name(path, root)] = path
    return modules


def imported_names(tree: ast.AST, module: str, is_package: bool) -> set[str]:
    """The dotted name of everything an import statement of ``tree`` brings in, at any depth (relative ones resolved).

    ``import a.b`` gives ``a.b``; ``from a import b`` gives ``a.b``, whether ``b`` is a module or a name of ``a``
    (``resolve`` tells them apart); ``from a import *`` gives ``a``.
    """
    package = module if is_package else module.rpartition(".")[0]
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            names.update(source if alias.name == "*" else f"{source}.{alias.name}" for alias in node.names)
    return names


def resolve(name: str, modules: Iterable[str]) -> str | None:
    """The project module a dotted name is or lies in: its longest prefix that is a module (None: outside)."""
    parts = name.split(".")
    for end in range(len(parts), 0, -1):
        if (candidate := ".".join(parts[:end])) in modules:
            return candidate
    return None


def build_graph(sources: dict[str, tuple[str, bool]]) -> Graph:
    """``{module: project modules it imports}`` from ``{module: (source text, whether it is a package __init__)}``."""
    graph: Graph = {}
    for module, (text, is_package) in sources.items():
        targets = (resolve(name, sources) for name in imported_names(ast.parse(text), module, is_package))
        graph[module] = {target for target in targets if target is not None}
    return graph


def project_graph(root: Path = ROOT, packages: Iterable[str] = PACKAGES) -> tuple[Graph, dict[str, list[str]]]:
    """The project's graph and, per module, every dotted import name (for rules on modules outside the graph)."""
    files = discover(root, packages)
    sources = {name: (path.read_text(encoding="utf-8"), path.name == "__init__.py") for name, path in files.items()}
    names = {
        module: sorted(imported_names(ast.parse(text), module, is_package))
        for module, (text, is_package) in sources.items()
    }
    return build_graph(sources), names


def cycles(graph: Graph) -> list[frozenset[str]]:
    """Strongly connected components with more than one module, plus modules importing themselves (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []

    def visit(root: str) -> None:
        # iterative Tarjan: (node, iterator over its successors)
        work = [(root, iter(sorted(graph.get(root, ()))))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, successors = work[-1]
            for successor in successors:
                if successor not in index:
                    index[successor] = low[successor] = len(index)
                    stack.append(successor)
                    on_stack.add(successor)
                    work.append((successor, iter(sorted(graph.get(successor, ())))))
                    break
                if successor in on_stack:
                    low[node] = min(low[node], index[successor])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = set()
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.add(member)
                        if member == node:
                            break
                    if len(component) > 1 or node in graph.get(node, ()):
                        found.append(frozenset(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def is_concrete_env(name: str, env_packages: Iterable[str]) -> bool:
    """Whether a dotted name is a module of an env subpackage (``envs.<pkg>`` or below it)."""
    parts = name.split(".")
    return len(parts) >= 2 and parts[0] == "envs" and parts[1] in set(env_packages)


def env_subpackages(root: Path = ROOT) -> set[str]:
    """The env packages: every directory of ``envs/`` with an ``__init__.py``."""
    return {path.parent.name for path in (root / "envs").glob("*/__init__.py")}


def layering_violations(names: dict[str, list[str]], env_packages: Iterable[str]) -> list[str]:
    """``"importer -> imported"`` for every import breaking the rules of talar_jax and envs."""
    env_packages = set(env_packages)
    bad = []
    for module, imported in sorted(names.items()):
        top = module.split(".")[0]
        for name in imported:
            head = name.split(".")[0]
            if top == "talar_jax" and (head in OUTSIDE or is_concrete_env(name, env_packages)):
                bad.append(f"{module} -> {name}")
            if top == "envs" and (head in OUTSIDE or head == "talar_jax"):
                bad.append(f"{module} -> {name}")
    return bad


@pytest.fixture(scope="module")
def project():
    return project_graph()


def test_the_walk_sees_the_project(project):
    graph, _ = project
    assert {
        "talar_jax.talar",
        "talar_jax.language.instructions",
        "envs.clevr.env",
        "experiments.pipeline",
    } <= graph.keys()
    assert "benchmarks.env_sps" in graph
    assert not [m for m in graph if ".venv" in m or "__pycache__" in m]
    assert "talar_jax.language.instructions" in graph["talar_jax.language"]  # an edge to a submodule
    assert "envs.clevr" in graph["envs"]  # ``from envs import clevr``
    assert env_subpackages() >= {"clevr", "kitchen"}


def test_talar_jax_imports_no_concrete_env_and_no_experiment_code(project):
    _, names = project
    bad = [v for v in layering_violations(names, env_subpackages()) if v.startswith("talar_jax")]
    assert not bad, f"talar_jax may import envs and envs/<module>.py only, never an env package: {bad}"


def test_envs_import_nothing_of_talar_jax_or_experiments(project):
    _, names = project
    bad = [v for v in layering_violations(names, env_subpackages()) if v.startswith("envs")]
    assert not bad, f"envs must stay usable without talar_jax and the experiments: {bad}"


def test_no_import_cycles(project):
    graph, _ = project
    unexpected = [sorted(c) for c in cycles(graph) if c not in KNOWN_CYCLES]
    assert not unexpected, f"import cycles: {unexpected}"


def test_known_cycles_still_exist(project):
    """An entry of ``KNOWN_CYCLES`` that no longer loops is stale: a warning (not a failure, so that the change
    removing a cycle need not touch this file) asks to remove it."""
    graph, _ = project
    stale = [sorted(c) for c in KNOWN_CYCLES if c not in cycles(graph)]
    if stale:
        warnings.warn(f"these import cycles are gone; remove them from KNOWN_CYCLES: {stale}", stacklevel=1)


def test_the_third_env_package_imports_only_generic_envs_modules():
    """tests/point_env.py stands for a new env package: env, variants and instruction format need only ``envs``."""
    path = ROOT / "tests" / "point_env.py"
    names = imported_names(ast.parse(path.read_text(encoding="utf-8")), "tests.point_env", is_package=False)
    project = sorted(name for name in names if name.split(".")[0] in (*PACKAGES, "scripts", "tests"))
    assert project and all(name.split(".")[0] == "envs" for name in project), project
    assert not [name for name in project if is_concrete_env(name, env_subpackages())]


def _graph(sources: dict[str, str]) -> Graph:
    return build_graph({name: (text, name in {"pkg", "pkg.sub", "envs"}) for name, text in sources.items()})


def test_checker_on_a_synthetic_graph():
    """The graph builder, the cycle finder and the layering rules on tiny made-up modules."""
    sources = {
        "pkg": "from pkg.a import f\nfrom . import b\n",
        "pkg.a": "from pkg.b import g\n",
        "pkg.b": "import os\n",
        "pkg.sub": "",
        "pkg.sub.c": "from ..a import f\nfrom . import d\n",
        "pkg.sub.d": "def late():\n    from pkg.sub import c\n",
    }
    graph = _graph(sources)
    assert graph["pkg"] == {"pkg.a", "pkg.b"}
    assert graph["pkg.a"] == {"pkg.b"}
    assert graph["pkg.sub.c"] == {"pkg.a", "pkg.sub.d"}
    # a package importing its submodules, which import siblings, is no cycle; an import inside a function is seen
    assert cycles(graph) == [frozenset({"pkg.sub.c", "pkg.sub.d"})]

    # a submodule importing a name of its package's __init__ loops back
    looped = _graph({**sources, "pkg.b": "from pkg import f\n", "pkg.sub.d": ""})
    assert cycles(looped) == [frozenset({"pkg", "pkg.a", "pkg.b"})]
    # a type-checking import counts, and a module importing itself is a cycle
    typed = _graph(
        {
            "pkg": "",
            "pkg.a": "from pkg.b import g\n",
            "pkg.b": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg.a import f\n",
            "pkg.sub": "import pkg.sub\n",
        }
    )
    assert sorted(map(sorted, cycles(typed))) == [["pkg.a", "pkg.b"], ["pkg.sub"]]
    assert not cycles(_graph({"pkg": "", "pkg.a": "import pkg.b\n", "pkg.b": ""}))


def test_layering_rules_on_synthetic_imports():
    names = {
        "talar_jax.ok": ["envs", "envs.base", "envs.registry", "numpy"],
        "talar_jax.bad_env": ["envs.clevr.tasks"],
        "talar_jax.bad_future_env": ["envs.point"],
        "talar_jax.bad_experiment": ["experiments.recipes"],
        "talar_jax.bad_script": ["scripts.soak"],
        "envs.clevr.env": ["envs.base", "envs.clevr.tasks", "jax"],
        "envs.bad": ["talar_jax.language"],
        "envs.point.bad": ["experiments"],
    }
    assert layering_violations(names, {"clevr", "kitchen", "point"}) == [
        "envs.bad -> talar_jax.language",
        "envs.point.bad -> experiments",
        "talar_jax.bad_env -> envs.clevr.tasks",
        "talar_jax.bad_experiment -> experiments.recipes",
        "talar_jax.bad_future_env -> envs.point",
        "talar_jax.bad_script -> scripts.soak",
    ]
