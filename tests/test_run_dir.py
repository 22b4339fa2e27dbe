"""What the sweep of run directories removes (runtime/launch/run_dir.py): only a run
directory as ``ctrlunit start`` makes one, of this user, whose launcher has ended. An
attacker's review had it remove a user's own ``ctrlunit-mydata01`` (photos and all) that
held a ``launcher.pid`` naming a dead process."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from ctrlunit.runtime.launch.run_dir import OWNER, keep, make_run_dir, sweep


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def _run_dir(root: Path, name: str, *, pid: int, started: str = "1", mode: int = 0o700,
             extra: tuple[str, ...] = ()) -> Path:
    d = root / name
    d.mkdir(mode=mode)
    d.chmod(mode)
    for f in ("spec.json", "plant.log", "peripheral-1.log", *extra):
        (d / f).write_text("x")
    (d / OWNER).write_text(f"{pid} {started}")
    return d


def test_only_a_run_directory_whose_launcher_ended_is_removed(tmp_path):
    alive = make_run_dir(tmp_path)  # this process's own (made first: it sweeps too)
    kept = make_run_dir(tmp_path)
    keep(kept)  # a fault's logs, kept for the user
    dead = _dead_pid()
    stale = _run_dir(tmp_path, "ctrlunit-abc_1234", pid=dead)
    photos = _run_dir(tmp_path, "ctrlunit-mydata01", pid=dead)  # not mkdtemp's name
    (photos / "photos").mkdir()
    folder = _run_dir(tmp_path, "ctrlunit-abcd1234", pid=dead)  # a folder inside
    (folder / "photos").mkdir()
    other = _run_dir(tmp_path, "ctrlunit-zzzz9999", pid=dead, extra=("notes.txt",))
    shared = _run_dir(tmp_path, "ctrlunit-mode0755", pid=dead, mode=0o755)
    link = tmp_path / "ctrlunit-link0000"
    link.symlink_to(stale)
    assert sweep(tmp_path) == [stale]
    assert not stale.exists() and link.is_symlink()
    for d in (photos, folder, other, shared, alive, kept):
        assert d.is_dir(), d
    assert (photos / "photos").is_dir()


def test_a_reused_pid_does_not_keep_a_directory(tmp_path):
    """The launcher file names the process by its pid and start time: a pid now used by
    another process (here this one, with another start time) is a launcher gone."""
    reused = _run_dir(tmp_path, "ctrlunit-reused00", pid=os.getpid(), started="1")
    assert sweep(tmp_path) == [reused]


def test_the_launchers_file_is_never_seen_half_written(tmp_path, monkeypatch):
    """``launcher.pid`` is written under another name and renamed: a SIGKILL between
    creating it and writing it (a review found an empty one, which no sweep removed) now
    leaves ``launcher.pid.part`` at worst, and the file that takes the name is whole."""
    import ctrlunit.runtime.launch.run_dir as run_dir

    made: list[str] = []
    real = Path.write_text

    def watch(self: Path, text: str, *a: object, **k: object) -> int:
        made.append(self.name)
        assert not (self.parent / OWNER).exists()  # the name comes after the writing
        return real(self, text, *a, **k)

    monkeypatch.setattr(Path, "write_text", watch)
    d = run_dir.make_run_dir(tmp_path)
    assert made == [f"{OWNER}.part"]
    assert sorted(p.name for p in d.iterdir()) == [OWNER]
    pid, started = (d / OWNER).read_text().split()
    assert int(pid) == os.getpid() and started
