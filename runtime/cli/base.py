"""The ``ctrlunit`` command group and what its commands share: the error and output
helpers, the file arguments and the ``--params`` option.

Every command prints a human summary, or JSON on stdout with ``--json``; warnings and
notes go to stderr (``ctrlunit: warning: ...``); errors are one line on stderr
(``ctrlunit: error: ...``) with the exit code of their class, the same for every command
(docs/faults-and-errors.md): 2 for a command line that does not parse (click's usage
error), 1 for input the command refuses, a file that is missing or unreadable among it.
"""

from __future__ import annotations

import json
import math
import os
import stat
import sys
from typing import Any

import click
import numpy as np

from ...kernels.params import DELTA_IA, DeltaParams, load_params


def _params(path: str | None) -> DeltaParams:
    return DELTA_IA if path is None else load_params(path)


def one_line(text: str) -> str:
    """``text`` with its line breaks and other unprintable characters escaped (``\\r``),
    so that an error quoting a user's value stays one line."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def _fail(msg: str, code: int = 1) -> None:
    click.echo(f"ctrlunit: error: {one_line(msg)}", err=True)
    sys.exit(code)


def warn(msg: str) -> None:
    """A warning: one line on stderr, so that stdout holds only the answer."""
    click.echo(f"ctrlunit: warning: {one_line(msg)}", err=True)


def exit_line(f: dict[str, Any], code: int, *, as_json: bool) -> str:
    """stderr's line for a run that did not end normally. The summary on stdout has the
    whole message; stderr gives a fault's first clause (its whole message with
    ``--json``). A refusal names what was refused and
    what to try either way (stdout may go to a file)."""
    if f.get("process") == "user":
        return f"ctrlunit: stopped on request: {f.get('message')} (exit {code})"
    if f.get("process") == "admission":
        if as_json:
            return f"ctrlunit: refused before any motion: {f.get('message')} (exit {code})"
        advice = f" {f['advice']}" if f.get("advice") else ""
        return (f"ctrlunit: refused before any motion: {f.get('headline') or f.get('message')}"
                f" (exit {code}).{advice}")
    message = str(f.get("message") or "")
    if not as_json:  # its first clause: what happened (the figures are the summary's)
        message = one_line(message).split(";")[0]
        message = message if len(message) <= 160 else message[:157] + "..."
    return (f"ctrlunit: fault in {f.get('process')}" + (f": {message}" if message else "")
            + f" (exit {code})")


class FilePath(click.Path):
    """:class:`click.Path` whose refusal (a file that does not exist, a directory given
    for a file or the reverse, no permission) is an input error, exit 1 like any other
    file the commands cannot read, rather than click's usage error (exit 2)."""

    def convert(self, value: Any, param: click.Parameter | None,
                ctx: click.Context | None) -> Any:
        """As click's, and a file that exists must be a regular one: a FIFO would hang the
        command and a device (/dev/zero) fill its memory (``--config /dev/zero`` did)."""
        path = super().convert(value, param, ctx)
        if not self.dir_okay and os.path.exists(path) and not stat.S_ISREG(
                os.stat(path).st_mode):
            self.fail(f"{path!r} is not a regular file (a FIFO, a device, ...)", param, ctx)
        if os.path.islink(path) and not os.path.exists(path):  # a write would follow it
            self.fail(f"{path!r} is a symbolic link to {os.readlink(str(path))!r}, which does not "
                      "exist: give the file itself", param, ctx)
        return path

    def fail(self, message: str, param: click.Parameter | None = None,
             ctx: click.Context | None = None) -> Any:
        from ..config import ConfigError

        where = (param.opts[0] if isinstance(param, click.Option) and param.opts
                 else param.human_readable_name if param is not None else "path")
        text = message.rstrip(".")
        raise ConfigError(f"{where}: {text[:1].lower()}{text[1:]}")


class FiniteRange(click.FloatRange):
    """:class:`click.FloatRange` that refuses NaN (which compares with no bound, and so
    passed every range: ``replay --rate nan`` replayed unpaced)."""

    def convert(self, value: Any, param: click.Parameter | None,
                ctx: click.Context | None) -> Any:
        x = super().convert(value, param, ctx)
        if x != x:
            self.fail(f"{value!r} is not a number in the range {self._describe_range()}",
                      param, ctx)
        return x


def _rt_priority(_ctx: Any, _param: click.Parameter, value: str | int) -> str | int:
    """``--rt-priority``: ``auto`` or a priority 0-99 (runtime/host/sched.py)."""
    from ..host.sched import AUTO, check_priority

    text = str(value).strip()
    priority: str | int = AUTO if text == AUTO else (
        int(text) if text.lstrip("-").isdigit() else text)
    try:
        check_priority(priority)
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from None
    return priority


def _emit(data: dict[str, Any], as_json: bool, text: str) -> None:
    if as_json:
        click.echo(json.dumps(_json_safe(data)))
    else:
        click.echo(text)


def _json_safe(x: Any) -> Any:
    """Map NaN/inf to None and numpy types to Python ones, recursively."""
    if isinstance(x, dict):
        return {str(k): _json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_json_safe(v) for v in x]
    if isinstance(x, np.ndarray):
        return _json_safe(x.tolist())
    if isinstance(x, np.generic):
        return _json_safe(x.item())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


params_option = click.option(
    "--params", "params_file", type=FilePath(dir_okay=False), default=None,
    help="TOML file of Delta parameters (default: the Delta-IA of the thesis).",
)


class _Group(click.Group):
    """The group: a configuration error no command caught itself, a value click refused
    (its type, choices or range), or a file the system refused to read or write, is one
    line on stderr and exit 1, never a traceback (a command line that does not parse, an
    unknown option or a missing argument, stays click's usage error, exit 2); Ctrl-C (or
    SIGTERM / SIGHUP where the command listens for them) one line and exit 130 (143,
    129)."""

    def invoke(self, ctx: click.Context) -> Any:
        from ..compute.blocks import ObserverDiverged
        from ..config import EXIT_CONFIG, ConfigError
        from ..roles.stopping import stop_of

        try:
            return super().invoke(ctx)
        except click.MissingParameter:
            raise
        except click.BadParameter as exc:  # a value, as --set and a run file refuse one
            _fail(exc.format_message(), EXIT_CONFIG)
        except ConfigError as exc:
            _fail(str(exc), EXIT_CONFIG)
        except ObserverDiverged as exc:  # a recording whose samples were damaged
            _fail(f"the input's samples lead the observer nowhere ({exc}): a damaged "
                  "recording?", EXIT_CONFIG)
        except RecursionError:  # a file of a thousand nested lists, tables or objects
            _fail("an input file is nested too deeply to be read", EXIT_CONFIG)
        except UnicodeDecodeError as exc:
            _fail(f"an input file is not UTF-8 text ({exc.reason} at byte {exc.start})",
                  EXIT_CONFIG)
        except OSError as exc:  # a file or folder the system refused (not where asked)
            where = f"{exc.filename}: " if exc.filename is not None else ""
            _fail(f"{where}{exc.strerror or exc}", EXIT_CONFIG)
        except KeyboardInterrupt as exc:
            code, fault = stop_of(exc)
            click.echo(f"ctrlunit: {fault['message']}", err=True)
            sys.exit(code)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="ctrlunit")
def cli() -> None:
    """ctrlunit: a distributed, model-based control unit for fast parallel robots."""


NUMERIC = {"ignore_unknown_options": True}  # so that -0.35 is a number, not an option


def kept_note(report: dict[str, Any]) -> str:
    """Where the run directory of a faulted run was kept (its spec and the roles' logs),
    as the end of a line."""
    kept = report.get("logs_kept")
    return f"; the roles' logs are kept in {kept}" if kept else ""
