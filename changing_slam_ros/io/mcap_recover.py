"""What can still be read of a truncated or damaged mcap file, copied into a complete one.

A recording cut short (the recorder killed, the disk full) lacks its summary and footer and may end inside a
chunk; `BagMessages` refuses it. `recover_mcap` reads the file front to back with the mcap library's streaming
reader (no summary needed, CRCs not checked), copies every schema, channel and message up to the first record
that cannot be read, and writes them into a new mcap with a summary (atomically: `io.atomic`). Messages of a
chunk the file ends inside are lost; everything before it is kept byte for byte. `changing-slam convert
--recover` runs it.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from changing_slam_ros.errors import BagError
from changing_slam_ros.io.atomic import atomic_open


@dataclass(frozen=True)
class RecoveredMcap:
    """What `recover_mcap` copied: counts, and why it stopped early (None when the file read to its end)."""

    messages: int
    channels: int
    schemas: int
    stopped: str | None


def _damage_errors() -> tuple[type[BaseException], ...]:
    """What the streaming reader raises on a cut or corrupt file: mcap's own errors, short reads, and the
    chunk decompressors' errors."""
    from mcap.exceptions import McapError

    return (McapError, EOFError, ValueError, struct.error, RuntimeError, KeyError)


def recover_mcap(src: str | Path, out: str | Path) -> RecoveredMcap:
    """Copy the readable records of `src` into the mcap `out`; BagError when `src` is no mcap at all or holds
    no message that could be read."""
    from mcap.records import Channel, Header, Message, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import CompressionType, Writer

    src, out = Path(src), Path(out)
    try:
        with src.open("rb") as fh:
            magic = fh.read(8)
    except OSError as err:
        raise BagError(f"{src}: cannot read ({err.strerror})") from err
    if not magic.startswith(b"\x89MCAP"):
        raise BagError(f"{src}: not an mcap file (bad magic bytes); --recover reads mcap files only")
    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    n_messages = 0
    stopped: str | None = None
    with src.open("rb") as fh, atomic_open(out, "wb") as dst:
        writer = Writer(dst, compression=CompressionType.LZ4, chunk_size=4 * 1024 * 1024)
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        started = False
        records = StreamReader(fh, validate_crcs=False).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                break
            except _damage_errors() as err:
                stopped = f"at byte {fh.tell()} of {src.stat().st_size}: {type(err).__name__} {err}".rstrip()
                break
            if isinstance(record, Header):
                writer.start(profile=record.profile, library=record.library or "changing_slam_ros")
                started = True
            elif isinstance(record, Schema) and record.id not in schema_ids:
                schemas[record.id] = record
                schema_ids[record.id] = writer.register_schema(record.name, record.encoding, record.data)
            elif isinstance(record, Channel) and record.id not in channel_ids:
                channels[record.id] = record
                channel_ids[record.id] = writer.register_channel(
                    record.topic, record.message_encoding, schema_ids.get(record.schema_id, 0), record.metadata)
            elif isinstance(record, Message) and record.channel_id in channel_ids:
                writer.add_message(channel_ids[record.channel_id], record.log_time, record.data, record.publish_time,
                                   record.sequence)  # fmt: skip
                n_messages += 1
        if not started or n_messages == 0:
            why = f" (stopped {stopped})" if stopped else ""
            raise BagError(f"{src}: no message could be read{why}; nothing to recover")
        writer.finish()
    return RecoveredMcap(n_messages, len(channels), len(schemas), stopped)
