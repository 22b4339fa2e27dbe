"""The layers of docs/architecture.md hold: each package imports only the ones below it,
only the command line imports the benchmarks, and the runtime has no import cycle.

Every import counts, those inside functions too (a deferred import is still a
dependency), read from the source with ``ast``; imports under ``if TYPE_CHECKING:`` do
not (they exist for annotations only)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("kernels", "plant", "topology", "runtime", "bench")


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return "ctrlunit." + ".".join(parts)


def imports_of(path: Path) -> set[str]:
    """The ``ctrlunit`` modules ``path`` imports, with relative imports resolved."""
    mod = module_name(path)
    package = mod if path.name == "__init__.py" else mod.rsplit(".", 1)[0]
    out: set[str] = set()
    tree = ast.parse(path.read_text())
    typing_only = {id(n) for top in ast.walk(tree) if isinstance(top, ast.If)
                   and getattr(top.test, "id", None) == "TYPE_CHECKING"
                   for n in ast.walk(top)}  # annotations only: no dependency at run time
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.startswith("ctrlunit."))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if not target.startswith("ctrlunit."):
                continue
            # "from . import x" and "from .pkg import mod" may name modules
            for a in node.names:
                sub = f"{target}.{a.name}"
                out.add(sub if (ROOT / Path(*sub.split(".")[1:])).with_suffix(".py").exists()
                        or (ROOT / Path(*sub.split(".")[1:]) / "__init__.py").exists()
                        else target)
    return out


def graph() -> dict[str, set[str]]:
    g = {}
    for pkg in PACKAGES:
        for path in (ROOT / pkg).rglob("*.py"):
            g[module_name(path)] = imports_of(path)
    return g


def layer(mod: str) -> str:
    return mod.split(".")[1]


ALLOWED = {
    "kernels": {"kernels"},
    "plant": {"plant"},  # and kernels.params, below
    "topology": {"topology", "kernels"},
    "runtime": {"runtime", "topology", "kernels", "plant"},
    "bench": set(PACKAGES),
}


@pytest.mark.parametrize("pkg", PACKAGES)
def test_each_package_imports_only_the_layers_below_it(pkg):
    bad = []
    for mod, deps in graph().items():
        if layer(mod) != pkg:
            continue
        for d in deps:
            ok = layer(d) in ALLOWED[pkg] or (pkg == "plant" and d == "ctrlunit.kernels.params")
            if layer(d) == "bench" and mod.startswith("ctrlunit.runtime.cli"):
                ok = True  # the command line is the one place that runs the benchmarks
            if not ok:
                bad.append(f"{mod} -> {d}")
    assert not bad, "\n".join(sorted(bad))


def test_the_runtime_has_no_import_cycle():
    g = {m: {d for d in deps if layer(d) == "runtime" and d != m}
         for m, deps in graph().items() if layer(m) == "runtime"}
    # Tarjan's strongly connected components
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    cycles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in g.get(v, ()):
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

    for v in sorted(g):
        if v not in index:
            visit(v)
    assert not cycles, "import cycles: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_the_checker_sees_a_violation():
    """The rules above are only as good as the import reader: it must find a deferred,
    relative import of another layer."""
    deps = imports_of(ROOT / "runtime" / "central" / "state_check.py")  # dynamics: deferred
    assert "ctrlunit.kernels.dynamics" in deps and "ctrlunit.runtime.config" in deps


RUNTIME_ORDER = ("transport", "host", "config", "compute", "observe", "roles", "central",
                 "recording", "launch", "cli")
"""The runtime's packages, each importing only those before it (docs/architecture.md)."""


def runtime_package(mod: str) -> str | None:
    parts = mod.split(".")
    return parts[2] if len(parts) > 2 and parts[1] == "runtime" else None


def test_the_runtime_is_in_packages_and_each_imports_only_those_before_it():
    flat = sorted(p.name for p in (ROOT / "runtime").glob("*.py") if p.name != "__init__.py")
    assert not flat, f"modules outside the runtime's packages: {flat}"
    assert {p.name for p in (ROOT / "runtime").iterdir() if p.is_dir()
            and (p / "__init__.py").exists()} == set(RUNTIME_ORDER)
    bad = []
    for mod, deps in graph().items():
        here = runtime_package(mod)
        if here is None:
            continue
        for d in deps:
            there = runtime_package(d)
            if there is not None and RUNTIME_ORDER.index(there) > RUNTIME_ORDER.index(here):
                bad.append(f"{mod} -> {d}")
    assert not bad, "\n".join(sorted(bad))
