"""The configuration a recording was made with, from the file alone.

A run reads three files beside its settings: a task (``--task FILE``), the robot's
parameters (``--params``) and a placement (``--placement``). The recorder keeps their
text in the metadata record ``ctrlunit.files``; ``report``, ``replay``, ``plot`` and
``export`` take them from there, never from the paths the recording names. They once
re-read those paths: a task file edited after the run made ``report`` give another
tracking error (51 mm where the run had 2.4 mm, "completed as planned") and ``replay
--verify`` diverge; a forged recording naming ``/dev/zero`` or a FIFO exhausted memory or
hung the reader. The settings that name the run's links and outputs (a Zenoh file, keys,
endpoints, files written) are not the reader's business and are dropped.

A recording made before the files were kept names paths only: each is read if it is a
regular file of at most :data:`MAX_FILE_BYTES`, else refused by name.
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
from pathlib import Path
from typing import Any, Final

from ...kernels.small_file import MAX_FILE_BYTES, read_small_text
from ...kernels.trajectory import TASKS
from ..config import RunConfig

FILES_RECORD: Final = "ctrlunit.files"
"""The metadata record holding the text of each file the run read, by setting name."""

FILE_FIELDS: Final = ("task", "params", "placement")
"""The settings that name a file the run's setup reads."""

LINKS_AND_OUTPUTS: Final[dict[str, Any]] = {
    "zenoh_config": None, "keys": None, "listen": [], "connect": [], "record": None,
    "report": None, "status_file": None, "foxglove": None, "ros2": None}
"""Settings a reader of the recording drops: the run's links and the files it wrote."""


def files_of(rc: RunConfig) -> dict[str, str]:
    """The text of each file ``rc``'s setup reads (a built-in task is no file), for the
    recorder; a file that cannot be read is left out (the run read it already)."""
    named = {"task": None if rc.control.task in TASKS else rc.control.task,
             "params": rc.control.params, "placement": rc.schedule.placement}
    out = {}
    for field, path in named.items():
        if path:
            try:
                out[field] = _read(path, field)
            except ValueError:
                continue
    return out


def run_config(rec: Any) -> RunConfig:
    """The run configuration of recording ``rec`` (:meth:`RunConfig.from_recording`),
    its files taken from the recording (module notes), its links and outputs dropped.

    Raises
    ------
    ValueError
        The configuration is not one (naming the field), or a file the recording names
        but does not hold is missing, not a regular file or larger than
        :data:`MAX_FILE_BYTES`.
    """
    data = dict(rec.config) | LINKS_AND_OUTPUTS
    held = rec.metadata.get(FILES_RECORD) or {}
    where: Path | None = None
    for field in FILE_FIELDS:
        value = data.get(field)
        if not isinstance(value, str) or not value or (field == "task" and value in TASKS):
            continue
        text = held.get(field)
        if text is None:  # recorded before the files were kept
            _read(value, field, recording=str(rec.path))
            continue
        if len(text) > MAX_FILE_BYTES:
            raise ValueError(f"{rec.path}: its {field} file ({FILES_RECORD}) is larger than "
                             f"{MAX_FILE_BYTES} bytes")
        where = where or _scratch()
        copy = where / f"{field}-{Path(value).name or field}"
        copy.write_text(text)
        data[field] = str(copy)
    return RunConfig.from_recording(data)


def _read(path: str, field: str, *, recording: str | None = None) -> str:
    whose = f"{recording}: the recording's {field} file {path}" if recording else \
        f"{field} file {path}"
    return read_small_text(path, whose=whose)


_SCRATCH: list[Path] = []


def _scratch() -> Path:
    """A private folder for the files of the recordings this process reads, removed at
    its exit."""
    if not _SCRATCH:
        _SCRATCH.append(Path(tempfile.mkdtemp(prefix="ctrlunit-recorded-")))
        atexit.register(shutil.rmtree, _SCRATCH[0], ignore_errors=True)
    return Path(tempfile.mkdtemp(dir=_SCRATCH[0]))


__all__ = ["FILES_RECORD", "FILE_FIELDS", "LINKS_AND_OUTPUTS", "MAX_FILE_BYTES", "files_of",
           "run_config"]
