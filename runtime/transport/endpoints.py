"""Zenoh endpoints and unit ids: their checks, made before any role starts, and the
endpoints the central listens on by default (a unix socket without keys, loopback TLS
with them)."""

from __future__ import annotations

import json
import re
import socket
import stat
from pathlib import Path

import zenoh

SOCKET = "unixsock-stream"
"""The link whose peers are the unit's own user's processes (its directory is theirs)."""


def is_socket(endpoint: str) -> bool:
    """Whether ``endpoint`` is a unix socket (:data:`SOCKET`): a link only processes that
    may enter its folder can reach."""
    return endpoint.startswith("unixsock")


UNIT_ID_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


def check_unit_id(unit: str) -> str:
    """A unit id is 1-64 characters of ``A-Z a-z 0-9 _ -`` (it becomes a key chunk)."""
    if not UNIT_ID_RE.match(unit):
        raise ValueError(
            f"unit id {unit!r} must be 1-64 characters of letters, digits, '_' or '-'"
        )
    return unit


_IP_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws)/(?P<host>\[[^\]]+\]|[^:\[\]/]+):(?P<port>[^?#]*)"
                          r"([?#].*)?$")


def check_endpoint(endpoint: str, *, option: str) -> str:
    """A Zenoh endpoint ``<protocol>/<address>``: checked here, before any role starts,
    where Zenoh would report it only when a session opens (or, for a connect endpoint,
    never: it keeps retrying). IP protocols need ``HOST:PORT`` with a port in 0-65535."""
    if not isinstance(endpoint, str) or "/" not in endpoint or endpoint.startswith("/"):
        raise ValueError(f"{option} = {endpoint!r}: expected <protocol>/<address>, e.g. "
                         "tcp/127.0.0.1:7447 or unixsock-stream/PATH")
    proto, _, address = endpoint.partition("/")
    if is_socket(endpoint) and not (address[:1] == "/" and len(address.encode()) < 108
                                             and Path(address).parent.is_dir()):
        raise ValueError(f"{option} = {endpoint!r}: expected {proto}//FOLDER/NAME, an absolute "
                         "path (two slashes) of at most 107 bytes in a folder that exists")
    if proto in ("tcp", "udp", "tls", "quic", "ws"):
        m = _IP_ENDPOINT.match(endpoint)
        port = m.group("port") if m else ""
        if not m or not port.isdigit() or not 0 <= int(port) <= 65535:
            raise ValueError(f"{option} = {endpoint!r}: expected {proto}/HOST:PORT with PORT "
                             "0 to 65535")
    try:
        conf = zenoh.Config()
        conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    except Exception as exc:  # Zenoh's parser: ZError, whose text is long and multi-line
        raise ValueError(f"{option} = {endpoint!r}: {zenoh_error_line(exc)}") from None
    return endpoint


def zenoh_error_line(exc: BaseException) -> str:
    """Zenoh's error in one line: without its source location, the parser's nesting and
    the JSON5 parser's drawing of the line (kept: its position and what it expected)."""
    text = re.sub(r" at /\S+:\d+\.?", "", str(exc)).strip() or type(exc).__name__
    where = re.search(r"-->\s*(\d+):(\d+)", text)
    expected = re.search(r"^\s*= (.*)$", text, re.MULTILINE)
    if where and expected:
        return f"syntax error at line {where[1]}, column {where[2]}: {expected[1]}"
    m = re.search(r'msg: "([^"]*)"', text)
    text = m.group(1) if m else text.splitlines()[0]
    return text if len(text) <= 300 else text[:text.rfind(", ", 0, 300)] + ", ..."


def default_endpoint(run_dir: Path) -> str:
    """The central's default endpoint: a unix socket in the run directory (loopback only)."""
    return f"unixsock-stream/{run_dir / 'central.sock'}"


def loopback_endpoint(protocol: str = "tls") -> str:
    """``PROTOCOL/127.0.0.1:PORT`` on a port free now (the kernel's choice for a socket
    bound to port 0, then closed): the central's default endpoint with keys, whose links
    must carry the roles' certificates, which a unix socket cannot. Another process may
    take the port before Zenoh binds it: the caller retries on another one."""
    return with_free_port(f"{protocol}/127.0.0.1:0")


def with_free_port(endpoint: str) -> str:
    """``endpoint`` with port 0 replaced by a port free now on its host (as
    :func:`loopback_endpoint` chooses one), so that what the summary names, and what
    the roles connect to, is the port listened on; any other endpoint unchanged. Another
    process may take the port before Zenoh binds it: the caller retries on another."""
    m = _IP_ENDPOINT.match(endpoint)
    if not m or m.group("port") != "0":
        return endpoint
    host = m.group("host").strip("[]")
    udp = m.group(1) in ("udp", "quic")
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_DGRAM if udp else socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        port = s.getsockname()[1]
    return f"{endpoint[:m.end('port') - 1]}{port}{endpoint[m.end('port'):]}"


def socket_path_taken(endpoint: str) -> str | None:
    """Why a unix socket cannot listen at ``endpoint``'s path, or None: Zenoh removes
    whatever is there before it binds, so a file there was deleted and another program's
    live socket taken over (an attacker's review: ``--listen unixsock-stream//DIR/notes``
    deleted ``notes``). A socket nobody answers on (left by a run that was killed) may
    go."""
    path = Path(endpoint.partition("/")[2])
    try:
        st = path.lstat()
    except OSError:
        return None
    if not stat.S_ISSOCK(st.st_mode):
        return (f"{path} exists and is not a socket: listening there would delete it; give "
                "a path where nothing is")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    probe.settimeout(0.5)
    try:
        probe.connect(str(path))
    except OSError:
        return None  # nobody answers: a socket left behind
    finally:
        probe.close()
    return (f"another program listens on {path}: listening there would take its socket "
            "away; give another path")
