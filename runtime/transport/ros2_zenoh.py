"""What a ROS 2 node using rmw_zenoh expects on the wire (``ctrlunit start --ros2``):
the Zenoh session that joins the ROS 2 network, the topics' key expressions, the
liveliness tokens ``ros2 topic list`` reads, and the attachment of each message.

The formats follow rmw_zenoh's design document (github.com/ros2/rmw_zenoh, docs/design.md,
and rmw_zenoh_cpp/src/detail/liveliness_utils.cpp, which it refers to):

- a topic's messages travel on ``<domain>/<topic without its leading slash>/<DDS type
  name>/<type hash>``, e.g. ``0/joint_states/sensor_msgs::msg::dds_::JointState_/RIHS01_a13e...``;
  the type hash is the ROS 2 type description hash (``RIHS01_`` and 64 hex digits);
- each node and publisher holds a liveliness token
  ``@ros2_lv/<domain>/<session id>/<node id>/<entity id>/<NN|MP>/<enclave>/<namespace>/<node>``
  (a publisher's followed by ``/<topic>/<DDS type name>/<type hash>/<QoS>``), every ``/``
  inside a part written ``%`` and an empty part ``%``;
- each message carries an attachment: its sequence number and source timestamp (int64,
  little-endian) and the publisher's 16-byte GID (length-prefixed), as Zenoh's
  serializer writes them.

The session is a Zenoh *client* of the ROS 2 router (rmw_zenoh's default router:
``tcp/localhost:7447``, the one ``ros2 run rmw_zenoh_cpp rmw_zenohd`` starts). A client
listens on nothing and talks to that router alone, which routes its messages to the ROS 2
nodes; it never opens a link to another host's nodes itself. The router is changed as
rmw_zenoh changes it, with ``ZENOH_CONFIG_OVERRIDE``
(``connect/endpoints=["tcp/192.168.1.2:7447"]``, ``;`` between settings). A router
beyond this host is refused without ``--insecure``: nothing on that link is keyed, and
anyone on the way would read the unit's signals (a router on this host that connects
onward is the way rmw_zenoh itself recommends).
"""

from __future__ import annotations

import json
import socket
import struct
from collections.abc import Mapping
from typing import Any

from .security import reaches_beyond_host
from .zsession import loaded_plugins

ROUTER = "tcp/localhost:7447"
"""rmw_zenoh's default router (DEFAULT_RMW_ZENOH_SESSION_CONFIG.json5)."""
OVERRIDE_ENV = "ZENOH_CONFIG_OVERRIDE"
"""rmw_zenoh's variable of Zenoh settings over its defaults: ``KEY=VALUE;KEY=VALUE``."""
DOMAIN_ENV = "ROS_DOMAIN_ID"
ADMIN_SPACE = "@ros2_lv"
QOS = "::,10:,:,:,,"
"""The publishers' QoS as a token writes it: ROS 2's default (reliable, volatile, keep
last 10; empty fields are the defaults). rmw_zenoh publishes such a topic as ctrlunit
does, dropping what a congested link cannot take."""
PROBE_S = 1.0


def default_domain(env: Mapping[str, str]) -> int:
    """``ROS_DOMAIN_ID`` if set, else 0 (``--ros2`` without a domain). Raises ValueError
    for one that is not a number from 0."""
    text = env.get(DOMAIN_ENV, "").strip()
    if not text:
        return 0
    if not text.isdigit():
        raise ValueError(f"{DOMAIN_ENV}={text!r}: a ROS 2 domain is a number from 0")
    return int(text)


def session_config(env: Mapping[str, str], *, insecure: bool) -> Any:
    """The Zenoh configuration of the session that joins the ROS 2 network: a client of
    :data:`ROUTER`, no listening, no scouting, then ``ZENOH_CONFIG_OVERRIDE``'s settings.

    Raises
    ------
    ValueError
        For an override that is not ``KEY=VALUE;...`` or that Zenoh refuses, and, without
        ``insecure``, for a router beyond this host or scouting turned on.
    """
    import zenoh

    conf = zenoh.Config()
    for key, value in (("mode", '"client"'), ("connect/endpoints", json.dumps([ROUTER])),
                       ("listen/endpoints", "[]"), ("scouting/multicast/enabled", "false"),
                       ("scouting/gossip/enabled", "false")):
        conf.insert_json5(key, value)
    for part in env.get(OVERRIDE_ENV, "").split(";"):
        if not part.strip():
            continue
        key, eq, value = part.partition("=")
        if not eq or not key.strip():
            raise ValueError(f"{OVERRIDE_ENV}: {part.strip()!r} is not KEY=VALUE")
        try:
            conf.insert_json5(key.strip(), value.strip())
        except Exception as exc:  # ZError
            raise ValueError(f"{OVERRIDE_ENV}: {part.strip()!r}: {exc}") from None
    if not insecure:
        check_links(conf)
    return conf


def _endpoints(conf: Any, key: str, *, every_mode: bool = False) -> list[str]:
    """The endpoints of ``key``: a list, or of a per-mode object the session's mode's entry
    (``every_mode``: every entry's)."""
    value = json.loads(conf.get_json(key))
    if isinstance(value, dict):
        mode = json.loads(conf.get_json("mode"))
        value = [e for m, es in value.items() if every_mode or m == mode for e in es or []]
    return [str(e) for e in value or []]


def router_endpoints(conf: Any) -> list[str]:
    """The routers the session connects to."""
    return _endpoints(conf, "connect/endpoints")


def check_links(conf: Any) -> None:
    """The unit's link rule on the ROS 2 session: no endpoint beyond this host and no
    scouting (raises ValueError naming it and the fix)."""
    for key in ("connect/endpoints", "listen/endpoints"):
        # every mode's: an override may set the mode too (a peer's listen once passed)
        for e in _endpoints(conf, key, every_mode=True):
            if reaches_beyond_host(e):
                raise ValueError(
                    f"--ros2: {key} {e} can be reached from other hosts, and nothing on "
                    "that link is keyed (anyone on the way reads the unit's signals): run "
                    "the ROS 2 router on this host (ros2 run rmw_zenoh_cpp rmw_zenohd) and "
                    "let it connect onward, or --insecure for a lab bench")
    if plugins := loaded_plugins(conf):
        raise ValueError(f"--ros2: {OVERRIDE_ENV} loads Zenoh plugins ({plugins}), which "
                         "open ports of their own (a REST port, say): ctrlunit uses none; "
                         "remove them, or --insecure for a lab bench")
    if json.loads(conf.get_json("scouting/multicast/enabled")) is True:
        raise ValueError(f"--ros2: {OVERRIDE_ENV} turns multicast scouting on, which "
                         "announces the unit to every host of the network: leave it off, or "
                         "--insecure for a lab bench")


def probe(conf: Any) -> None:
    """Whether a Zenoh router answers on the session's ``tcp/`` endpoints: a TCP
    connection, then Zenoh's handshake in a client session of its own, each within
    :data:`PROBE_S` (other protocols are left to Zenoh). Raises OSError naming them and
    how to start one; a listener that accepts and never answers is no router."""
    import zenoh

    tcp = [e for e in router_endpoints(conf) if e.startswith("tcp/")]
    silent = []
    for e in tcp:
        host, _, port = e[4:].split("#")[0].split("?")[0].rpartition(":")
        try:
            socket.create_connection((host.strip("[]"), int(port)), timeout=PROBE_S).close()
        except (OSError, ValueError):
            continue
        client = zenoh.Config.from_json5(json.dumps({
            "mode": "client", "scouting": {"multicast": {"enabled": False}},
            "connect": {"endpoints": [e], "timeout_ms": int(PROBE_S * 1000)}}))
        try:
            zenoh.open(client).close()
            return
        except Exception:  # ZError: no Zenoh handshake within the time
            silent.append(e)
    if silent:
        raise OSError(f"--ros2: {', '.join(silent)} accepted a connection but answered no "
                      f"Zenoh handshake within {PROBE_S:g} s: not a Zenoh router (start the "
                      "ROS 2 one: ros2 run rmw_zenoh_cpp rmw_zenohd)")
    if tcp:
        raise OSError(f"--ros2: no Zenoh router answers at {', '.join(tcp)}: start the ROS 2 "
                      "one (ros2 run rmw_zenoh_cpp rmw_zenohd), or name yours with "
                      f"{OVERRIDE_ENV}='connect/endpoints=[\"tcp/HOST:PORT\"]'")


def dds_type(msgtype: str) -> str:
    """``sensor_msgs/msg/JointState`` as DDS names it: ``sensor_msgs::msg::dds_::JointState_``."""
    pkg, kind, name = msgtype.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def mangle(name: str) -> str:
    """A name as one part of a token: ``/`` written ``%``, empty as ``%``."""
    return name.replace("/", "%") or "%"


def topic_key(domain: int, topic: str, msgtype: str, type_hash: str) -> str:
    """The key expression of a topic's messages."""
    return f"{domain}/{topic.strip('/')}/{dds_type(msgtype)}/{type_hash}"


def node_token(domain: int, zid: str, node: str, *, node_id: int = 0) -> str:
    """The liveliness token of a node in the root namespace (no enclave)."""
    return (f"{ADMIN_SPACE}/{domain}/{zid}/{node_id}/{node_id}/NN/%/%/{mangle(node)}")


def publisher_token(domain: int, zid: str, node: str, entity_id: int, topic: str,
                    msgtype: str, type_hash: str, *, node_id: int = 0) -> str:
    """The liveliness token of a publisher of ``node``."""
    return (f"{ADMIN_SPACE}/{domain}/{zid}/{node_id}/{entity_id}/MP/%/%/{mangle(node)}/"
            f"{mangle(topic)}/{dds_type(msgtype)}/{type_hash}/{QOS}")


def gid(token: str) -> bytes:
    """A publisher's 16-byte GID, as rmw_zenoh makes it: the 128-bit XXH3 hash (seed 0) of
    its liveliness token, the low 64 bits then the high 64 bits, each little-endian. A
    ROS 2 node computes the same GID from the token it discovers, so that the attachment's
    (a message's ``publisher_gid``) names the publisher in the graph."""
    import xxhash

    h = xxhash.xxh3_128_intdigest(token.encode())
    return (h & (1 << 64) - 1).to_bytes(8, "little") + (h >> 64).to_bytes(8, "little")


_ATTACHMENT = struct.Struct("<qqB16s")


def attachment(sequence: int, source_ns: int, gid16: bytes) -> bytes:
    """A message's attachment: sequence number, source timestamp (ns since the epoch),
    GID."""
    return _ATTACHMENT.pack(sequence, source_ns, 16, gid16)


def node_name(unit: str) -> str:
    """The ROS 2 node of unit ``unit``: ``ctrlunit_<unit>``, any character a ROS 2 name
    does not allow written ``_``."""
    return "ctrlunit_" + "".join(c if c.isascii() and (c.isalnum() or c == "_") else "_"
                                 for c in unit)
