"""The runtime, the kernels, the topology and the plant type-check clean under mypy (the
version pinned in the test extra, the settings in pyproject.toml's ``[tool.mypy]``).

The packages install under the ``ctrlunit`` namespace from folders of other names, so
mypy reads them through a tree of links named as they are imported."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
CHECKED = ("runtime", "kernels", "topology", "plant")


def test_mypy_finds_no_error(tmp_path):
    pytest.importorskip("mypy")
    tree = tmp_path / "tree" / "ctrlunit"
    tree.mkdir(parents=True)
    for pkg in (*CHECKED, "bench"):  # the command line imports the benchmarks
        (tree / pkg).symlink_to(ROOT / pkg, target_is_directory=True)
    args = [a for pkg in CHECKED for a in ("-p", f"ctrlunit.{pkg}")]
    res = subprocess.run(
        [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"),
         "--cache-dir", str(tmp_path / "cache"), *args],
        cwd=tree.parent, env=os.environ | {"MYPYPATH": str(tree.parent)},
        capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "Success: no issues found" in res.stdout
