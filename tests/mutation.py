"""Mutation testing of the runtime's claims with mutmut (not part of the CI run).

    pip install -e '.[test,mutation]'
    python tests/mutation.py codec laws      # or: all; --keep DIR keeps the work tree

mutmut expects the package under ``src/``; ctrlunit installs its top-level folders under
one namespace instead, so this script stages a copy (``src/ctrlunit/<package>``, the
tests), runs ``mutmut run`` there on the target's module with the target's tests, and
prints the score and every surviving mutant's diff. Only tests that run in this process
are used (mutmut switches mutants inside the process). The figures and the surviving
mutants, each killed by a test or explained, are in docs/measurements/.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
PACKAGES = ("kernels", "plant", "topology", "runtime", "bench")

TARGETS: dict[str, tuple[list[str], list[str]]] = {
    # target: (modules to mutate, tests that check them in-process)
    "codec": (["runtime/transport/codec.py"], ["tests/test_codec.py", "tests/test_validation.py",
                                    "tests/test_codec_contract.py"]),
    "laws": (["kernels/laws.py"], ["tests/test_law_oracles.py", "tests/test_engine.py",
                                   "tests/test_laws.py"]),
    "guard": (["runtime/central/silence.py", "runtime/central/silence_rule.py",
               "runtime/central/excuse.py", "runtime/central/late.py",
               "runtime/central/state_check.py", "runtime/central/overload.py"],
              ["tests/test_silence_arithmetic.py", "tests/test_silence_watch.py",
               "tests/test_excuses.py", "tests/test_late_data.py",
               "tests/test_guard.py", "tests/test_loopback.py",
                                             "tests/test_validation.py",
                                             "tests/test_silence_rule.py",
                                             "tests/test_foreseen2.py",
                                             "tests/test_late_compute.py",
                                             "tests/test_overload.py"]),
    "replay": (["runtime/recording/replay.py"],
               ["tests/test_replay_unit.py", "tests/test_overload.py", "tests/test_foreseen2.py",
                "tests/test_late.py"]),
    "pipeline": (["topology/pipeline.py"], ["tests/test_pipeline.py", "tests/test_schedule.py",
                                            "tests/test_loopback.py",
                                            "tests/test_pipeline_overlap.py"]),
    "peripheral": (["runtime/roles/peripheral.py"], ["tests/test_peripheral_role.py",
                                               "tests/test_validation.py",
                                               "tests/test_pipeline_overlap.py",
                                               "tests/test_loopback.py",
                                               "tests/test_late_compute.py",
                                             "tests/test_overload.py"]),
    "admission": (["runtime/launch/admission.py"], ["tests/test_admission_rules.py",
                                             "tests/test_admission.py"]),
}

MUTMUT = "3.8.1"
"""The mutmut these scores are measured with (pyproject's ``mutation`` extra pins it)."""


def stage(where: Path, modules: list[str], tests: list[str]) -> None:
    """A copy of the repository in the layout mutmut expects, configured for one target."""
    for pkg in PACKAGES:
        shutil.copytree(REPO / pkg, where / "src" / "ctrlunit" / pkg,
                        ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(REPO / "tests", where / "tests", ignore=shutil.ignore_patterns("__pycache__"))
    only = ", ".join(f'"src/ctrlunit/{m}"' for m in modules)
    sel = ", ".join(f'"{t}"' for t in tests if (REPO / t).exists())
    (where / "pyproject.toml").write_text(f"""
[tool.mutmut]
source_paths = ["src"]
only_mutate = [{only}]
pytest_add_cli_args_test_selection = [{sel}]
pytest_add_cli_args = ["-p", "no:cacheprovider", "-q", "-x"]
use_git_change_detection = false

[tool.pytest.ini_options]
pythonpath = ["src"]
markers = ["slow: long", "zenoh: starts Zenoh sessions and processes"]
addopts = "-m 'not slow'"
""")


def run(target: str, keep: Path | None) -> dict[str, int]:
    modules, tests = TARGETS[target]
    where = keep / target if keep else Path(tempfile.mkdtemp(prefix=f"mutation-{target}-"))
    if where.exists() and keep:
        shutil.rmtree(where)
    where.mkdir(parents=True, exist_ok=True)
    stage(where, modules, tests)
    # the mutated copy, for the commands below (pytest itself has pythonpath = src)
    env = dict(os.environ, PYTHONPATH=str(where / "mutants" / "src"))
    try:
        # not env: a PYTHONPATH entry that does not exist yet is cached as empty
        subprocess.run([sys.executable, "-m", "mutmut", "run", "--max-children", "2"],
                       cwd=where, check=False, timeout=3600,
                       stdout=subprocess.DEVNULL)
        res = subprocess.run([sys.executable, "-m", "mutmut", "results", "--all", "true"],
                             cwd=where, env=env, capture_output=True, text=True, timeout=600)
        counts: dict[str, int] = {}
        survivors = []
        for line in res.stdout.splitlines():
            m = re.match(r"\s*(\S+): (.+)$", line)
            if not m:
                continue
            status = m.group(2).strip()
            counts[status] = counts.get(status, 0) + 1
            if status == "survived":
                survivors.append(m.group(1))
        killed = counts.get("killed", 0) + counts.get("timeout", 0)
        total = sum(counts.values()) - counts.get("skipped", 0)
        print(f"\n== {target}: {', '.join(modules)}: {killed} of {total} mutants killed "
              f"({100.0 * killed / max(1, total):.1f} %); {counts}")
        for name in survivors:
            diff = subprocess.run([sys.executable, "-m", "mutmut", "show", name], cwd=where,
                                  env=env, capture_output=True, text=True, timeout=120)
            print(f"-- survived: {name}\n{diff.stdout.strip()}")
        return counts
    finally:
        if keep is None:
            shutil.rmtree(where, ignore_errors=True)


def main() -> None:
    from importlib.metadata import version

    if version("mutmut") != MUTMUT:
        raise SystemExit(f"mutmut {version('mutmut')} is installed; the scores are "
                         f"measured with {MUTMUT}: pip install -e '.[test,mutation]'")
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("targets", nargs="+", choices=[*TARGETS, "all"])
    ap.add_argument("--keep", type=Path, default=None, help="Keep the work trees in DIR.")
    args = ap.parse_args()
    for t in TARGETS if "all" in args.targets else args.targets:
        run(t, args.keep)


if __name__ == "__main__":
    main()
