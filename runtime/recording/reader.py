"""Reading a recording: the seeking reader when the file is whole, a salvaging
non-seeking pass when it was cut off (the seeking reader needs the footer).

:mod:`.recorded_report` rebuilds the run's report from it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack
from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata
from mcap.stream_reader import StreamReader


@dataclass
class Recording:
    """Messages by topic (``(log_time_ns, raw bytes)`` in file order) and metadata."""

    path: str
    topics: dict[str, list[tuple[int, bytes]]] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    salvaged: bool = False
    note: str = ""

    def decoded(self, topic: str) -> list[tuple[int, dict]]:
        """Messages of ``topic`` decoded from msgpack (bad ones skipped)."""
        out = []
        for t, data in self.topics.get(topic, []):
            try:
                out.append((t, msgpack.unpackb(data, raw=False)))
            except Exception:
                continue
        return out

    @property
    def config(self) -> dict[str, Any]:
        return json.loads(self.metadata.get("ctrlunit", {}).get("config", "{}"))


def read(path: str | Path) -> Recording:
    """Read a recording; salvage it with a non-seeking pass if it has no footer.

    Raises
    ------
    ValueError
        If the file is not an MCAP recording at all.
    """
    path = str(path)
    rec = Recording(path)
    try:
        with open(path, "rb") as fh:
            reader = make_reader(fh)
            for _schema, channel, msg in reader.iter_messages(log_time_order=False):
                rec.topics.setdefault(channel.topic, []).append((msg.log_time, msg.data))
            for m in reader.iter_metadata():
                rec.metadata[m.name] = dict(m.metadata)
        return rec
    except Exception as exc:
        first_error = exc
    rec = Recording(path, salvaged=True)
    channels: dict[int, str] = {}
    try:
        with open(path, "rb") as fh:
            for record in StreamReader(fh, skip_magic=False).records:
                if isinstance(record, Message):
                    topic = channels.get(record.channel_id)
                    if topic is not None:
                        rec.topics.setdefault(topic, []).append((record.log_time, record.data))
                elif isinstance(record, Metadata):
                    rec.metadata[record.name] = dict(record.metadata)
                elif isinstance(record, Channel):
                    channels[record.id] = record.topic
    except Exception as exc:
        rec.note = f"{type(exc).__name__}"
    if not rec.metadata and not rec.topics:
        raise ValueError(f"{path}: not a readable MCAP recording ({first_error})")
    n = len(rec.topics.get("/plant/command", []))
    if n == 0:
        raise ValueError(f"{path}: the recording was cut off before its first interval was "
                         "written: there is nothing to replay or report")
    rec.note = (f"{path} has no footer (the recording was cut off); salvaged {n} intervals "
                "with a non-seeking pass")
    return rec
