"""The house stays readable (docs/architecture.md): no module over 400 lines, no function
over 80 (350 and 60 in the central's package), no class with more than 25 attributes, the
central composed of its parts rather than inheriting them, and tests that drive runtime
objects through what they expose.

Each limit is read from the source with ``ast``. The modules and functions that are over
a limit today are listed in :data:`OVER` with their size now: such an entry may shrink,
must not grow, and must leave the list once it is within the limit (so that the list
only ever gets shorter); anything over a limit that is not listed fails."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("kernels", "plant", "topology", "runtime", "bench")
MODULE_LINES, FUNCTION_LINES, CLASS_ATTRIBUTES = 400, 80, 25
PRIVATE_CALLS = 20

OVER: dict[str, int] = {
    # modules (lines) and functions (module:function, lines) still over their limit
}


def sources() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))


def class_attributes(node: ast.ClassDef) -> set[str]:
    """The names a class assigns on ``self`` in its methods, and its annotated fields
    (a dataclass's or a NamedTuple's)."""
    names = {st.target.id for st in node.body
             if isinstance(st, ast.AnnAssign) and isinstance(st.target, ast.Name)}
    for sub in ast.walk(node):
        if (isinstance(sub, ast.Attribute) and isinstance(sub.ctx, ast.Store)
                and isinstance(sub.value, ast.Name) and sub.value.id == "self"):
            names.add(sub.attr)
    return names


def sizes() -> dict[str, tuple[int, int]]:
    """Everything measured: name -> (size, limit). A function is named by its module and
    its qualified name (``records.py:InFlight.sampled``), so that two methods of one name
    in one module are both measured."""
    out: dict[str, tuple[int, int]] = {}

    def visit(node: ast.AST, rel: str, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                assert child.end_lineno is not None
                name = prefix + child.name
                out[f"{rel}:{name}"] = (child.end_lineno - child.lineno + 1, FUNCTION_LINES)
                visit(child, rel, name + ".")
            elif isinstance(child, ast.ClassDef):
                name = prefix + child.name
                out[f"{rel}:{name}"] = (len(class_attributes(child)), CLASS_ATTRIBUTES)
                visit(child, rel, name + ".")
            else:
                visit(child, rel, prefix)

    for path in sources():
        rel = path.relative_to(ROOT).as_posix()
        text = path.read_text()
        out[rel] = (len(text.splitlines()), MODULE_LINES)
        visit(ast.parse(text), rel, "")
    return out


def test_nothing_new_is_over_a_limit_and_nothing_listed_grew():
    measured = sizes()
    new = [f"{k}: {n} (limit {lim})" for k, (n, lim) in measured.items()
           if n > lim and k not in OVER]
    grew = [f"{k}: {measured[k][0]}, listed at {n}" for k, n in OVER.items()
            if k in measured and measured[k][0] > n]
    assert not new and not grew, "\n".join(new + grew)


def test_the_list_of_what_is_over_only_shrinks():
    """An entry within its limit now, or gone, leaves :data:`OVER`."""
    measured = sizes()
    stale = [k for k in OVER if k not in measured or measured[k][0] <= measured[k][1]]
    assert not stale, f"within the limit now, take off OVER: {stale}"


CENTRAL_MODULE_LINES, CENTRAL_FUNCTION_LINES = 350, 60
"""The central's own limits, under the house's: room for what it will take on (the
interval's phase, the modes) without meeting a wall."""


def test_the_central_package_is_within_every_limit():
    measured = {k: v for k, v in sizes().items() if k.startswith("runtime/central/")}
    functions = [k for k in measured if ":" in k and measured[k][1] == FUNCTION_LINES]
    assert len(functions) > 100  # the rule reads the package, methods by class included
    over = {k: n for k, (n, lim) in measured.items()
            if n > (CENTRAL_MODULE_LINES if ":" not in k
                    else CENTRAL_FUNCTION_LINES if k in functions else lim)}
    assert not over, over


def test_the_central_inherits_from_no_part_of_itself():
    tree = ast.parse((ROOT / "runtime" / "central" / "scheduler.py").read_text())
    central = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Central")
    assert central.bases == [] and len(class_attributes(central)) <= CLASS_ATTRIBUTES


def private_method_calls() -> list[str]:
    """Calls in tests of a ``_name`` method on an object that is neither the caller's own
    (``self``) nor a module the test imported (a module's private helper is a unit of
    its own), ``_replace`` (a named tuple's public API) aside."""
    found = []
    for path in sorted((ROOT / "tests").glob("*.py")):
        tree = ast.parse(path.read_text())
        modules = {a.asname or a.name.split(".")[0] for n in ast.walk(tree)
                   if isinstance(n, ast.Import) for a in n.names}
        modules |= {a.asname or a.name for n in ast.walk(tree)
                    if isinstance(n, ast.ImportFrom) for a in n.names
                    if a.name.islower() and (n.module or "").startswith("ctrlunit")}
        for n in ast.walk(tree):
            if not (isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute)):
                continue
            attr, recv = n.func.attr, n.func.value
            if not attr.startswith("_") or attr.startswith("__") or attr == "_replace":
                continue
            if isinstance(recv, ast.Name) and (recv.id == "self" or recv.id in modules):
                continue
            found.append(f"{path.name}:{n.lineno} {attr}")
    return found


def _callable_classes(root: Path) -> set[str]:
    """Classes of runtime/central/ that define ``__call__``."""
    return {c.name for p in (root / "runtime" / "central").glob("*.py")
            for c in ast.walk(ast.parse(p.read_text())) if isinstance(c, ast.ClassDef)
            and any(isinstance(f, ast.FunctionDef) and f.name == "__call__" for f in c.body)}


def central_parts(root: Path = ROOT, *, callable_only: bool = False) -> set[str]:
    """The names by which the central holds its parts: each ``self.<name> = Part(...)`` (or
    ``Part.of(...)``) in ``Central.__init__``, and each property of ``Central`` that hands
    out a part's collaborator (``return self.<part>.<attr>``, annotated with a class:
    ``engine``, ``ctl``); not the values it hands out (``done``, ``inflight``). With
    ``callable_only``, the parts that are called (their class defines ``__call__``)."""
    tree = ast.parse((root / "runtime" / "central" / "scheduler.py").read_text())
    central = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Central")
    names = set()
    for fn in central.body:
        if not isinstance(fn, ast.FunctionDef):
            continue
        for n in ast.walk(fn):
            if fn.name == "__init__" and isinstance(n, ast.Assign) \
                    and isinstance(n.value, ast.Call):
                f = n.value.func
                cls = f.value if isinstance(f, ast.Attribute) else f
                if isinstance(cls, ast.Name) and cls.id[:1].isupper() and (
                        not callable_only or cls.id in _callable_classes(root)):
                    names |= {t.attr for t in n.targets if isinstance(t, ast.Attribute)}
            if not callable_only and isinstance(n, ast.Return) \
                    and isinstance(n.value, ast.Attribute) \
                    and isinstance(n.value.value, ast.Attribute) and fn.decorator_list \
                    and isinstance(fn.returns, ast.Name) and fn.returns.id[:1].isupper() \
                    and fn.returns.id != "Any":
                names.add(fn.name)
    return names


def _of_central(part: ast.Attribute) -> bool:
    """Whether ``<obj>.<part>`` may be a central's part: not a value handed out
    (``c.snapshot().late``), not a test class's own (``self.log``)."""
    obj = part.value
    return not isinstance(obj, ast.Call) and not (isinstance(obj, ast.Name) and obj.id == "self")


def part_pokes(root: Path = ROOT) -> list[str]:
    """Where tests reach into one of the central's parts: every ``<obj>.<part>.<attr>``,
    read or written, and every call of a part (``c.rate(2, ...)``), ``<part>`` a name of
    :func:`central_parts` (``self.log.append`` in a test's own class is that class's;
    ``c.snapshot().late.computed`` is the snapshot's)."""
    parts, found = central_parts(root), []
    callable_parts = central_parts(root, callable_only=True)
    for path in sorted((root / "tests").glob("*.py")):
        for n in ast.walk(ast.parse(path.read_text())):
            if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Attribute) \
                    and n.value.attr in parts and _of_central(n.value):
                found.append(f"{path.name}:{n.lineno} .{n.value.attr}.{n.attr}")
            if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) \
                    and n.func.attr in callable_parts and _of_central(n.func):
                found.append(f"{path.name}:{n.lineno} .{n.func.attr}(")
    return found


def test_tests_seldom_call_private_methods_or_reach_into_the_centrals_parts():
    """Issue 58: tests drive the central through what it exposes (its snapshot, its events)
    and its parts on their own; at most :data:`PRIVATE_CALLS` places in all do otherwise."""
    found = private_method_calls() + part_pokes()
    assert len(found) <= PRIVATE_CALLS, "\n".join(found)


def test_the_central_s_parts_are_named_as_the_central_names_them():
    parts = central_parts()
    assert {"silence", "late", "intervals", "meters", "takeover", "ctl", "engine"} <= parts
    assert not parts & {"node", "rc", "on_cycle", "on_message",  # given, not its parts
                        "done", "inflight", "params"}  # values it hands out


@pytest.mark.parametrize("text, pokes", [
    ("c.silence.last_sample_ns = 3\n", 1),
    ("assert u.central.late.held == {1}\n", 1),
    ("x = c.ctl.stride + c.intervals.done\n", 2),
    ("c.rate(2, {})\nsetup.engine()\nnp.log(2)\n", 1),
    ("c.silence\nw.last_sample_ns\nc.check_silence(3)\nrc.schedule.late\n", 0),
    ("self.log.append(1)\nc.inflight.get(1)\nsetup.params.m\nc.snapshot().late.late\n", 0),
])
def test_the_part_counter_counts_what_it_should(tmp_path, text, pokes):
    for d in ("tests", "runtime/central"):
        (tmp_path / d).mkdir(parents=True)
    for p in (ROOT / "runtime" / "central").glob("*.py"):
        (tmp_path / "runtime" / "central" / p.name).write_text(p.read_text())
    (tmp_path / "tests" / "test_x.py").write_text(text)
    assert len(part_pokes(tmp_path)) == pokes


@pytest.mark.parametrize("text, calls", [
    ("c._check_late(1)\n", 1),
    ("self._next()\n", 0),
    ("from ctrlunit.runtime import replay\nreplay._nudge(1)\n", 0),
    ("t._replace(a=1)\n", 0),
])
def test_the_private_call_counter_counts_what_it_should(tmp_path, monkeypatch, text, calls):
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_x.py").write_text(text)
    monkeypatch.setitem(globals(), "ROOT", tmp_path)
    assert len(private_method_calls()) == calls


CLOCK_BRANCHES = 5
"""Issue 58: the clock chooses the central's parts once (its pace, sample source and
silence limits, and the settings derived from it), not a branch in every part."""


def _is_clock(node: ast.expr) -> bool:
    name = node.attr if isinstance(node, ast.Attribute) else getattr(node, "id", "")
    return name == "clock"


def clock_branches(root: Path = ROOT) -> list[str]:
    """Where runtime/central/ asks which clock the run has: a comparison of a clock
    (a name or attribute ``clock``) with anything, or a ``match`` on one."""
    found = []
    for path in sorted((root / "runtime" / "central").glob("*.py")):
        for n in ast.walk(ast.parse(path.read_text())):
            if (isinstance(n, ast.Compare) and any(map(_is_clock, [n.left, *n.comparators]))) \
                    or (isinstance(n, ast.Match) and _is_clock(n.subject)):
                found.append(f"{path.name}:{n.lineno}")
    return found


def test_the_clock_is_asked_in_few_places():
    found = clock_branches()
    assert len(found) <= CLOCK_BRANCHES, found


@pytest.mark.parametrize("text, branches", [
    ("if settings.clock == 'realtime':\n    pass\n", 1),
    ("x = 'freerun' != clock\n", 1),
    ("match rc.clock:\n    case 'lockstep':\n        pass\n", 1),
    ("if realtime:\n    pass\nx = settings.clock\n", 0),
])
def test_the_clock_branch_counter_counts_what_it_should(tmp_path, text, branches):
    (tmp_path / "runtime" / "central").mkdir(parents=True)
    (tmp_path / "runtime" / "central" / "x.py").write_text(text)
    assert len(clock_branches(tmp_path)) == branches
