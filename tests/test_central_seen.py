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


RECORDS = ROOT / "runtime" / "central" / "records.py"
PHASE = {"round", "waiting", "handed_off", "started", "finishing", "dropped",
         "awaiting_sample", "gated", "late_ns", "deadline_ns"}
"""An interval's phase: the fields of ``InFlight`` (runtime/central/records.py) that say
where it stands in the pipeline (its times and its work are measurements)."""
MUTATORS = {"add", "discard", "remove", "clear", "update", "pop",
            "difference_update", "intersection_update", "symmetric_difference_update"}


def phase_writes(path: Path) -> list[str]:
    """Writes of an interval's phase in ``path`` other than an object's own (``self``):
    an assignment to one of :data:`PHASE`, or a call that changes one of its sets."""
    found = []
    for n in ast.walk(ast.parse(path.read_text())):
        if isinstance(n, ast.Attribute) and isinstance(n.ctx, ast.Store | ast.Del) \
                and n.attr in PHASE and not (isinstance(n.value, ast.Name)
                                             and n.value.id == "self"):
            found.append(f"{n.lineno}: {ast.unparse(n)}")
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) \
                and n.func.attr in MUTATORS and isinstance(n.func.value, ast.Attribute) \
                and n.func.value.attr in PHASE and not (
                    isinstance(n.func.value.value, ast.Name)
                    and n.func.value.value.id == "self"):
            found.append(f"{n.lineno}: {ast.unparse(n.func)}")
    return found


def test_only_the_interval_itself_changes_its_phase():
    """Issue 58: the interval's phase as one state machine. ``InFlight``'s own methods
    (``sent``, ``answered``, ``stood_in``, ``gate``, ``sampled``, ...) are its transitions;
    the pipeline (intervals.py), the replies, the late data and the take-over call them
    and assign none of its phase fields themselves."""
    mods = [p for pkg in ("runtime", "bench") for p in sorted((ROOT / pkg).rglob("*.py"))]
    bad = [f"{p.relative_to(ROOT)}:{w}" for p in mods for w in phase_writes(p)]
    assert not bad, "\n".join(bad)
    inflight = next(n for n in ast.parse(RECORDS.read_text()).body
                    if isinstance(n, ast.ClassDef) and n.name == "InFlight")
    fields = {s.target.id for s in inflight.body
              if isinstance(s, ast.AnnAssign) and isinstance(s.target, ast.Name)}
    assert PHASE <= fields, PHASE - fields  # the rule follows the record


def test_the_phase_rule_sees_a_write(tmp_path):
    mod = tmp_path / "m.py"
    mod.write_text("def f(f, g):\n    f.waiting = set()\n    g.dropped.add(1)\n"
                   "    f.finishing, x = True, 1\n    f.work_ns = 3\n    f.answered(1)\n"
                   "class C:\n    def m(self):\n        self.gated = True\n")
    assert sorted(phase_writes(mod)) == ["2: f.waiting", "3: g.dropped.add", "4: f.finishing"]
