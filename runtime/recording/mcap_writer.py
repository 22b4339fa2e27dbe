"""A lean MCAP writer for the recorder's hot path.

The recorder writes about nine messages per interval on the central's thread. The ``mcap``
package's :class:`mcap.writer.Writer` builds each one as a dataclass and six separate
``struct`` writes into a ``BytesIO`` (about 15-20 us a message in a run here, three
quarters of what recording cost per interval). :class:`LeanWriter` packs a Message record
with one ``struct`` call into the open chunk and keeps the chunk's message indexes as flat
lists; a closed chunk and its Message Index records are packed the same way and written in
one call. The records written once per file (header, schemas, channels, metadata, data
end, summary, footer) are serialised by the ``mcap`` package's own record classes. The
layout is the reference writer's with chunking and CRCs on: schemas and channels inside
the chunk where they first appear (a chunk read alone is self-contained), a Message Index
per channel after each chunk (Foxglove's indexed reader finds messages through them), and
a summary with schemas, channels, statistics, chunk and metadata indexes and summary
offsets. Its chunk and Message Index records are byte for byte the reference's,
uncompressed and compressed (tested).

Chunks are compressed with MCAP's own chunk compression (``zstd`` or ``lz4``, the names the
MCAP specification gives), which the ``mcap`` reader and Foxglove read. With
``background=True`` every write to the stream (and the compression of each closed chunk)
happens on one writer thread, in the order the calls were made: the caller's thread only
appends to the open chunk; zstandard and lz4 release the GIL while they compress.

Call contract: the same methods the recorder used on :class:`mcap.writer.Writer`
(``start``, ``register_schema``, ``register_channel``, ``add_message``, ``add_metadata``,
``finish``); ``finish`` does not close the stream.
"""

from __future__ import annotations

import queue
import struct
import threading
import zlib
from collections.abc import Callable
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

from ..config import COMPRESSIONS

MAGIC = b"\x89MCAP0\r\n"
_MESSAGE = struct.Struct("<BQHIQQ")  # opcode, record length, channel, sequence, log, publish
_MESSAGE_FIXED = 2 + 4 + 8 + 8
_FOOTER_HEAD = struct.Struct("<BQQQ")
# opcode, length, start, end, uncompressed size, uncompressed CRC (then the compression's
# name as u32 length + bytes, then the records' length as u64)
_CHUNK_HEAD = struct.Struct("<BQQQQI")
_CHUNK_FIXED = 8 + 8 + 8 + 4 + 4 + 8
_U64_MAX = (1 << 64) - 1


ZSTD_LEVEL = 3
"""zstd level of the chunks (zstd's default): a recording's 256 KiB chunks compress 3.07x
with their message indexes, for 15 us of the writer thread's time per interval; level 6 gains
1.5 % for 2.4 times the time (docs/measurements/2026-11-23-recording.md)."""


def compressor(name: str) -> Callable[[bytes | bytearray], bytes] | None:
    """The function that compresses one chunk's records for ``name`` (None for ``none``).

    Raises
    ------
    ValueError
        If ``name`` is not one of :data:`COMPRESSIONS`.
    """
    if name == "none":
        return None
    if name == "zstd":
        import zstandard

        return zstandard.ZstdCompressor(level=ZSTD_LEVEL).compress
    if name == "lz4":
        import lz4.frame

        return lz4.frame.compress
    raise ValueError(f"compression must be one of {', '.join(COMPRESSIONS)}, got {name!r}")


class _Worker:
    """A writer thread that runs jobs in the order submitted; an error in one is raised
    to the caller at its next call (no later job runs)."""

    def __init__(self, before_job: Callable[[], None] | None) -> None:
        self._before_job = before_job
        # bounded: a disk slower than the run holds the caller back, never eats memory
        self._jobs: queue.Queue[Callable[[], None] | None] = queue.Queue(maxsize=64)
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._work, name="mcap-writer", daemon=True)
        self._thread.start()

    def _raise(self) -> None:
        if self._error is not None:
            raise RuntimeError(f"the MCAP writer thread failed: {self._error!r}") \
                from self._error

    def submit(self, job: Callable[[], None]) -> None:
        """Run ``job`` after those submitted before it."""
        self._raise()
        self._jobs.put(job)

    def finish(self) -> None:
        """Wait for every job submitted, then end the thread."""
        self._jobs.put(None)
        self._thread.join()
        self._raise()

    def _work(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            if self._error is None:
                try:
                    if self._before_job is not None:
                        self._before_job()
                    job()
                except BaseException as exc:  # reported to the caller at its next call
                    self._error = exc


class LeanWriter:
    """Write an MCAP file: chunked, CRCs on, chunks compressed or not.

    Parameters
    ----------
    stream : a binary file opened for writing (``tell`` is not needed).
    chunk_size : a chunk is closed once its (uncompressed) records exceed this many bytes.
    chunk_age : a chunk is also closed once a message's log time is this many (log time
        units, ns in a recording) past the chunk's first; None: by size alone. This bounds
        in time what a file cut off mid-run loses, whatever the message rate.
    compression : one of :data:`COMPRESSIONS`.
    background : write (and compress) on a writer thread; :meth:`finish` waits for it.
    before_job : called on the writer thread before each job (with ``background``): the
        caller's hook to set that thread up, e.g. its scheduling policy.
    """

    def __init__(self, stream: IO[bytes], *, chunk_size: int = 1024 * 1024,
                 chunk_age: int | None = None, compression: str = "none",
                 background: bool = False,
                 before_job: Callable[[], None] | None = None) -> None:
        if chunk_size < 1:
            raise ValueError(f"chunk_size must be >= 1 byte, got {chunk_size}")
        if chunk_age is not None and chunk_age < 0:
            raise ValueError(f"chunk_age must be >= 0 or None, got {chunk_age}")
        self._chunk_age = _U64_MAX if chunk_age is None else chunk_age
        self._compress = compressor(compression)
        self._compression = b"" if compression == "none" else compression.encode()
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
        self._worker = _Worker(before_job) if background else None

    # -- low level ----------------------------------------------------------------------

    def _write(self, data: bytes | bytearray) -> None:
        self._stream.write(data)
        self._crc = zlib.crc32(data, self._crc)
        self._pos += len(data)

    def _submit(self, job: Callable[[], None]) -> None:
        """Run ``job`` (a write to the stream) now, or in order on the writer thread."""
        if self._worker is None:
            job()
        else:
            self._worker.submit(job)

    def flush(self) -> None:
        """Flush the stream once the writes asked for so far are done."""
        self._submit(self._stream.flush)

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
        header = MAGIC + self._record(Header(profile=profile, library=library))
        self._submit(lambda: self._write(header))

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
        """Append one Message record to the open chunk (closed past ``chunk_size`` or
        ``chunk_age``)."""
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
        if len(chunk) > self._chunk_size or log_time - self._chunk_start >= self._chunk_age:
            self._close_chunk()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A Metadata record in the data section, indexed in the summary."""
        record = self._record(Metadata(name=name, metadata=dict(data)))

        def write() -> None:
            self._metadata_indexes.append(MetadataIndex(offset=self._pos,
                                                        length=len(record), name=name))
            self._write(record)

        self._submit(write)

    def finish(self) -> None:
        """Close the open chunk; write Data End, the summary, the footer and the magic."""
        if self._finished:
            return
        self._finished = True
        self._close_chunk()
        if self._worker is not None:
            self._worker.finish()
            self._worker = None
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
        """Hand the open chunk to :meth:`_write_chunk` and start a new one."""
        if not self._chunk_messages:  # schemas or channels alone wait for the next chunk
            return
        job = (self._chunk, self._chunk_index, self._chunk_start, self._chunk_end)
        self._chunks += 1
        self._messages += self._chunk_messages
        self._start = min(self._start, self._chunk_start)
        self._end = max(self._end, self._chunk_end)
        self._chunk = bytearray()
        self._chunk_index = {}
        self._chunk_start = _U64_MAX
        self._chunk_end = 0
        self._chunk_messages = 0
        self._submit(lambda: self._write_chunk(*job))

    def _write_chunk(self, records: bytearray, chunk_index: dict[int, list[int]], start: int,
                     end: int) -> None:
        """Write one chunk (compressed if asked) and its message indexes; record its
        Chunk Index."""
        size = len(records)
        data = records if self._compress is None else self._compress(records)
        name = self._compression
        head = (_CHUNK_HEAD.pack(Opcode.CHUNK, _CHUNK_FIXED + len(name) + len(data), start,
                                 end, size, zlib.crc32(records))
                + struct.pack("<I", len(name)) + name + struct.pack("<Q", len(data)))
        chunk_start = self._pos
        chunk_length = len(head) + len(data)
        offsets: dict[int, int] = {}
        indexes = []
        pos = chunk_start + chunk_length
        for cid, flat in chunk_index.items():  # in order of first use, as mcap's
            n = len(flat)
            offsets[cid] = pos
            indexes.append(struct.pack(f"<BQHI{n}Q", Opcode.MESSAGE_INDEX, 6 + 8 * n, cid,
                                       8 * n, *flat))
            pos += 15 + 8 * n
        index_start = chunk_start + chunk_length
        self._write(b"".join([head, data, *indexes]))
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=start, message_end_time=end,
            chunk_start_offset=chunk_start, chunk_length=chunk_length,
            message_index_offsets=offsets, message_index_length=self._pos - index_start,
            compression=name.decode(), compressed_size=len(data), uncompressed_size=size))
