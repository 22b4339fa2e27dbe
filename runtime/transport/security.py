"""Who may talk to a unit: mutual TLS and Zenoh's access control, by role.

A unit's credentials (``ctrlunit keys init DIR``, :func:`make_keys`) are one certificate
authority and one key and certificate per role, each certificate's common name the role's
name (``central``, ``plant``, ``peripheral-K``, ``viewer``). With ``--keys DIR`` every
link is TLS with mutual authentication (a peer without a certificate signed by the
unit's authority cannot connect; a link that cannot carry a certificate, a unix socket,
is refused), and each role's session carries the same access-control policy
(:func:`access_control`), default deny:

- only the plant publishes samples to the central;
- only peripheral K publishes its replies (``central/reply/K``);
- only the central publishes into the plant's and the peripherals' inboxes (requests,
  commands, orders);
- each of the unit's roles says its hello and bye to the central on a key of its own
  (``central/hello/<role>``): none can speak for another;
- each role may subscribe to, and be sent, its own inbox alone; a viewer the observers'
  keys (``view/``) alone, and it may publish nothing. A reader that stops reading can
  then hold back no put of the control path (runtime/transport/zsession.py,
  ``closed_links``).

Zenoh drops a message the policy denies before the role sees it. Before anything starts,
:func:`check_credentials` checks the files of the roles a run uses (they parse, each key
is its certificate's, each certificate is the role's and signed by the authority, and
valid now; no key others can read, no file others can write). What this protects, and
what not, is in docs/faults-and-errors.md (Security).
"""

from __future__ import annotations

import ipaddress
import json
import os
from pathlib import Path
from typing import Any

from .endpoints import SOCKET, is_socket
from .keycheck import CA_CERT, CA_KEY
from .keycheck import check_credentials as check_credentials  # the checks live apart

VIEWER = "viewer"
VIEWER_KEYS = "view"
"""The observers' key space, ``ctrlunit/<unit>/view/``: all a viewer may read."""
MAX_PERIPHERALS = 3
VALID_DAYS = 365


def role_names(peripherals: int = MAX_PERIPHERALS) -> list[str]:
    """The roles a unit's credentials cover: central, plant, peripheral-1..n, viewer."""
    return ["central", "plant", *(f"peripheral-{k}" for k in range(1, peripherals + 1)),
            VIEWER]


def make_keys(directory: str | Path, *, authority: str | Path | None = None,
              peripherals: int = MAX_PERIPHERALS, days: int = VALID_DAYS) -> list[Path]:
    """Write a unit's credentials: ``ca.pem`` and a key and certificate per role
    (:func:`role_names`) into ``directory``, the authority's ``ca.key`` (and a copy of
    ``ca.pem``) into ``authority`` (default: the sibling ``<directory>-authority``). Both
    directories are made 0700, keys 0600, certificates 0644, whatever the umask; no file
    is overwritten (a :class:`FileExistsError` names the first, before anything is
    written). Returns the files written, the authority's two last.

    Uses the ``cryptography`` package: an ECDSA P-256 authority and, per role, a
    certificate for both TLS server and client use whose common name is the role
    (runtime/transport/keygen.py)."""
    from .keygen import write_keys

    return write_keys(directory, role_names(peripherals), authority=authority, days=days,
                      ca_cert=CA_CERT, ca_key=CA_KEY)


def credentials(directory: str | Path, role: str) -> dict[str, str]:
    """The authority's certificate and ``role``'s key and certificate in ``directory``.

    Raises
    ------
    FileNotFoundError
        Naming the missing file and how to make the unit's keys."""
    d = Path(directory)
    files = {"ca": d / CA_CERT, "key": d / f"{role}.key", "cert": d / f"{role}.pem"}
    for f in files.values():
        if not f.is_file():
            raise FileNotFoundError(f"--keys {directory}: {f.name} is missing (make a unit's "
                                    "keys with: ctrlunit keys init DIR)")
    return {k: str(v) for k, v in files.items()}


def _rule(rid: str, messages: list[str], keys: list[str], flows: list[str]) -> dict[str, Any]:
    return {"id": rid, "permission": "allow", "messages": messages, "key_exprs": keys,
            "flows": flows}


def access_control(peripherals: int = MAX_PERIPHERALS) -> dict[str, Any]:
    """The unit's access-control policy (Zenoh's ``access_control`` section), the same on
    every role's session; subjects are certificate common names (module notes). Each
    subject may subscribe to, and be sent, its own inbox alone (the central ``central/``,
    the plant ``plant/``, every peripheral ``peripheral/``) and a viewer the observers'
    keys ``view/`` alone: no reader but the roles an interval needs gets the control
    path's messages, so none can hold back a put on it."""
    unit = "ctrlunit/*"
    roles = role_names(peripherals)
    units = [r for r in roles if r != VIEWER]
    inbox = {"central": "central", "plant": "plant", VIEWER: VIEWER_KEYS,
             **{f"peripheral-{k}": "peripheral" for k in range(1, peripherals + 1)}}
    rules = [
        # a unit's role learns the others' subscriptions (where to send)
        _rule("learn", ["declare_subscriber"], ["ctrlunit/**"], ["egress"]),
        *(rule for p in sorted(set(inbox.values())) for rule in (
            _rule(f"sub-{p}", ["declare_subscriber"], [f"{unit}/{p}/**"], ["ingress"]),
            _rule(f"to-{p}", ["put"], [f"{unit}/{p}/**"], ["egress"]))),
        *(_rule(f"hello-{r}", ["put"], [f"{unit}/central/hello/{r}"], ["ingress"])
          for r in units if r != "central"),
        _rule("sample", ["put"], [f"{unit}/central/sample"], ["ingress"]),
        _rule("orders", ["put"], [f"{unit}/plant/**", f"{unit}/peripheral/**",
                                  f"{unit}/{VIEWER_KEYS}/**"], ["ingress"]),
        *(_rule(f"reply-{k}", ["put"], [f"{unit}/central/reply/{k}"], ["ingress"])
          for k in range(1, peripherals + 1)),
    ]
    subjects = [{"id": r, "cert_common_names": [r]} for r in roles]
    policies = [
        {"id": "units", "rules": ["learn"], "subjects": units},
        *({"id": f"inbox-{r}", "rules": [f"sub-{inbox[r]}", f"to-{inbox[r]}"],
           "subjects": [r]} for r in roles),
        *({"id": f"hello-{r}", "rules": [f"hello-{r}"], "subjects": [r]}
          for r in units if r != "central"),
        {"id": "plant", "rules": ["sample"], "subjects": ["plant"]},
        {"id": "central", "rules": ["orders"], "subjects": ["central"]},
        *({"id": f"peripheral-{k}", "rules": [f"reply-{k}"], "subjects": [f"peripheral-{k}"]}
          for k in range(1, peripherals + 1)),
    ]
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}


OTHER_LINKS = ("tcp", "udp", "tls", "quic", "ws", "serial", "unixpipe", "vsock")
"""Every other link protocol Zenoh's access control names (``link_protocols``)."""
EVERY_MESSAGE = ("put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                 "liveliness_token", "declare_liveliness_subscriber", "liveliness_query")


def socket_rule() -> dict[str, Any]:
    """The unit's access control without keys (Zenoh's ``access_control``, subjects by
    link protocol, default deny), on the session of each of a unit's roles that has a
    link other than a unix socket, unless ``--insecure``: a unix socket's peers (the
    processes of the user who may enter its directory: the unit's roles) everything; a
    peer on any other link (a loopback TCP port, where any process of the host may
    connect) the observers' keys ``view/`` alone, to subscribe to and be sent, and it may
    publish nothing. The control path then never goes to such a peer, so one that stops
    reading holds back no put of it, and a forged sample, reply or order from it is
    dropped before any role sees it. Without keys the roles cannot tell one another
    apart: on the socket each may publish anything (with keys each its own keys alone:
    :func:`access_control`)."""
    view = f"ctrlunit/*/{VIEWER_KEYS}/**"
    rules = [_rule("socket", list(EVERY_MESSAGE), ["**"], ["ingress", "egress"]),
             _rule("sub-view", ["declare_subscriber"], [view], ["ingress"]),
             _rule("to-view", ["put"], [view], ["egress"])]
    subjects = [{"id": "socket", "link_protocols": [SOCKET]},
                {"id": "observers", "link_protocols": list(OTHER_LINKS)}]
    policies = [{"id": "socket", "rules": ["socket"], "subjects": ["socket"]},
                {"id": "observers", "rules": ["sub-view", "to-view"],
                 "subjects": ["observers"]}]
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}


def control_link_error(endpoints: list[str], *, way: str, keys: str | None,
                       insecure: bool) -> str | None:
    """Why a role started by hand could not reach the unit's control path over
    ``endpoints`` (the central: where it listens; another role: where it connects), or
    None: without keys and without ``--insecure`` only a unix socket carries it
    (:func:`socket_rule`). None too without endpoints: such a role reaches nothing, and
    waits for the central's configuration until ``--startup-timeout``."""
    if keys or insecure or not endpoints or any(map(is_socket, endpoints)):
        return None
    fix = ("add --listen unixsock-stream/PATH (the other roles --connect to it)"
           if way == "listen" else "--connect to the unix socket the central listens on "
           "(unixsock-stream/PATH)")
    return (f"--{way} {', '.join(endpoints)}: without keys the unit's roles reach the "
            "central over a unix socket alone, and any other link carries the observers' "
            f"keys (view/) alone, to anyone on this host: {fix}, or give every role "
            "--keys DIR (ctrlunit keys init DIR); --insecure lets every link carry the "
            "control path (a lab bench)")


def secure(conf: Any, directory: str | Path, role: str) -> None:
    """Make ``conf`` (a ``zenoh.Config``) authenticate as ``role`` with the unit's keys in
    ``directory`` and enforce :func:`access_control`. Names in certificates are roles, not
    host names: the peer is identified by its certificate's chain to the unit's authority
    and its common name, not by the address it was reached at."""
    c = credentials(directory, role)
    tls = {"root_ca_certificate": c["ca"], "enable_mtls": True,
           "listen_private_key": c["key"], "listen_certificate": c["cert"],
           "connect_private_key": c["key"], "connect_certificate": c["cert"],
           "verify_name_on_connect": False}
    conf.insert_json5("transport/link/tls", json.dumps(tls))
    conf.insert_json5("access_control", json.dumps(access_control()))


def tls_endpoint(endpoint: str) -> str:
    """``tcp/HOST:PORT`` as ``tls/HOST:PORT``; other endpoints (the local socket, tls) as
    they are."""
    return "tls/" + endpoint[4:] if endpoint.startswith("tcp/") else endpoint


def reaches_beyond_host(endpoint: str) -> bool:
    """Whether an endpoint can be reached from another host: anything but a unix socket
    or a loopback address (127.0.0.0/8, ::1, localhost)."""
    addr = endpoint.partition("/")[2]
    if is_socket(endpoint):
        return False
    host = addr.rsplit(":", 1)[0].strip("[]") if ":" in addr else addr
    host = host.split("?")[0].split("#")[0]
    if host == "localhost":
        return False
    try:
        return not ipaddress.ip_address(host).is_loopback
    except ValueError:
        return True  # a host name other than localhost


PROTECTIONS = ("insecure", "loopback", "local", "tls")
"""What protects a link, the weakest first: ``insecure`` (a link other than a unix socket
without keys, with ``--insecure``: it carries the control path to whoever reaches it),
``loopback`` (a loopback address without keys: any process on this host may connect,
and gets the observers' keys alone, :func:`socket_rule`), ``local`` (a unix socket: who
may enter its directory; the default one's is this user's alone) and ``tls`` (mutual
TLS under the unit's access control)."""

CERTIFIED = ("tcp", "tls")
"""The protocols whose links carry the roles' certificates with ``--keys`` (``tcp``
becomes ``tls``)."""

Link = tuple[str, str, str]
"""One link: (endpoint, ``listen`` or ``connect``, where it was given: ``--listen``,
``--connect``, ``--zenoh-config FILE`` or ``default``)."""


def _where(endpoint: str, way: str, source: str) -> str:
    """An endpoint as an error names it: with the option, or the file and its key."""
    if source.startswith("--zenoh-config"):
        return f"{source}: {way}/endpoints {endpoint}"
    return f"{source} {endpoint}" if source.startswith("--") else endpoint


def _beyond(endpoint: str, way: str, source: str) -> ValueError:
    where = _where(endpoint, way, source) if source.startswith("--zenoh") else endpoint
    return ValueError(
        f"{where} can be reached from other hosts, and without keys anyone who can "
        "reach it may read the unit's traffic and move the robot: make keys with "
        "'ctrlunit keys init DIR' and give --keys DIR to every role, or --insecure for "
        "a lab bench")


SCOUTING_WHY = {
    "multicast": "multicast scouting announces the unit to every host of the network and "
                 "connects to what answers",
    "gossip": "gossip scouting passes every peer's address on to the others, which then "
              "connect to it past the unit's links (a reader of the observers' port "
              "would reach the plant)",
}
"""Why a file's scouting is a link of its own, by kind."""


def protect(links: list[Link], *, keys: str | None, insecure: bool,
            scouting: dict[str, str] | None = None) -> list[dict[str, str]]:
    """Each link with what protects it (:data:`PROTECTIONS`), as the report lists them:
    ``{"endpoint", "way", "from", "protection"}``; with keys, ``tcp`` endpoints as the
    ``tls`` ones they become. ``scouting`` names, by kind (``multicast``, ``gossip``),
    the file that turns that scouting on (it makes links the unit did not give,
    :data:`SCOUTING_WHY`): each a link of its own, ``scouting``. A unix socket whose
    folder others may write is refused without ``--insecure``: another user could put a
    socket of their own in its place and pose as the central.

    Raises
    ------
    ValueError
        Without keys or ``--insecure``: a link beyond the host, scouting (naming the
        endpoint or ``scouting/<kind>/enabled``, the file, and the fix), or a unix socket
        in a folder others may write (naming the folder). With keys: a link that cannot
        carry a certificate (a unix socket, udp, ...): the unit's access control would
        drop all of its traffic."""
    out = []
    for endpoint, way, source in links:
        proto = endpoint.partition("/")[0]
        if keys:
            if proto not in CERTIFIED:
                raise ValueError(
                    f"{_where(endpoint, way, source)}: with --keys every role is known by "
                    f"its certificate, and a {proto} link carries none (the unit's access "
                    "control would drop all of its traffic): use a tcp/ endpoint (it becomes "
                    "tls/), e.g. tcp/127.0.0.1:7447")
            prot = "tls"
        elif is_socket(endpoint):
            if not insecure and (why := shared_folder(endpoint)):
                raise ValueError(f"{_where(endpoint, way, source)}: {why}")
            prot = "local"
        elif not reaches_beyond_host(endpoint) and not insecure:
            prot = "loopback"
        elif insecure:
            prot = "insecure"
        else:
            raise _beyond(endpoint, way, source)
        out.append({"endpoint": tls_endpoint(endpoint) if keys else endpoint, "way": way,
                    "from": source, "protection": prot})
    for kind, source in (scouting or {}).items():
        if not keys and not insecure:
            raise ValueError(
                f"{source}: scouting/{kind}/enabled is true, and without keys "
                f"{SCOUTING_WHY[kind]}, which may then read the unit's traffic and move the "
                "robot: remove it from the file (ctrlunit turns scouting off), or make keys "
                "with 'ctrlunit keys init DIR' and give --keys DIR to every role, or "
                "--insecure for a lab bench")
        out.append({"endpoint": f"scouting/{kind}", "way": "scouting", "from": source,
                    "protection": "tls" if keys else "insecure"})
    return out


def shared_folder(endpoint: str) -> str | None:
    """Why a unix socket's folder will not do, or None: one that others (group or anyone)
    may write, such as /tmp, or that another user owns, where another user could bind the
    socket's path first and pose as the central. A folder that does not exist yet is
    Zenoh's to refuse."""
    folder = Path(endpoint.partition("/")[2]).parent
    try:
        st = folder.stat()
    except OSError:
        return None
    if st.st_mode & 0o022 == 0 and st.st_uid in (os.geteuid(), 0):
        return None
    why = f"may be written by others (mode {st.st_mode & 0o7777:o})" \
        if st.st_mode & 0o022 else f"is another user's (uid {st.st_uid})"
    return (f"its folder {folder} {why}: another user could bind the socket there first "
            "and pose as the central; put it in a folder of your own (mkdir -m 700 DIR), "
            "or --insecure for a lab bench")


def weakest(links: list[dict[str, str]], *, keys: str | None) -> str:
    """The weakest protection among ``links`` (:data:`PROTECTIONS`); with none, the
    default link's: ``tls`` with keys, else ``local``."""
    if not links:
        return "tls" if keys else "local"
    return min((ln["protection"] for ln in links), key=PROTECTIONS.index)


def unit_links(transport: Any, *, central: str | None = None,
               file: Any = None) -> list[dict[str, str]]:
    """The links of a unit whose transport settings are ``transport`` (a
    ``TransportConfig``), each with its protection (:func:`protect`): the endpoints
    listened on (the launcher's ``central`` endpoint if given, ``--listen`` and the
    ``--zenoh-config`` file's), those connected to (``--connect``, else the file's) and
    the file's multicast and gossip scouting if it turns them on; ``file``: what the file says
    (runtime/transport/zsession.py, ``file_links``), given when there is one.

    Raises
    ------
    ValueError
        As :func:`protect`."""
    t = transport
    given = list(dict.fromkeys(t.listen or []))  # one link however often given
    listen = [*([central] if central and central not in given else []), *given]
    links: list[Link] = [(e, "listen", "--listen" if e in given else "default")
                         for e in listen]
    links += [(e, "connect", "--connect") for e in t.connect or []]
    scouting: dict[str, str] = {}
    if file is not None:
        f, source = file, f"--zenoh-config {t.zenoh_config}"
        links += [(e, "listen", source) for e in f.listen if e not in listen]
        if t.connect is None:
            links += [(e, "connect", source) for e in f.connect]
        scouting = {kind: source for kind, on in (("multicast", f.multicast),
                                                   ("gossip", f.gossip)) if on}
    return protect(links, keys=t.keys, insecure=t.insecure, scouting=scouting)


def link_security(listen: list[str] | None, connect: list[str] | None, keys: str | None,
                  insecure: bool) -> str:
    """How a role's links are protected, for the report: the weakest of
    :data:`PROTECTIONS` among ``listen`` and ``connect`` (:func:`protect`, :func:`weakest`).

    Raises
    ------
    ValueError
        As :func:`protect`."""
    links = [*((e, "listen", "--listen") for e in listen or []),
             *((e, "connect", "--connect") for e in connect or [])]
    return weakest(protect(links, keys=keys, insecure=insecure), keys=keys)
