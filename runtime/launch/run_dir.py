"""The run directory of one ``ctrlunit start``: the spec its roles read, the central's
local socket and each role's log, in a private folder ``ctrlunit-XXXXXXXX`` of the
temporary directory (mode 0700, as :func:`tempfile.mkdtemp` makes it).

The launcher removes it at the end, or keeps it for the diagnosis of a fault (the summary
names it). A launcher ended by SIGKILL can do neither, so each directory names its
launcher (:data:`OWNER`: its process id and start time), and every start first removes
the directories of this user whose launcher is gone. A directory kept on purpose no
longer names one, and stays until the user deletes it. The launcher's file is written
whole before it takes its name, so a SIGKILL never leaves it empty or half written (an
empty one read as no owner, and the directory stayed for good); a SIGKILL in the moment
between making the directory and naming the file still leaves it, as if kept.
"""

from __future__ import annotations

import os
import re
import shutil
import stat
import tempfile
from pathlib import Path

PREFIX = "ctrlunit-"
OWNER = "launcher.pid"
"""The file naming the launcher that owns a run directory: ``PID START_TIME``."""


def _started(pid: int) -> str | None:
    """Process ``pid``'s start time (clock ticks since boot, ``/proc/PID/stat`` field 22),
    or None if there is no such process: with the pid, it names one process for good."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rfind(")") + 2:].split()  # after the command's name
    return fields[19] if len(fields) > 19 else None


NAME = re.compile(rf"^{PREFIX}[a-z0-9_]{{8}}$")
"""A run directory's name as :func:`tempfile.mkdtemp` makes it."""

CONTENTS = re.compile(
    r"^(spec\.json|(central|view)\.sock(\.lock)?|[a-z0-9-]+\.log|launcher\.pid(\.part)?)$")
"""What a run directory holds; one holding anything else (a folder, other files) is not
removed, whatever its launcher file says."""


def _owner_gone(d: Path) -> bool:
    """Whether ``d`` is a run directory of this user whose launcher has ended: named and
    made as :func:`make_run_dir` makes one (mode 0700), holding only what a run writes
    (:data:`CONTENTS`, no folder). False for anything else: another user's, a link, a
    folder of the user's own that happens to be named alike, one kept on purpose, one
    being made."""
    try:
        st = d.lstat()
        if (not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or not NAME.match(d.name)
                or stat.S_IMODE(st.st_mode) != 0o700):
            return False
        if not all(CONTENTS.match(e.name) and not e.is_dir(follow_symlinks=False)
                   for e in os.scandir(d)):
            return False
        owner = d / OWNER
        if not stat.S_ISREG(owner.lstat().st_mode):
            return False
        with owner.open() as fh:
            pid, started = fh.read(64).split()
        return _started(int(pid)) != started
    except (OSError, ValueError):
        return False


def sweep(root: str | Path | None = None) -> list[Path]:
    """Remove the run directories under ``root`` (the temporary directory) whose launcher
    has ended without removing them; returns them."""
    gone = [d for d in Path(root or tempfile.gettempdir()).glob(f"{PREFIX}*") if _owner_gone(d)]
    for d in gone:
        shutil.rmtree(d, ignore_errors=True)
    return gone


def make_run_dir(root: str | Path | None = None) -> Path:
    """A new run directory owned by this process, after :func:`sweep`."""
    sweep(root)
    d = Path(tempfile.mkdtemp(prefix=PREFIX, dir=root))
    part = d / f"{OWNER}.part"  # written whole, then renamed: never seen empty or half
    part.write_text(f"{os.getpid()} {_started(os.getpid())}")
    part.rename(d / OWNER)
    return d


def keep(d: Path) -> None:
    """Keep ``d`` for the user: no sweep removes it."""
    (d / OWNER).unlink(missing_ok=True)


__all__ = ["OWNER", "keep", "make_run_dir", "sweep"]
