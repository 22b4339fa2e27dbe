"""Nothing outside runtime/central/ reads or writes a part of the central: the report, the
recorder, the views, the admission, the launcher and the benchmarks see the central
through what it hands out (runtime/central/snapshot.py) and its own methods
(docs/architecture.md, "The central seen from outside").

Read from the source with ``ast``: a part is whatever ``Central.__init__`` assigns to
``self`` (the run configuration and the hooks it was given aside), or a property of
``Central`` that returns one; a reach into one is ``<central>.<part>`` where
``<central>`` is a name or attribute called as :data:`CENTRAL_NAMES` says
(``central``, ``u.central``, ``self._central``, ``probe``, ...)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCHEDULER = ROOT / "runtime" / "central" / "scheduler.py"
GIVEN = {"rc", "on_cycle", "on_message"}
"""What ``Central`` keeps of what it was given: values, not parts."""
PART_PROPERTIES = {"engine", "ctl", "inflight"}
"""``Central``'s properties that hand out a part."""


def parts() -> set[str]:
    tree = ast.parse(SCHEDULER.read_text())
    central = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Central")
    init = next(n for n in central.body if isinstance(n, ast.FunctionDef)
                and n.name == "__init__")
    names = {t.attr for n in ast.walk(init) if isinstance(n, ast.Assign) for t in n.targets
             if isinstance(t, ast.Attribute) and isinstance(t.value, ast.Name)
             and t.value.id == "self"}
    return (names - GIVEN) | PART_PROPERTIES


CENTRAL_NAMES = {"central", "_central", "probe"}
"""What a central is called outside: the run's, a view's copy, the admission's trial's."""


def is_central(node: ast.AST) -> bool:
    return (isinstance(node, ast.Name) and node.id in CENTRAL_NAMES) or (
        isinstance(node, ast.Attribute) and node.attr in CENTRAL_NAMES)


def reaches(path: Path, part_names: set[str]) -> list[str]:
    """``central.<part>`` in ``path``, as ``"LINE: central.PART"``."""
    tree = ast.parse(path.read_text())
    return [f"{n.lineno}: central.{n.attr}" for n in ast.walk(tree)
            if isinstance(n, ast.Attribute) and n.attr in part_names and is_central(n.value)]


def outside() -> list[Path]:
    mods = [p for pkg in ("runtime", "bench", "kernels", "plant", "topology")
            for p in sorted((ROOT / pkg).rglob("*.py"))]
    return [p for p in mods if ROOT / "runtime" / "central" not in p.parents]


def test_the_parts_are_found():
    found = parts()
    assert {"meters", "log", "orders", "warmup", "silence", "takeover", "intervals",
            "node", "settings", "engine"} <= found
    assert not found & GIVEN


def test_nothing_outside_the_central_reaches_into_its_parts():
    found = parts()
    bad = [f"{p.relative_to(ROOT)}:{r}" for p in outside() for r in reaches(p, found)]
    assert not bad, "\n".join(bad)


def test_the_rule_sees_a_reach(tmp_path):
    """The check itself: reading a part, binding one and writing through one are each
    caught; the run configuration is not a part."""
    mod = tmp_path / "m.py"
    mod.write_text("def f(central, u):\n    m = central.meters\n"
                   "    u.central.meters.t_end_ns = 1\n"
                   "    return central.log.digest, central.rc, central.snapshot()\n")
    assert sorted(reaches(mod, parts())) == ["2: central.meters", "3: central.meters",
                                             "4: central.log"]
