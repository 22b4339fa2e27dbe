"""The one rule for reading a file a user names as input (a task, the parameters, a
placement, and the copies a recording keeps of them): a regular file of at most
:data:`MAX_FILE_BYTES`, in UTF-8, else refused by name before anything is read.

A FIFO given as ``--placement`` hung the start, and ``/dev/zero`` read until memory ran
out (docs/measurements/2026-11-29-reviews.md); a stat first keeps both from being opened
for reading at all.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

MAX_FILE_BYTES = 1 << 20
"""The largest input file read (1 MiB: a task of 256 segments takes a few kB)."""


def read_small_text(path: str | os.PathLike[str], *, whose: str,
                    error: type[Exception] = ValueError) -> str:
    """The text of ``path``.

    Parameters
    ----------
    whose
        How the file is named in an error, e.g. ``"task file run.json"``.
    error
        The exception raised (a caller's own ``ValueError`` subclass).

    Raises
    ------
    error
        ``"{whose}: <reason>"`` when the file cannot be read,
        ``"{whose} is not a regular file ..."``, ``"{whose} is larger than ..."`` or
        ``"{whose} is not UTF-8 text"``.
    """
    try:
        st = os.stat(path)
    except OSError as exc:
        raise error(f"{whose}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{whose} is not a regular file (a FIFO, a device, a folder, ...)")
    if st.st_size > MAX_FILE_BYTES:
        raise error(f"{whose} is larger than {MAX_FILE_BYTES} bytes ({st.st_size})")
    try:
        return Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise error(f"{whose} is not UTF-8 text") from None
    except OSError as exc:
        raise error(f"{whose}: {exc.strerror or exc}") from None


__all__ = ["MAX_FILE_BYTES", "read_small_text"]
