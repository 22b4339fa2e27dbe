"""Reading a recording: the seeking reader when the file is whole, a salvaging
non-seeking pass when it was cut off (the seeking reader needs the footer).

:mod:`.recorded_report` rebuilds the run's report from it.
"""

from __future__ import annotations

import json
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack
from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata
from mcap.stream_reader import StreamReader

from ...plant.limits import check_command
from ..central.intake import check_sample
from ..transport.codec import MAX_CYCLE, BadMessage


def _cycle_ok(m: dict[str, Any]) -> bool:
    k = m.get("cycle")
    return type(k) is int and 0 <= k < MAX_CYCLE


def _sample_ok(m: dict[str, Any]) -> bool:
    """A sample as the central takes one (runtime/central/intake.py, ``check_sample``), or
    one it made itself (``synthetic``: freerun's, with counts and a time alone)."""
    if m.get("synthetic") is True:  # its counts and time, checked as a plant's are
        m = m | {"p": [0.0, 0.0, 0.0], "span": [0, 0]}
    try:
        check_sample(m)
    except BadMessage:
        return False
    return _cycle_ok(m)


def _command_ok(m: dict[str, Any]) -> bool:
    """A command as the plant takes one (plant/limits.py, ``check_command``)."""
    return _cycle_ok(m) and check_command(m.get("tau")) is None


def _stage_ok(m: Any) -> bool:
    return isinstance(m, dict) and _cycle_ok(m) and type(m.get("stage")) is int


def _parts_ok(m: dict[str, Any]) -> bool:
    """A request or a reply: its parts, each a round's cycle, stage and values."""
    parts = m.get("parts")
    return isinstance(parts, list) and all(
        _stage_ok(p) and isinstance(p.get("vals", {}), dict) for p in parts)


def _trace_ok(m: dict[str, Any]) -> bool:
    """The central's traced outputs of an interval."""
    return _cycle_ok(m) and isinstance(m.get("vals"), dict)


CHECKED: dict[str, Callable[[dict[str, Any]], bool]] = {
    "/central/sample": _sample_ok, "/plant/command": _command_ok,
    "/peripheral/request": _parts_ok, "/central/reply/": _parts_ok,
    "/trace/central": _trace_ok}
"""The wire's messages that readers take fields from, each with the live check (the
replies under their prefix): a file edited to hold a field of another shape is then a
message missing, which ``replay --verify`` names, not a traceback."""


@dataclass
class Recording:
    """Messages by topic (``(log_time_ns, raw bytes)`` in file order) and metadata."""

    path: str
    topics: dict[str, list[tuple[int, bytes]]] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    salvaged: bool = False
    damaged: bool = False
    """The file is whole (it ends with MCAP's magic) yet could not be read whole: its
    content was changed or corrupted, not cut off by a crash."""
    note: str = ""

    def decoded(self, topic: str) -> list[tuple[int, dict]]:
        """Messages of ``topic`` decoded from msgpack; bad ones skipped: undecodable, not
        a map, and for a sample or a command what the live roles would refuse
        (:data:`CHECKED`), so that no reader of a forged file meets a field of the wrong
        type."""
        check = CHECKED.get("/central/reply/" if topic.startswith("/central/reply/") else topic)
        out = []
        for t, data in self.topics.get(topic, []):
            try:
                m = msgpack.unpackb(data, raw=False)
            except Exception:
                continue
            if isinstance(m, dict) and (check is None or check(m)):
                out.append((t, m))
        return out

    @property
    def config(self) -> dict[str, Any]:
        """The run's configuration (the ``ctrlunit`` metadata record's ``config``).

        Raises
        ------
        ValueError
            If the recording holds none, or one that is not a JSON object."""
        text = self.metadata.get("ctrlunit", {}).get("config")
        if text is None:
            raise ValueError(f"{self.path}: no run configuration in it (the metadata record "
                             "ctrlunit, field config): not a recording of ctrlunit start")
        try:
            config = json.loads(text)
        except ValueError:
            config = None
        if not isinstance(config, dict):
            raise ValueError(f"{self.path}: its run configuration (metadata ctrlunit, field "
                             f"config) is not a JSON object: {text[:60]!r}")
        return config


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
            reader = make_reader(fh, validate_crcs=True)
            for _schema, channel, msg in reader.iter_messages(log_time_order=False):
                rec.topics.setdefault(channel.topic, []).append((msg.log_time, msg.data))
            for m in reader.iter_metadata():
                rec.metadata[m.name] = dict(m.metadata)
        if (why := _crc_damage(path)) is not None:  # the records themselves are whole
            rec.damaged = True
            rec.note = (f"{path} is damaged: {why}; every chunk passed its CRC, and all "
                        f"{len(rec.topics.get('/plant/command', []))} intervals were read")
        return rec
    except Exception as exc:
        first_error = exc
    rec = Recording(path, salvaged=True)
    channels: dict[int, str] = {}
    try:
        with open(path, "rb") as fh:
            for record in StreamReader(fh, skip_magic=False, validate_crcs=True).records:
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
        if _begins_mcap(path) and _ends_whole(path):  # written whole, damaged near its start
            raise ValueError(f"{path}: the recording is damaged ({_said(first_error)}) before its "
                             "first record: the file is whole, so it was changed or "
                             "corrupted, not cut off; there is nothing to replay or report")
        if _begins_mcap(path):  # a recording's first bytes, then nothing whole
            raise ValueError(f"{path}: the recording was cut off before its first interval "
                             "was written (it holds MCAP's header and no record whole): "
                             "there is nothing to replay or report")
        raise ValueError(f"{path}: not a readable MCAP recording ({_said(first_error)})")
    rec.damaged = _ends_whole(path)
    n = len(rec.topics.get("/plant/command", []))
    if n == 0:
        raise ValueError(f"{path}: " + (
            f"the recording is damaged ({_said(first_error)}) before its first interval"
            if rec.damaged else "the recording was cut off before its first interval was "
            "written") + ": there is nothing to replay or report")
    rec.note = (f"{path} is damaged: the file is whole, but {_said(first_error)}; salvaged {n} "
                "intervals before the damage with a non-seeking pass" if rec.damaged else
                f"{path} has no footer (the recording was cut off); salvaged {n} intervals "
                "with a non-seeking pass")
    return rec


def _said(exc: Exception) -> str:
    """An exception as a reader of the note can take it: its message, or its kind where
    it has none (the MCAP reader raises some without one)."""
    return str(exc) or f"the MCAP reader's {type(exc).__name__}"


MAGIC = b"\x89MCAP0\r\n"
"""What begins and ends a whole MCAP file."""


def _begins_mcap(path: str) -> bool:
    """Whether the file begins with MCAP's magic."""
    try:
        with open(path, "rb") as fh:
            return fh.read(len(MAGIC)) == MAGIC
    except OSError:
        return False


def _ends_whole(path: str) -> bool:
    """Whether the file ends with MCAP's magic, as only a file written to its end does."""
    try:
        with open(path, "rb") as fh:
            fh.seek(0, 2)
            if fh.tell() < 2 * len(MAGIC):
                return False
            fh.seek(-len(MAGIC), 2)
            return fh.read() == MAGIC
    except OSError:
        return False


FOOTER = struct.Struct("<BQQQI")
"""MCAP's footer record before the closing magic: opcode 0x02, its length (20), where the
summary section starts, where its offsets start, and the summary's CRC-32."""

DATA_END = struct.Struct("<BQI")
"""MCAP's DataEnd record, the data section's last: opcode 0x0F, its length (4), and the
CRC-32 of every byte of the file before it."""


def _crc(fh: Any, start: int, stop: int) -> int:
    """CRC-32 of bytes ``[start, stop)`` of ``fh``, read a block at a time: a recording may
    be larger than the memory one should take to check it."""
    fh.seek(start)
    crc, left = 0, stop - start
    while left > 0 and (block := fh.read(min(left, 1 << 20))):
        crc, left = zlib.crc32(block, crc), left - len(block)
    return crc


def _crc_damage(path: str) -> str | None:
    """Why a whole file fails one of MCAP's two file-wide CRCs, or None. The seeking reader
    checks each chunk's CRC and neither of these, so a byte changed outside the chunks
    went unnoticed: in the summary section (the indexes, the statistics; the footer's
    ``summary_crc``, every byte from the summary's start through the footer's
    ``summary_offset_start``) or in a record between the chunks, such as the run's result
    record (DataEnd's ``data_section_crc``). A CRC left at 0 (not computed, as MCAP allows
    and other writers do: a file rewritten by a tool) is not checked."""
    with open(path, "rb") as fh:
        end = fh.seek(0, 2) - len(MAGIC) - FOOTER.size
        if end < len(MAGIC) + DATA_END.size:
            return None
        fh.seek(end)
        opcode, length, start, _offsets, crc = FOOTER.unpack(fh.read(FOOTER.size))
        if opcode != 0x02 or length != FOOTER.size - 9:
            return "its footer is not MCAP's"
        if start and not len(MAGIC) + DATA_END.size <= start <= end:
            return f"its footer places the summary at byte {start}, outside the file"
        if start and crc and (got := _crc(fh, start, end + FOOTER.size - 4)) != crc:
            return f"its summary section's CRC is {got:08x}, the footer says {crc:08x}"
        data_end = (start or end) - DATA_END.size
        fh.seek(data_end)
        opcode, length, crc = DATA_END.unpack(fh.read(DATA_END.size))
        if opcode != 0x0F or length != DATA_END.size - 9:
            return f"no DataEnd record where its data section ends (byte {data_end})"
        if crc and (got := _crc(fh, 0, data_end)) != crc:
            return f"its data section's CRC is {got:08x}, its DataEnd says {crc:08x}"
    return None
