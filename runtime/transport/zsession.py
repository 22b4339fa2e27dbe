"""Zenoh session set-up and the key space of a unit.

Peer mode, multicast and gossip scouting off, and the lowest-latency transport that
eclipse-zenoh offers here (``transport/unicast/lowlatency`` with QoS off: docs/message-costs.md
measured 138 us against 172 us p50 for a unix-socket round trip). The central listens; the
other roles connect to it (a star). Every key lives under ``ctrlunit/<unit-id>/``.
"""

from __future__ import annotations

import functools
import json
import os
from dataclasses import dataclass

import zenoh

from ...kernels.small_file import read_small_text
from .endpoints import check_endpoint, is_socket, zenoh_error_line
from .limits import Limits


def check_zenoh_config(path: str) -> None:
    """``--zenoh-config``: a readable Zenoh JSON5 configuration (Zenoh's own parser) whose
    mode, if it names one, is ``peer`` (the roles are peers in a star around the central:
    a client cannot listen, a router would route for others) and whose endpoints are
    valid ones (:func:`check_endpoint`)."""
    links = file_links(path)
    if links.plugins:  # a plugin listens where its own settings say (a REST port, say)
        raise ValueError(f"--zenoh-config {path}: it loads Zenoh plugins ({links.plugins}), "
                         "which open ports and keys of their own beyond the unit's link rule "
                         "and keys: ctrlunit uses none; remove plugins and plugins_loading")
    if links.namespace:  # the access control is written for ctrlunit/<unit>/...
        raise ValueError(f"--zenoh-config {path}: namespace {links.namespace!r}: the unit's "
                         "keys would move, and could fall inside the observers' keys; remove "
                         "namespace")
    if links.admin_write:
        raise ValueError(f"--zenoh-config {path}: adminspace/permissions/write is true: a "
                         "peer could change this session's configuration; remove it")
    if links.mode not in (None, "peer"):
        raise ValueError(f"--zenoh-config {path}: mode {links.mode!r}: the unit's roles are "
                         "Zenoh peers (a star around the central); remove mode from the "
                         "file or set it to \"peer\"")
    for key, endpoints in (("listen/endpoints", links.listen),
                           ("connect/endpoints", links.connect)):
        for e in endpoints:
            check_endpoint(e, option=f"--zenoh-config {path}: {key}")


@dataclass(frozen=True)
class FileLinks:
    """What a ``--zenoh-config`` file says of the links: the endpoints a peer listens on
    and connects to (a per-mode object read for ``peer``; listen endpoints only where the
    file gives them, not Zenoh's default), whether it turns multicast scouting and gossip
    on or off (None: it does not say), and its mode (None: not given); the plugins it
    loads (their names, or ``plugins_loading`` where it names none), whether its admin
    space may be written, and the namespace it puts every key under (None: none)."""

    listen: list[str]
    connect: list[str]
    multicast: bool | None
    gossip: bool | None
    mode: str | None
    plugins: str = ""
    admin_write: bool = False
    namespace: str | None = None


MAX_NESTING = 64
"""How deep a Zenoh configuration file may nest its lists and objects: Zenoh's parser
recurses, and 100 000 nested lists overflowed its stack (the process died of SIGSEGV)."""


def _check_nesting(path: str) -> None:
    """Refuse a file that is not one the project reads (kernels/small_file.py: a regular
    file of at most 1 MiB), or whose brackets nest deeper than :data:`MAX_NESTING`
    (counted on the text, strings included: a bracket in a string only makes the count
    stricter)."""
    text = read_small_text(path, whose=f"--zenoh-config {path}")
    depth = deepest = 0
    for b in text:
        if b in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif b in "]}":
            depth -= 1
    if deepest > MAX_NESTING:
        raise ValueError(f"--zenoh-config {path}: nested {deepest} levels deep: allowed "
                         f"at most {MAX_NESTING}")


def file_links(path: str) -> FileLinks:
    """Read :class:`FileLinks` from a Zenoh configuration file with Zenoh's parser.

    Raises
    ------
    ValueError
        ``--zenoh-config FILE: ...``: the file does not parse (Zenoh's message in a line)
        or its endpoints are not lists of strings."""
    _check_nesting(path)
    try:
        conf = zenoh.Config.from_file(path)
    except Exception as exc:  # ZError: syntax, unknown field, unreadable file
        raise ValueError(f"--zenoh-config {path}: {zenoh_error_line(exc)}") from None

    def endpoints(key: str) -> list[str]:
        value = json.loads(conf.get_json(key))
        if key.startswith("listen") and value == json.loads(zenoh.Config().get_json(key)):
            return []  # Zenoh's default, not the file's: ctrlunit listens only where asked
        if isinstance(value, dict):  # per mode: the roles are peers
            value = value.get("peer") or []
        if not isinstance(value, list) or not all(isinstance(e, str) for e in value):
            raise ValueError(f"--zenoh-config {path}: {key} must be a list of endpoints (or "
                             "one per mode), e.g. [\"tcp/127.0.0.1:7447\"]")
        return value

    admin = json.loads(conf.get_json("adminspace/permissions")) or {}
    return FileLinks(listen=endpoints("listen/endpoints"),
                     connect=endpoints("connect/endpoints"),
                     multicast=json.loads(conf.get_json("scouting/multicast/enabled")),
                     gossip=json.loads(conf.get_json("scouting/gossip/enabled")),
                     mode=json.loads(conf.get_json("mode")),
                     plugins=loaded_plugins(conf),
                     admin_write=admin.get("write") is True,
                     namespace=json.loads(conf.get_json("namespace")))


def loaded_plugins(conf: zenoh.Config) -> str:
    """The Zenoh plugins a configuration loads: their names, ``plugins_loading`` where it
    turns loading on and names none, or empty (ctrlunit uses none: a plugin opens ports
    and keys of its own, past the link rule and the unit's keys)."""
    names = sorted(json.loads(conf.get_json("plugins")) or {})
    loading = json.loads(conf.get_json("plugins_loading/enabled")) is True
    return ", ".join(names) or ("plugins_loading" if loading else "")


@dataclass(frozen=True)
class Keys:
    """Key expressions of one unit, addressed by destination: every key a role receives
    lies under its inbox ``ctrlunit/<unit>/<role>/`` (``central``, ``peripheral``,
    ``plant``), so that each role reads all of its traffic from one subscriber."""

    unit: str

    @property
    def root(self) -> str:
        return f"ctrlunit/{self.unit}"

    def inbox(self, role: str) -> str:
        """The key prefix of everything ``role`` (central, peripheral, plant) receives."""
        return f"{self.root}/{role}"

    @property
    def sample(self) -> str:
        """Plant -> central: encoder counts of one sample."""
        return f"{self.root}/central/sample"

    def reply(self, k: int) -> str:
        """Peripheral k -> central: the values of one round."""
        return f"{self.root}/central/reply/{k}"

    def hello(self, role: str) -> str:
        """``role`` (``plant``, ``peripheral-K``) -> central: its hello and bye, on a key of
        its own (with keys, each role may publish on its own alone: none speaks for
        another)."""
        return f"{self.root}/central/hello/{role}"

    @property
    def request(self) -> str:
        """Central -> every peripheral: one request per round (each reads its own axes)."""
        return f"{self.root}/peripheral/request"

    @property
    def command(self) -> str:
        """Central -> plant: the torques of one interval."""
        return f"{self.root}/plant/command"

    def view(self, name: str) -> str:
        """Central -> observers: ``view/state``, ``view/running`` (runtime/observe/zview.py);
        the only keys a viewer may read with keys."""
        return f"{self.root}/view/{name}"

    def control(self, role: str) -> str:
        """Central -> ``role`` (peripheral or plant): go, start, stop."""
        return f"{self.root}/{role}/control"


def zenoh_runtime(workers: int) -> str:
    """Zenoh's asynchronous runtimes (receive, transmit, accept, network, application) as
    one pool of ``workers`` threads. By default each is a pool of its own, and a message
    crosses threads on its way between the socket and the role's inbox. Measured side by
    side (docs/message-costs.md): a round trip between two processes 30-50 % faster at
    the median and 35-45 % less CPU; the main job at a fixed 2 ms, 3-12 % less CPU per
    interval, misses no worse; one worker and two alike."""
    return ("(rx: (handover: app), tx: (handover: app), acc: (handover: app), "
            f"net: (handover: app), app: (worker_threads: {int(workers)}))")


def runtime_workers(listen: list[str] | None, limits: Limits) -> int:
    """Worker threads of a process whose first session listens on ``listen``. Zenoh opens
    TCP and TLS links with SO_LINGER at 10 s, so closing one whose peer has stopped
    reading blocks the worker thread that closes it in ``close()`` for up to 10 s (seen
    in a stack dump; docs/measurements/2026-11-28-stopped-readers.md). A session that
    only connects has one link, and two workers keep one free. One that listens on TCP or
    TLS (the central's, with keys or ``--listen tcp/...``) admits up to
    ``limits.max_sessions`` peers, every one of which may stop together (four stopped
    readers held both workers of a central that had two, and the run faulted): it
    runs one per admitted peer, one for the ROS 2 router's link (``--ros2``: a session of
    its own in the same process, on the same workers) and one free to receive. A unix
    socket's close does not linger: two."""
    lingering = any(e.split("/", 1)[0] in ("tcp", "tls") for e in listen or [])
    return limits.max_sessions + 2 if lingering else 2


RUNTIME_MARK = "CTRLUNIT_ZENOH_RUNTIME"
"""The ``ZENOH_RUNTIME`` value :func:`set_runtime` wrote, so that it knows its own (a
launcher's, inherited by the roles it starts) from the user's."""


def set_runtime(workers: int) -> None:
    """Set ``ZENOH_RUNTIME`` to :func:`zenoh_runtime` of ``workers`` for this process and
    its children (read when a process opens its first session), unless the user's
    environment sets a runtime of its own: a user's setting wins, whatever it says. A
    value this function wrote (:data:`RUNTIME_MARK`) is replaced; the environment is
    written only when the value changes."""
    current = os.environ.get("ZENOH_RUNTIME")
    if current is not None and current != os.environ.get(RUNTIME_MARK):
        return
    want = zenoh_runtime(workers)
    if current != want:
        os.environ["ZENOH_RUNTIME"] = os.environ[RUNTIME_MARK] = want


@functools.cache
def zenoh_log() -> bool:
    """Zenoh's own log, to this process's standard output, where ``RUST_LOG`` asks for it
    (e.g. ``RUST_LOG=zenoh=info``; the roles a launcher starts inherit it, their output
    goes to their logs); none otherwise. Returns whether it was asked for; once a
    process."""
    if not os.environ.get("RUST_LOG"):
        return False
    zenoh.try_init_log_from_env()
    return True


WAIT_BEFORE_DROP_US = 100
"""How long a put waits for room in a peer's full transmit queue before it drops the
message for that peer (Zenoh's default: 1000 us). Only a peer that stops reading fills
its queue (two batches of 64 KB per priority, behind its socket's buffer); once full,
Zenoh drops at once until it drains."""


def closed_links(endpoints: list[str], *, keys: str | None) -> bool:
    """Whether no one but the unit's own user can connect to these links: every link a
    unix socket (in the run's directory, its user's alone) and no keys (with keys every
    link is TLS). There the roles use Zenoh's low-latency transport, whose put writes to
    each subscriber's socket itself on the caller's thread (docs/message-costs.md), and
    so waits for one that stops reading, holding that link (Zenoh's own threads then
    wait on it too: docs/measurements/2026-11-27-observers.md). Elsewhere, where another
    user or host may connect (TCP, TLS: even a keyed viewer reads the observers' keys),
    they use the default transport, whose put hands each peer's copy to that peer's
    queue and, under DROP congestion control (:meth:`~.node.Node.publisher`), drops it
    there when that queue is full."""
    return keys is None and all(map(is_socket, endpoints))


def make_config(
    *,
    listen: list[str] | None = None,
    connect: list[str] | None = None,
    lowlatency: bool | None = None,
    config_file: str | None = None,
    keys: str | None = None,
    role: str = "central",
    limits: Limits | None = None,
    control: bool = False,
) -> zenoh.Config:
    """A Zenoh configuration for one role.

    Parameters
    ----------
    listen, connect : endpoints (``tcp/127.0.0.1:7447``, ``unixsock-stream/PATH``, ...).
    lowlatency : use the low-latency transport (QoS off); None: where no one but the
        unit's own user can connect (:func:`closed_links`).
    config_file : a Zenoh JSON5 configuration passed through (``--zenoh-config``): the
        role listens on ``listen`` and the file's listen endpoints, and connects to
        ``connect`` if given, else to the file's; multicast scouting and gossip stay off
        unless the file turns them on. Whether its links may reach beyond the host is
        :meth:`RunConfig.validate`'s check, not this function's.
    keys, role : with the unit's keys (``--keys DIR``), ``tcp`` endpoints become ``tls``
        ones, authenticated both ways as ``role`` (``central``, ``plant``,
        ``peripheral-K``, ``viewer``), under the unit's access control
        (runtime/transport/security.py).
    limits : what the session accepts from its links (runtime/transport/limits.py; the
        run's ``transport`` settings); None: the defaults. They apply over a
        ``config_file``'s own.
    control : the session carries the unit's control path (a role without
        ``--insecure``): without keys, each of its links other than a unix socket carries
        the observers' keys alone (runtime/transport/security.py, ``socket_rule``, over a
        ``config_file``'s own access control, as the keys' policy is).
    """
    links = file_links(config_file) if config_file else None
    if links is not None:
        listen = [*(listen or []), *(e for e in links.listen if e not in (listen or []))]
        connect = links.connect if connect is None and links.connect else connect
    if keys is not None:
        from .security import tls_endpoint

        listen = [tls_endpoint(e) for e in listen or []]
        connect = None if connect is None else [tls_endpoint(e) for e in connect]
    zenoh_log()
    set_runtime(runtime_workers(listen, limits or Limits()))
    conf = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    if links is not None:  # no discovery unless the file asks for it
        if links.multicast is not True:
            conf.insert_json5("scouting/multicast/enabled", "false")
        if links.gossip is not True:
            conf.insert_json5("scouting/gossip/enabled", "false")
    if not config_file:
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("scouting/gossip/enabled", "false")
        if lowlatency is None:
            lowlatency = closed_links([*(listen or []), *(connect or [])], keys=keys)
        if lowlatency:
            conf.insert_json5("transport/unicast/lowlatency", "true")
            conf.insert_json5("transport/unicast/qos/enabled", "false")
        else:  # a reader that stops reading fills only its own queue, then loses messages
            conf.insert_json5("transport/link/tx/queue/congestion_control/drop/"
                              "wait_before_drop", str(WAIT_BEFORE_DROP_US))
    # listen only where asked (Zenoh's default would open a port on every interface)
    conf.insert_json5("listen/endpoints", json.dumps(listen or []))
    if connect is not None:
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    (limits or Limits()).apply(conf)
    if keys is not None:
        from .security import secure

        secure(conf, keys, role)
    elif control and not all(map(is_socket, [*(listen or []), *(connect or [])])):
        from .security import socket_rule

        conf.insert_json5("access_control", json.dumps(socket_rule()))
    return conf


def pin_cpus(spec: str | None) -> None:
    """Pin this process to CPUs (``"0"``, ``"0,1"``) before ``zenoh.open`` so that Zenoh's
    threads inherit it (docs/message-costs.md). ``None`` leaves the affinity alone."""
    if not spec:
        return
    cpus = {int(c) for c in spec.split(",") if c.strip()}
    os.sched_setaffinity(0, cpus)
