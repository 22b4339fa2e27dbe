"""Where a run writes its files (``--record``, ``--report``): checked before anything
starts, so that a run is not made only to lose what it measured at its end."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any


def output_file_error(path: str | None, option: str) -> str | None:
    """Why no file can be written at ``path``, naming ``option`` (its directory does not
    exist, is not a directory or is not writable; the path is a directory, a device, a
    pipe, a socket, a file of /proc or /sys, or a link to nothing), or None if one can
    (or ``path`` is None: nothing to write)."""
    if path is None:
        return None
    p = Path(path).expanduser()
    parent = p.parent
    if p.is_symlink() and not p.exists():  # writing would make its target
        return (f"{option}: {path} is a symbolic link to {os.readlink(p)}, which does not "
                "exist: give the file itself")
    if p.is_dir():
        return f"{option}: {path} is a directory: give a file name in it"
    if p.exists() and not p.is_file():
        return f"{option}: {path} is not a regular file (a device, a pipe or a socket)"
    if p.resolve().parts[1:2] in (("proc",), ("sys",)):
        return f"{option}: {path} is a kernel interface file, not a file to write a run to"
    if not parent.exists():
        return f"{option}: {path}: the directory {parent} does not exist (make it first)"
    if not parent.is_dir():
        return f"{option}: {path}: {parent} is not a directory"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"{option}: {path}: the directory {parent} is not writable"
    return None


def central_output_error(run: Any, listen: list[str] | None) -> str | None:
    """Why the central cannot write its files (``--record``, ``--report``:
    :func:`output_file_error`) or listen on its unix sockets (something is at the path:
    runtime/transport/endpoints.py, ``socket_path_taken``), or None."""
    for name in ("record", "report"):
        if (why := output_file_error(getattr(run, name), f"--{name}")):
            return why
    if run.record and run.report and Path(run.record).resolve() == Path(run.report).resolve():
        return (f"--record and --report: both are {run.report}: the report would overwrite "
                "the recording; give two files")
    from ..transport.endpoints import is_socket, socket_path_taken

    for e in listen or []:
        if is_socket(e) and (why := socket_path_taken(e)):
            return f"--listen {e}: {why}"
    return None


def view_error(foxglove: str | None, *, insecure: bool,
               parse: Callable[..., tuple[str, int]]) -> str | None:
    """Why ``--foxglove [HOST:]PORT`` will not do: a host other programs on other hosts
    reach, without ``--insecure`` (the view carries the samples, commands and positions,
    with no key: the link rule of runtime/transport/security.py); None if it will.
    ``parse``: the package's ``parse_host_port``, which raises ConfigError for a value
    that is no ``[HOST:]PORT``."""
    if foxglove is None:
        return None
    from ..transport.security import reaches_beyond_host

    host, _ = parse(foxglove, field_name="--foxglove")
    if insecure or not reaches_beyond_host(f"tcp/{host}:1" if ":" not in host
                                           else f"tcp/[{host}]:1"):
        return None
    return (f"--foxglove {foxglove}: other hosts can reach the live view, which carries the "
            "samples, commands and positions with no key; serve it on 127.0.0.1 (and "
            "forward it, e.g. ssh -L), or --insecure for a lab bench")


__all__ = ["central_output_error", "output_file_error", "view_error"]
