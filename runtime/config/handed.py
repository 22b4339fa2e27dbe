"""The unit's configuration handed to a role started by hand (``ctrlunit plant``,
``ctrlunit peripheral --index K``, on this host or another): the central sends it at the
handshake (runtime/central/orders.py, ``config``), so such a role needs only its unit id,
where to connect and its keys.

The role keeps its own :data:`ROLE_OWN` settings (its endpoints, credentials and CPUs)
and takes every other one from the central's configuration. A file that configuration
names (:data:`FILE_SETTINGS`: a task file, the robot's parameters, a placement) is read
on the role's own host: at the path the role was given, else at the central's, and its
contents must be the central's (their SHA-256 travels with the configuration).
"""

from __future__ import annotations

import hashlib
import os
from typing import Any

from ..transport.codec import MAX_STR_BYTES
from ..transport.endpoints import is_socket
from . import FLAT, ConfigError, RunConfig
from .sections import SECTIONS

ROLE_OWN = frozenset({"unit", "listen", "connect", "zenoh_config", "keys", "insecure",
                      "startup_timeout", "pin", "status_file", "max_message_size",
                      "max_sessions", "accept_pending", "accept_timeout"})
"""Settings by flat name that a role started by hand keeps from its own command line:
which unit, how it reaches the central, its credentials, what its own Zenoh accepts
from its links and its host's CPUs."""

FILE_SETTINGS = ("task", "params", "placement")
"""Settings by flat name that may name a file on the host that reads them."""

CENTRAL_ONLY = frozenset({"record", "report", "foxglove", "reject_limit", "ros2"})
"""Settings only the central uses (its outputs, its flood rule): not sent."""

SENT = frozenset(FLAT) - ROLE_OWN - CENTRAL_ONLY
"""The settings the ``config`` message carries, by flat name: every one a role reads."""

MAX_TEXT = MAX_STR_BYTES
"""The longest text the message codec passes: a setting longer cannot be handed."""


def _digest(path: str) -> str:
    with open(path, "rb") as fh:
        return hashlib.sha256(fh.read()).hexdigest()


def config_message(rc: RunConfig) -> dict[str, Any]:
    """The fields of the central's ``config`` message: ``settings``, each of :data:`SENT`
    by section and flat name (each map well under the codec's bound on a map's entries),
    ``files``, the SHA-256 of each :data:`FILE_SETTINGS` setting that names a file on
    the central's host, and ``insecure``, whether the central runs with ``--insecure``
    (a role keeps its own, but may not be insecure alone: :func:`handed`); or ``error``
    alone, saying why the configuration cannot be handed (a text longer than the codec
    passes)."""
    settings: dict[str, dict[str, Any]] = {name: {} for name in SECTIONS}
    for flat, value in rc.to_dict().items():
        if flat not in SENT:
            continue
        texts = value if isinstance(value, list) else [*value.keys(), *value.values()] \
            if isinstance(value, dict) else [value]
        if any(isinstance(t, str) and len(t.encode()) > MAX_TEXT for t in texts):
            section, name = FLAT[flat]
            return {"error": f"{section}.{name} is longer than {MAX_TEXT} bytes, which the "
                    "unit's messages do not carry: start the central with a shorter one"}
        settings[FLAT[flat][0]][flat] = value
    files = {flat: _digest(path) for flat in FILE_SETTINGS
             if isinstance(path := rc.option(flat), str) and os.path.isfile(path)}
    return {"settings": settings, "files": files, "insecure": rc.transport.insecure}


def _flat_settings(msg: dict[str, Any]) -> dict[str, Any]:
    """The settings of a ``config`` message by flat name, each checked to be where the
    message says it is, and every one of :data:`SENT` there."""
    if "error" in msg:
        raise ConfigError(f"the central cannot hand this role its configuration: "
                          f"{msg['error']}")
    settings = msg.get("settings")
    if not isinstance(settings, dict) or set(settings) != set(SECTIONS):
        raise ConfigError(f"the central's configuration: expected the sections "
                          f"{', '.join(SECTIONS)}")
    flat: dict[str, Any] = {}
    for section, table in settings.items():
        if not isinstance(table, dict):
            raise ConfigError(f"the central's configuration: [{section}] is not a table")
        for name, value in table.items():
            if name not in SENT or FLAT[name][0] != section:
                raise ConfigError(f"the central's configuration: [{section}] has no "
                                  f"{name!r}")
            flat[name] = value
    missing = sorted(SENT - set(flat))
    if missing:
        raise ConfigError(f"the central's configuration: missing {', '.join(missing)} (a "
                          "central of another version?)")
    return flat


def _check_files(rc: RunConfig, digests: dict[str, Any]) -> None:
    """Each file the central named exists on this host with the central's contents."""
    for flat, digest in digests.items():
        if flat not in FILE_SETTINGS:
            raise ConfigError(f"the central's configuration: files has {flat!r} (allowed: "
                              f"{', '.join(FILE_SETTINGS)})")
        path = rc.option(flat)
        flag = "--" + flat.replace("_", "-")
        if not isinstance(path, str) or not os.path.isfile(path):
            raise ConfigError(f"{flag} {path}: the unit's file is not on this host; give "
                              f"{flag} with this host's copy")
        if _digest(path) != digest:
            raise ConfigError(f"{flag} {path}: differs from the central's file (SHA-256 "
                              f"{str(digest)[:12]}...); give {flag} with a copy of it")


def handed(msg: dict[str, Any], own: RunConfig, given: set[str]
           ) -> tuple[RunConfig, list[str]]:
    """The configuration a role started by hand runs with, and a note for each setting it
    was given that the unit's replaces.

    Parameters
    ----------
    msg : the central's ``config`` message (:func:`config_message`'s fields).
    own : the role's configuration from its own command line.
    given : the settings (flat names) given on that command line, by flag, ``--set`` or
        run file.

    A file setting given (``--params FILE``) is kept where the central's names a file
    too: it is this host's copy of it, checked against the central's digest. Otherwise
    the unit's value replaces it, as any other setting.

    Raises
    ------
    ConfigError
        On a malformed or incomplete configuration (naming the section or settings), a
        file the unit names that is missing on this host or differs from the central's,
        or ``--insecure`` here, without keys and with a link other than a unix socket,
        where the central runs without it.
    """
    unit = RunConfig.from_dict(_flat_settings(msg), source="the central's configuration")
    mine = own.transport
    if mine.insecure and msg.get("insecure") is False and not mine.keys and not all(
            map(is_socket, [*(mine.listen or []), *(mine.connect or [])])):
        raise ConfigError(
            "--insecure: the unit's central runs without it, so that a link other than its "
            "unix socket carries the observers' keys alone; this role's links would carry "
            "the control path to whoever reaches them, and route for them: drop --insecure "
            "here, or start the central with it too")
    digests = msg.get("files", {})
    if not isinstance(digests, dict):
        raise ConfigError("the central's configuration: 'files' is not a table")
    copies = {f for f in FILE_SETTINGS if f in given and f in digests}
    rc = unit.replace(**{f: own.option(f) for f in ROLE_OWN | copies})
    _check_files(rc, digests)
    notes = [f"{FLAT[f][0]}.{FLAT[f][1]} = {unit.option(f)!r} of the unit over "
             f"{own.option(f)!r} given" for f in sorted(given & SENT - copies)
             if own.option(f) != unit.option(f)]
    return rc.validate(), notes
