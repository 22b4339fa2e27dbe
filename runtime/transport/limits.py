"""What a role's Zenoh session accepts from its links: the bounds ``make_config`` gives
Zenoh, each a setting of the run file's ``transport`` section (runtime/config/sections.py),
and the bound on a sender's malformed messages that the central applies itself
(runtime/central/flood.py).

The unit's largest message is a role's final report or the configuration order the
central hands a role at its handshake, 1-2 KB (measured: the ``config`` order of the
default run 808 bytes, a peripheral's ``bye`` with twenty rejection reasons 1358); every
other message is smaller, and the codec refuses anything over
:data:`~.codec.MAX_MESSAGE_BYTES` (64 KiB) whatever Zenoh delivers. What Zenoh 1.10.2 does
with each bound, as measured, is in docs/faults-and-errors.md (Security).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from .codec import MAX_MESSAGE_BYTES

MAX_MESSAGE_SIZE = MAX_MESSAGE_BYTES
"""Default ``transport/link/rx/max_message_size`` (bytes): the codec's own bound, 30 times
the unit's largest message (Zenoh's default: 1 GiB)."""

MAX_MESSAGE_SIZE_MIN = 16 * 1024
"""The smallest bound allowed: room for the unit's largest message (1-2 KB) eight times
over, so that no setting can drop the unit's own traffic."""

MAX_SESSIONS = 16
"""Default ``transport/unicast/max_sessions``: the central's peers are the plant, at most
three peripherals and a few observers (Zenoh's default: 1000)."""

ACCEPT_PENDING = 8
"""Default ``transport/unicast/accept_pending``: handshakes under way at once; the unit's
roles say hello one after the other (Zenoh's default: 100)."""

ACCEPT_TIMEOUT_S = 2.0
"""Default ``transport/unicast/accept_timeout``: a handshake not complete by then is
dropped (Zenoh's default: 10 s; a TLS handshake on a loopback link takes milliseconds)."""

REJECT_LIMIT = 20
"""Default bound of the central's flood rule: a peripheral or the plant whose malformed
messages exceed this many within a second is a fault by name (a role of the unit sends
none)."""


@dataclass(frozen=True)
class Limits:
    """The bounds a Zenoh session of the unit is opened with.

    Attributes
    ----------
    max_message_size : the largest message (bytes, after reassembly) a link may deliver.
    max_sessions : the most peers a session holds at once.
    accept_pending : the most handshakes under way at once.
    accept_timeout : seconds a handshake may take before it is dropped.
    """

    max_message_size: int = MAX_MESSAGE_SIZE
    max_sessions: int = MAX_SESSIONS
    accept_pending: int = ACCEPT_PENDING
    accept_timeout: float = ACCEPT_TIMEOUT_S

    @classmethod
    def of(cls, transport: Any) -> Limits:
        """The limits of a run's ``transport`` section (its fields of the same names)."""
        return cls(max_message_size=transport.max_message_size,
                   max_sessions=transport.max_sessions,
                   accept_pending=transport.accept_pending,
                   accept_timeout=transport.accept_timeout)

    def entries(self) -> dict[str, str]:
        """Zenoh's configuration keys and their JSON values (checked against
        ``zenoh.Config().get_json(key)`` of eclipse-zenoh 1.10.2: each key exists)."""
        return {
            "transport/link/rx/max_message_size": json.dumps(int(self.max_message_size)),
            "transport/unicast/max_sessions": json.dumps(int(self.max_sessions)),
            "transport/unicast/accept_pending": json.dumps(int(self.accept_pending)),
            "transport/unicast/accept_timeout": json.dumps(
                max(1, round(self.accept_timeout * 1000))),
        }

    def apply(self, conf: Any) -> None:
        """Write the limits into a ``zenoh.Config``."""
        for key, value in self.entries().items():
            conf.insert_json5(key, value)


__all__ = ["ACCEPT_PENDING", "ACCEPT_TIMEOUT_S", "MAX_MESSAGE_SIZE", "MAX_MESSAGE_SIZE_MIN",
           "MAX_SESSIONS", "REJECT_LIMIT", "Limits"]
