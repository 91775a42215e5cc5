"""The layers of the library, read from the source with ``ast`` (every import counts,
including those inside functions; imports under ``if TYPE_CHECKING:`` count for the
layer rules, not for cycles, since they never run).

plants / lines / trains → mpc engine → controllers → scenarios → runner → envs →
(reproductions, CLI) → tuners → agents.  Nothing imports upward and there is no
import cycle between modules; the layers above train_envs add their subcommands and
reproductions through entry points, not imports.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("train_envs", "tuners", "agents")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
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


def _resolve(name: str) -> str | None:
    """The library module ``name`` refers to (its longest existing prefix), or None."""
    parts = name.split(".")
    while parts:
        cand = ".".join(parts)
        if cand in MODULES:
            return cand
        parts.pop()
    return None


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(mod: str, runtime_only: bool = False) -> set[str]:
    """Library modules ``mod`` imports; ``runtime_only`` leaves out the imports under
    ``if TYPE_CHECKING:`` (annotations only, never executed)."""
    path = MODULES[mod]
    tree = ast.parse(path.read_text(), str(path))
    is_pkg = path.name == "__init__.py"
    out: set[str] = set()
    typing_only = {
        id(n)
        for block in ast.walk(tree)
        if isinstance(block, ast.If) and _is_type_checking(block.test)
        for stmt in block.body
        for n in ast.walk(stmt)
    }
    for node in ast.walk(tree):
        if runtime_only and id(node) in typing_only:
            continue
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = mod.split(".")
                anchor = anchor if is_pkg else anchor[:-1]
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            # ``from pkg import submodule`` imports the submodule
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base
                       for a in node.names]
        else:
            continue
        for t in targets:
            r = _resolve(t)
            if r is not None and r != mod:
                out.add(r)
    return out


GRAPH = {m: _imports(m) for m in MODULES}
#: the graph of executed imports (what can form an import cycle)
RUNTIME = {m: _imports(m, runtime_only=True) for m in MODULES}


def _under(mod: str, prefix: str) -> bool:
    return mod == prefix or mod.startswith(prefix + ".")


#: (importer prefix, forbidden imported prefixes)
RULES = [
    ("train_envs", ("tuners", "agents")),
    ("tuners", ("agents",)),
    *[
        (base, ("train_envs.mpc", "train_envs.controllers", "train_envs.scenarios",
                "train_envs.simulation", "train_envs.envs"))
        for base in ("train_envs.plants", "train_envs.lines", "train_envs.trains")
    ],
    ("train_envs.mpc", ("train_envs.trains", "train_envs.lines", "train_envs.controllers",
                        "train_envs.scenarios", "train_envs.simulation", "train_envs.envs")),
    ("train_envs.controllers", ("train_envs.scenarios", "train_envs.simulation",
                                "train_envs.envs", "train_envs.reproduce")),
    ("train_envs.simulation", ("train_envs.envs", "train_envs.reproduce")),
]


@pytest.mark.parametrize("importer,forbidden", RULES, ids=[r[0] for r in RULES])
def test_nothing_imports_upward(importer, forbidden):
    bad = sorted(
        f"{m} -> {t}"
        for m, targets in GRAPH.items()
        if _under(m, importer)
        for t in targets
        if any(_under(t, f) for f in forbidden)
    )
    assert not bad, "upward imports:\n" + "\n".join(bad)


def test_no_import_cycle():
    # Tarjan's strongly connected components over the module graph
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    cycles: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(RUNTIME[v]):
            if w not in index:
                visit(w)
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
                cycles.append(sorted(comp))

    for v in sorted(RUNTIME):
        if v not in index:
            visit(v)
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_the_graph_sees_the_library():
    assert "train_envs.simulation" in GRAPH["train_envs.envs.train_env"]
