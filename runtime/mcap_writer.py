"""A lean MCAP writer for the recorder's hot path.

The recorder writes about nine messages per interval on the central's thread. The ``mcap``
package's :class:`mcap.writer.Writer` builds each one as a dataclass and six separate
``struct`` writes into a ``BytesIO`` (about 15-20 us a message in a run here, three
quarters of what recording cost per interval). :class:`LeanWriter` packs a Message record
with one ``struct`` call into the open chunk and keeps the chunk's message indexes as flat
lists; a closed chunk and its Message Index records are packed the same way and written in
one call. The records written once per file (header, schemas, channels, metadata, data
end, summary, footer) are serialised by the ``mcap`` package's own record classes. The
layout is the reference writer's with chunking, no compression and CRCs on: schemas and
channels inside the chunk where they first appear (a chunk read alone is
self-contained), a Message Index per channel after each chunk, and a summary with
schemas, channels, statistics, chunk and metadata indexes and summary offsets. Its chunk
and Message Index records are byte for byte the reference's (tested).

Call contract: the same methods the recorder used on :class:`mcap.writer.Writer`
(``start``, ``register_schema``, ``register_channel``, ``add_message``, ``add_metadata``,
``finish``); ``finish`` does not close the stream.
"""

from __future__ import annotations

import struct
import zlib
from typing import IO

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

MAGIC = b"\x89MCAP0\r\n"
_MESSAGE = struct.Struct("<BQHIQQ")  # opcode, record length, channel, sequence, log, publish
_MESSAGE_FIXED = 2 + 4 + 8 + 8
_FOOTER_HEAD = struct.Struct("<BQQQ")
# opcode, length, start, end, uncompressed size, CRC, compression "" (u32 0), records length
_CHUNK_HEAD = struct.Struct("<BQQQQIIQ")
_CHUNK_FIXED = 8 + 8 + 8 + 4 + 4 + 8
_U64_MAX = (1 << 64) - 1


class LeanWriter:
    """Write an MCAP file: chunked, uncompressed, CRCs on.

    Parameters
    ----------
    stream : a binary file opened for writing (``tell`` is not needed).
    chunk_size : a chunk is closed once its records exceed this many bytes.
    """

    def __init__(self, stream: IO[bytes], *, chunk_size: int = 1024 * 1024) -> None:
        if chunk_size < 1:
            raise ValueError(f"chunk_size must be >= 1 byte, got {chunk_size}")
        self._stream = stream
        self._chunk_size = chunk_size
        self._pos = 0  # bytes written to the stream
        self._crc = 0  # CRC32 of the data section so far
        self._chunk = bytearray()
        self._chunk_index: dict[int, list[int]] = {}  # channel -> [log, offset, log, ...]
        self._chunk_start = _U64_MAX
        self._chunk_end = 0
        self._chunk_messages = 0
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._counts: dict[int, int] = {}
        self._messages = 0
        self._start = _U64_MAX
        self._end = 0
        self._chunks = 0
        self._started = False
        self._finished = False

    # -- low level ----------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        self._stream.write(data)
        self._crc = zlib.crc32(data, self._crc)
        self._pos += len(data)

    @staticmethod
    def _record(record: object) -> bytes:
        rb = RecordBuilder()
        record.write(rb)  # type: ignore[attr-defined]
        return rb.end()

    # -- the writer's calls -------------------------------------------------------------

    def start(self, *, profile: str = "", library: str = "") -> None:
        """Write the magic and the Header record."""
        if self._started:
            raise RuntimeError("start() was already called")
        self._started = True
        self._write(MAGIC)
        self._write(self._record(Header(profile=profile, library=library)))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """A new schema; returns its id (1, 2, ...; 0 means no schema)."""
        sid = len(self._schemas) + 1
        schema = Schema(id=sid, name=name, encoding=encoding, data=data)
        self._schemas[sid] = schema
        self._chunk += self._record(schema)
        return sid

    def register_channel(self, topic: str, message_encoding: str, schema_id: int, *,
                         metadata: dict[str, str] | None = None) -> int:
        """A new channel; returns its id (1, 2, ...)."""
        if schema_id != 0 and schema_id not in self._schemas:
            raise ValueError(f"schema_id {schema_id} is not registered (0 or one of "
                             f"{sorted(self._schemas)})")
        cid = len(self._channels) + 1
        channel = Channel(id=cid, schema_id=schema_id, topic=topic,
                          message_encoding=message_encoding, metadata=dict(metadata or {}))
        self._channels[cid] = channel
        self._counts[cid] = 0
        self._chunk += self._record(channel)
        return cid

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int,
                    sequence: int = 0) -> None:
        """Append one Message record to the open chunk (closed past ``chunk_size``)."""
        count = self._counts.get(channel_id)
        if count is None:
            raise ValueError(f"channel_id {channel_id} is not registered "
                             f"(one of {sorted(self._channels)})")
        self._counts[channel_id] = count + 1
        chunk = self._chunk
        index = self._chunk_index.get(channel_id)
        if index is None:
            index = self._chunk_index[channel_id] = []
        index.append(log_time)
        index.append(len(chunk))
        chunk += _MESSAGE.pack(Opcode.MESSAGE, _MESSAGE_FIXED + len(data), channel_id,
                               sequence, log_time, publish_time)
        chunk += data
        if log_time < self._chunk_start:
            self._chunk_start = log_time
        if log_time > self._chunk_end:
            self._chunk_end = log_time
        self._chunk_messages += 1
        if len(chunk) > self._chunk_size:
            self._close_chunk()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A Metadata record in the data section, indexed in the summary."""
        record = self._record(Metadata(name=name, metadata=dict(data)))
        self._metadata_indexes.append(MetadataIndex(offset=self._pos, length=len(record),
                                                    name=name))
        self._write(record)

    def finish(self) -> None:
        """Close the open chunk; write Data End, the summary, the footer and the magic."""
        if self._finished:
            return
        self._finished = True
        self._close_chunk()
        self._write(self._record(DataEnd(data_section_crc=self._crc)))
        summary_start = self._pos
        groups: list[tuple[int, list[bytes]]] = [
            (Opcode.SCHEMA, [self._record(s) for s in self._schemas.values()]),
            (Opcode.CHANNEL, [self._record(c) for c in self._channels.values()]),
            (Opcode.STATISTICS, [self._record(Statistics(
                message_count=self._messages,
                schema_count=len(self._schemas),
                channel_count=len(self._channels),
                attachment_count=0,
                metadata_count=len(self._metadata_indexes),
                chunk_count=self._chunks,
                message_start_time=self._start if self._messages else 0,
                message_end_time=self._end,
                channel_message_counts={c: n for c, n in self._counts.items() if n}))]),
            (Opcode.CHUNK_INDEX, [self._record(c) for c in self._chunk_indexes]),
            (Opcode.METADATA_INDEX, [self._record(m) for m in self._metadata_indexes]),
        ]
        summary = bytearray()
        offsets = []
        for opcode, records in groups:
            if not records:
                continue
            start = summary_start + len(summary)
            for r in records:
                summary += r
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=start,
                                         group_length=summary_start + len(summary) - start))
        offset_start = summary_start + len(summary)
        for o in offsets:
            summary += self._record(o)
        crc = zlib.crc32(bytes(summary))
        crc = zlib.crc32(_FOOTER_HEAD.pack(Opcode.FOOTER, 20, summary_start, offset_start),
                         crc)
        self._stream.write(bytes(summary))
        self._stream.write(self._record(Footer(summary_start=summary_start,
                                               summary_offset_start=offset_start,
                                               summary_crc=crc)))
        self._stream.write(MAGIC)

    # -- chunks -------------------------------------------------------------------------

    def _close_chunk(self) -> None:
        """Write the open chunk and its message indexes; records its Chunk Index."""
        if not self._chunk_messages:  # schemas or channels alone wait for the next chunk
            return
        records = self._chunk
        size = len(records)
        head = _CHUNK_HEAD.pack(Opcode.CHUNK, _CHUNK_FIXED + size, self._chunk_start,
                                self._chunk_end, size, zlib.crc32(records), 0, size)
        chunk_start = self._pos
        chunk_length = len(head) + size
        offsets: dict[int, int] = {}
        indexes = []
        pos = chunk_start + chunk_length
        for cid, flat in self._chunk_index.items():  # in order of first use, as mcap's
            n = len(flat)
            offsets[cid] = pos
            indexes.append(struct.pack(f"<BQHI{n}Q", Opcode.MESSAGE_INDEX, 6 + 8 * n, cid,
                                       8 * n, *flat))
            pos += 15 + 8 * n
        index_start = chunk_start + chunk_length
        self._write(b"".join([head, records, *indexes]))
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=self._chunk_start, message_end_time=self._chunk_end,
            chunk_start_offset=chunk_start, chunk_length=chunk_length,
            message_index_offsets=offsets, message_index_length=self._pos - index_start,
            compression="", compressed_size=size, uncompressed_size=size))
        self._chunks += 1
        self._messages += self._chunk_messages
        self._start = min(self._start, self._chunk_start)
        self._end = max(self._end, self._chunk_end)
        self._chunk = bytearray()
        self._chunk_index = {}
        self._chunk_start = _U64_MAX
        self._chunk_end = 0
        self._chunk_messages = 0
