"""The lean MCAP writer against the ``mcap`` package's own writer and readers."""

from __future__ import annotations

import io

import lz4.frame
import pytest
import zstandard
from ctrlunit.runtime.recording.mcap_writer import LeanWriter
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.records import Chunk, Message, MessageIndex
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

TOPICS = ("/central/sample", "/peripheral/request", "/central/reply/1", "/signals/state")


def _write(writer_cls: type, messages: list[tuple[int, int, bytes]], *,
           chunk_size: int, compression: str = "none", background: bool = False) -> bytes:
    """The recorder's calls: metadata, two schemas, channels on first use, messages,
    metadata at the end."""
    f = io.BytesIO()
    if writer_cls is LeanWriter:
        w = LeanWriter(f, chunk_size=chunk_size, compression=compression,
                       background=background)
    else:
        w = Writer(f, chunk_size=chunk_size, compression=CompressionType[compression.upper()],
                   enable_data_crcs=True)
    w.start(profile="", library="test")
    w.add_metadata("ctrlunit", {"clock": "freerun"})
    raw = w.register_schema("", "", b"")
    js = w.register_schema("ctrlunit.State", "jsonschema", b'{"type": "object"}')
    channels: dict[int, int] = {}
    for seq, (topic, t, data) in enumerate(messages, 1):
        if topic not in channels:
            channels[topic] = w.register_channel(TOPICS[topic], "json" if topic == 3
                                                 else "msgpack", js if topic == 3 else raw)
        w.add_message(channels[topic], t, data, t, seq)
    w.add_metadata("ctrlunit.result", {"t1_s": "4.8e-05"})
    w.finish()
    return f.getvalue()


def _read(blob: bytes) -> tuple[list, object, list]:
    reader = make_reader(io.BytesIO(blob), validate_crcs=True)
    msgs = [(c.topic, c.message_encoding, s.name if s else None, m.log_time, m.sequence,
             m.data) for s, c, m in reader.iter_messages(log_time_order=False)]
    meta = [(m.name, m.metadata) for m in reader.iter_metadata()]
    return msgs, reader.get_summary().statistics, meta


def _messages(n: int, *, size: int = 120) -> list[tuple[int, int, bytes]]:
    return [(i % len(TOPICS), 1_000_000 + 1000 * i, bytes([i % 251]) * (size + i % 7))
            for i in range(n)]


def _records(blob: bytes) -> list:
    """Chunks (decompressed: the compressors' levels differ) and message indexes."""
    out = []
    for r in StreamReader(io.BytesIO(blob), emit_chunks=True).records:
        if isinstance(r, Chunk):
            data = r.data
            if r.compression == "zstd":
                data = zstandard.ZstdDecompressor().decompress(
                    data, max_output_size=r.uncompressed_size)
            elif r.compression == "lz4":
                data = lz4.frame.decompress(data)
            out.append((r.compression, r.message_start_time, r.message_end_time,
                        r.uncompressed_size, r.uncompressed_crc, bytes(data)))
        elif isinstance(r, MessageIndex):
            out.append(r)
    return out


@pytest.mark.parametrize(("compression", "background"), [
    ("none", False), ("none", True), ("zstd", False), ("zstd", True), ("lz4", True)])
def test_lean_writer_file_reads_back_like_the_reference_writers(compression: str,
                                                                background: bool) -> None:
    msgs = _messages(2000)
    lean = _write(LeanWriter, msgs, chunk_size=4096, compression=compression,
                  background=background)
    ref = _write(Writer, msgs, chunk_size=4096, compression=compression)
    got, want = _read(lean), _read(ref)
    assert got[0] == want[0] and len(got[0]) == 2000
    assert got[1] == want[1]  # statistics: counts per channel, chunks, times
    assert got[2] == want[2]
    # the chunks (their records) and message indexes are byte for byte the reference's
    assert _records(lean) == _records(ref)
    if compression == "none":  # and so is the whole data section
        assert lean[:make_reader(io.BytesIO(lean)).get_summary().chunk_indexes[-1]
                    .chunk_start_offset] == ref[:make_reader(io.BytesIO(ref)).get_summary()
                                                .chunk_indexes[-1].chunk_start_offset]
    else:  # repeated bytes: the chunks shrink
        assert len(lean) < len(_write(LeanWriter, msgs, chunk_size=4096)) / 3


@settings(max_examples=60, deadline=None)
@given(
    msgs=st.lists(st.tuples(st.integers(0, len(TOPICS) - 1), st.integers(0, 2**63),
                            st.binary(max_size=300)), max_size=80),
    chunk_size=st.integers(1, 3000),
    compression=st.sampled_from(["none", "zstd", "lz4"]),
    background=st.booleans(),
)
def test_any_messages_round_trip_through_both_readers(msgs: list, chunk_size: int,
                                                      compression: str,
                                                      background: bool) -> None:
    blob = _write(LeanWriter, msgs, chunk_size=chunk_size, compression=compression,
                  background=background)
    got, stats, meta = _read(blob)
    assert [(TOPICS.index(t), lt, d) for t, _, _, lt, _, d in got] == msgs
    assert stats.message_count == len(msgs)
    assert [m[0] for m in meta] == ["ctrlunit", "ctrlunit.result"]
    # in log-time order through the chunk indexes too
    ordered = [m.log_time for _, _, m in make_reader(io.BytesIO(blob)).iter_messages()]
    assert ordered == sorted(lt for _, lt, _ in msgs)
    # a non-seeking pass sees the same messages
    streamed = [r for r in StreamReader(io.BytesIO(blob)).records if isinstance(r, Message)]
    assert [(m.log_time, m.data) for m in streamed] == [(lt, d) for _, lt, d in msgs]


@pytest.mark.parametrize("compression", ["none", "zstd"])
def test_file_cut_anywhere_keeps_every_closed_chunk(compression: str) -> None:
    """A crash loses the open chunk at most: a non-seeking pass over the file cut at any
    point returns every message of the chunks written whole before the cut."""
    msgs = _messages(300)
    blob = _write(LeanWriter, msgs, chunk_size=2048, compression=compression,
                  background=True)
    summary = make_reader(io.BytesIO(blob)).get_summary()
    assert len(summary.chunk_indexes) >= 10
    for ci in summary.chunk_indexes[::3]:
        cut = ci.chunk_start_offset + ci.chunk_length + ci.message_index_length
        seen = []
        with pytest.raises(Exception):  # noqa: B017  (the reader ends on the cut record)
            for r in StreamReader(io.BytesIO(blob[:cut + 5])).records:
                if isinstance(r, Message):
                    seen.append(r.log_time)
        whole = [m for m in msgs if m[1] <= ci.message_end_time]
        assert seen == [m[1] for m in whole]


@pytest.mark.parametrize("age", [2500, 10_000, 49_000])
def test_a_chunk_closes_by_age_when_it_is_still_small(age: int) -> None:
    # 1 us apart, 100 bytes each: by size alone (64 MiB) everything would be one chunk
    f = io.BytesIO()
    w = LeanWriter(f, chunk_size=64 << 20, chunk_age=age * 1000, compression="zstd")
    w.start()
    cid = w.register_channel("/x", "msgpack", 0)
    for i in range(50_000):
        w.add_message(cid, 1_000_000 + 1000 * i, bytes([i % 256]) * 100, 0)
    w.finish()
    reader = make_reader(io.BytesIO(f.getvalue()), validate_crcs=True)
    chunks = reader.get_summary().chunk_indexes
    # each chunk spans exactly `age` messages, the last the rest
    assert [(c.message_end_time - c.message_start_time) // 1000 for c in chunks[:-1]] \
        == [age] * (len(chunks) - 1)
    assert len(chunks) == -(-50_000 // (age + 1))
    assert sum(1 for _ in reader.iter_messages()) == 50_000


def test_unknown_channel_and_bad_chunk_size_are_named() -> None:
    w = LeanWriter(io.BytesIO())
    w.start()
    with pytest.raises(ValueError, match="channel_id 7 is not registered"):
        w.add_message(7, 0, b"", 0)
    with pytest.raises(ValueError, match="schema_id 3 is not registered"):
        w.register_channel("/x", "msgpack", 3)
    with pytest.raises(ValueError, match="chunk_size must be >= 1"):
        LeanWriter(io.BytesIO(), chunk_size=0)
    with pytest.raises(ValueError, match="chunk_age must be >= 0 or None, got -1"):
        LeanWriter(io.BytesIO(), chunk_age=-1)
    with pytest.raises(ValueError, match="compression must be one of none, lz4, zstd, got 'gz'"):
        LeanWriter(io.BytesIO(), compression="gz")


def test_a_failed_background_write_is_reported_not_lost() -> None:
    class Full(io.BytesIO):
        def write(self, b: bytes) -> int:  # type: ignore[override]
            if self.tell() > 3000:
                raise OSError(28, "No space left on device")
            return super().write(b)

    w = LeanWriter(Full(), chunk_size=512, compression="zstd", background=True)
    w.start()
    cid = w.register_channel("/x", "msgpack", 0)
    with pytest.raises(RuntimeError, match="No space left on device"):
        for i in range(10_000):
            w.add_message(cid, i, bytes(range(256)) * 4, i)
        w.finish()


def test_the_writer_thread_runs_its_set_up_hook_before_every_job() -> None:
    """The recorder sets the writer thread's policy this way (runtime/host/sched.py, leave_rt):
    the hook runs on the writer thread, never on the caller's, once before each job."""
    import threading

    seen: list[int] = []
    f = io.BytesIO()
    w = LeanWriter(f, chunk_size=64, compression="none", background=True,
                   before_job=lambda: seen.append(threading.get_ident()))
    w.start(profile="", library="test")
    cid = w.register_channel("/t", "msgpack", w.register_schema("", "", b""))
    for k in range(10):
        w.add_message(cid, k, b"x" * 40, k)  # 40 bytes over a 64-byte chunk: a chunk each
    w.finish()
    assert len(seen) >= 10 and threading.get_ident() not in seen and len(set(seen)) == 1
    assert len(list(StreamReader(io.BytesIO(f.getvalue())).records)) > 10
