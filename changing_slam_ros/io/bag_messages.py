"""Raw messages from any bag: ROS 1 `.bag`, ROS 2 bag folders (sqlite3 or mcap storage), bare `.mcap`.

This is the lowest layer of bag input, the one `bag_player` publishes from and `bag_reader` decodes:
it moves bytes plus connection records and decodes nothing unless asked (`BagMessages.deserialize`).
Every payload is yielded as CDR, ready for `rclpy` publishing: ROS 1 payloads are converted on the
byte level with rosbags' `ros1_to_cdr`, using the bag's own ROS 1 definitions with the ROS 2
`std_msgs/Header` (the ROS 1 `seq` field is dropped), and ROS 1 type names are renamed to their ROS 2
equivalents (`tf/tfMessage` -> `tf2_msgs/msg/TFMessage`).

Any unreadable, truncated or corrupt input raises `BagError` naming the file. Usage: `BagMessages`.
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Collection, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from types import TracebackType
from typing import Any

from changing_slam_ros.errors import BagError

# Type renames from ROS 1 to ROS 2 (as rosbags.convert does).
ROS1_TO_ROS2_MSGTYPE = {"tf/msg/tfMessage": "tf2_msgs/msg/TFMessage"}

HEADER_TYPE = "std_msgs/msg/Header"


class BagKind(enum.Enum):
    """What a path holds."""

    ROS1 = "ros1 bag"
    ROS2_SQLITE3 = "ros2 bag (sqlite3)"
    ROS2_MCAP = "ros2 bag (mcap)"
    MCAP = "mcap file"


@dataclass(frozen=True)
class BagConnection:
    """One topic of a bag.

    - `msgtype`: ROS 2 type name (`sensor_msgs/msg/Image`), the one to publish the CDR bytes as.
    - `msgcount`: number of messages on the topic.
    - `latched`: ROS 1 latched topic or ROS 2 transient-local QoS (publish with transient local).
    - `has_header`: the message starts with a `std_msgs/Header` (so `header_stamp_ns` is filled).
    """

    topic: str
    msgtype: str
    msgcount: int
    latched: bool
    has_header: bool


@dataclass(frozen=True)
class RawMessage:
    """One message as stored, with its payload in CDR.

    - `log_stamp_ns`: bag log / receive time, nanoseconds.
    - `header_stamp_ns`: `header.stamp` in nanoseconds when the type starts with a Header, else None.
    - `cdr`: CDR bytes (4-byte encapsulation header included), publishable as-is.
    """

    topic: str
    msgtype: str
    log_stamp_ns: int
    header_stamp_ns: int | None
    cdr: bytes


_REPAIR_HINT = {
    BagKind.ROS1: " (a truncated or unindexed recording can be repaired with 'rosbag reindex')",
    BagKind.ROS2_SQLITE3: "",
    BagKind.ROS2_MCAP: " (what a truncated recording still holds: 'changing-slam convert --recover FILE.mcap "
                       "OUT.mcap' with the .mcap file inside the folder)",
    BagKind.MCAP: " (what a truncated recording still holds: 'changing-slam convert --recover FILE.mcap OUT.mcap')",
}


def detect_bag_kind(path: Path) -> BagKind:
    """Classify `path` by what it is on disk; BagError when it is none of the supported kinds."""
    if not path.exists():
        raise BagError(f"{path}: no such file or folder")
    if path.is_dir():
        meta = path / "metadata.yaml"
        if not meta.is_file():
            raise BagError(f"{path}: folder is not a ROS 2 bag (no metadata.yaml)")
        try:
            text = meta.read_text()
        except OSError as err:
            raise BagError(f"{meta}: cannot read ({err.strerror})") from err
        return BagKind.ROS2_MCAP if "storage_identifier: mcap" in text else BagKind.ROS2_SQLITE3
    try:
        with path.open("rb") as fh:
            magic = fh.read(13)
    except OSError as err:
        raise BagError(f"{path}: cannot read ({err.strerror})") from err
    if magic.startswith(b"#ROSBAG V2.0"):
        return BagKind.ROS1
    if magic.startswith(b"\x89MCAP"):
        return BagKind.MCAP
    if path.suffix == ".bag":
        raise BagError(f"{path}: not a ROS 1 bag (expected '#ROSBAG V2.0' at the start)")
    if path.suffix == ".mcap":
        raise BagError(f"{path}: not an mcap file (bad magic bytes)")
    raise BagError(
        f"{path}: unrecognised bag; expected a ROS 1 .bag, a ROS 2 bag folder or an .mcap file"
    )


def _read_errors() -> tuple[type[BaseException], ...]:
    """Exceptions rosbags raises on unreadable or corrupt input (turned into BagError)."""
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Reader1Error
    from rosbags.rosbag2 import ReaderError as Reader2Error
    from rosbags.serde import SerdeError
    from rosbags.typesys import TypesysError

    return (
        AnyReaderError,
        Reader1Error,
        Reader2Error,
        SerdeError,
        TypesysError,
        OSError,
        EOFError,
        struct.error,
        ValueError,
        KeyError,
        IndexError,
        AssertionError,
        # sqlite3 / zstd / lz4 errors are Exception subclasses with no common base
        RuntimeError,
    ) + _optional_errors()


def _optional_errors() -> tuple[type[BaseException], ...]:
    import sqlite3

    errors: list[type[BaseException]] = [sqlite3.Error]
    try:
        import zstandard

        errors.append(zstandard.ZstdError)
    except ImportError:  # pragma: no cover - rosbags depends on it
        pass
    return tuple(errors)


class BagMessages:
    """Context manager over one bag (raw CDR messages, see the module docstring).

        with BagMessages(path) as bag:
            for conn in bag.connections: ...
            for msg in bag.messages(topics={"/camera/rgb/image_color"}):
                image = bag.deserialize(msg)   # rosbags dataclass, ROS 2 wire layout
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.kind = detect_bag_kind(self.path)
        self._reader: Any = None
        self._conns: list[Any] = []
        self._decode_store: Any = None
        self._cdr_store: Any = None  # ROS 1 only: bag types with the ROS 2 Header
        self._by_rosbags_id: dict[int, tuple[BagConnection, str]] = {}
        self.connections: list[BagConnection] = []

    # -- lifetime ----------------------------------------------------------------------------
    def open(self) -> "BagMessages":
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        errors = _read_errors()
        try:
            reader = AnyReader([self.path], default_typestore=get_typestore(Stores.ROS2_JAZZY))
            reader.open()
        except FileNotFoundError as err:
            raise BagError(f"{self.path}: {err}") from err
        except errors as err:
            raise BagError(
                f"{self.path}: cannot open {self.kind.value}: {_describe(err)}{_REPAIR_HINT[self.kind]}"
            ) from err
        self._reader = reader
        try:
            self._prepare_types()
        except errors as err:
            self.close()
            raise BagError(f"{self.path}: message definitions unusable: {_describe(err)}") from err
        return self

    def close(self) -> None:
        if self._reader is not None:
            reader, self._reader = self._reader, None
            try:
                reader.close()
            except Exception:  # noqa: BLE001 - closing a broken reader must not mask the first error
                pass

    def __enter__(self) -> "BagMessages":
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- metadata ----------------------------------------------------------------------------
    @property
    def topics(self) -> dict[str, BagConnection]:
        """Topic name -> connection (the first one when a topic was recorded several times)."""
        out: dict[str, BagConnection] = {}
        for c in self.connections:
            if c.topic in out:
                prev = out[c.topic]
                out[c.topic] = BagConnection(
                    c.topic, prev.msgtype, prev.msgcount + c.msgcount, prev.latched, prev.has_header
                )
            else:
                out[c.topic] = c
        return out

    def describe_topics(self) -> str:
        """`topic (type)` list for error messages."""
        return ", ".join(f"{t} ({c.msgtype})" for t, c in sorted(self.topics.items())) or "none"

    @property
    def start_ns(self) -> int:
        """Log time of the first message, ns."""
        self._check_open()
        return int(self._reader.start_time)

    @property
    def end_ns(self) -> int:
        """One past the log time of the last message, ns (rosbags' convention)."""
        self._check_open()
        return int(self._reader.end_time)

    @property
    def message_count(self) -> int:
        return sum(c.msgcount for c in self.connections)

    # -- messages ----------------------------------------------------------------------------
    def messages(
        self,
        topics: Collection[str] | None = None,
        start_ns: int | None = None,
        stop_ns: int | None = None,
        *,
        payload: bool | Collection[str] = True,
    ) -> Iterator[RawMessage]:
        """Messages in log-time order, optionally filtered by topic and [start_ns, stop_ns).

        `payload=False` skips the CDR conversion and copy (`cdr` is empty); header stamps are still
        filled, which is what an indexing pass over large image topics needs. A collection of topic
        names keeps the payload of those topics only (one pass, so compressed chunks are read once).
        """
        self._check_open()
        conns = self._conns if topics is None else [c for c in self._conns if c.topic in topics]
        if topics is not None and not conns:
            return
        errors = _read_errors()
        gen = self._reader.messages(connections=conns, start=start_ns, stop=stop_ns)
        while True:
            try:
                conn, log_ns, raw = next(gen)
                meta, _decode_type = self._by_rosbags_id[id(conn)]
                if payload is True or (payload is not False and meta.topic in payload):
                    cdr = self._to_cdr(conn, raw)
                    header_ns = _cdr_header_stamp_ns(cdr) if meta.has_header else None
                else:
                    cdr = b""
                    header_ns = self._raw_header_stamp_ns(raw) if meta.has_header else None
            except StopIteration:
                return
            except errors as err:
                raise BagError(
                    f"{self.path}: corrupt or truncated {self.kind.value}: {_describe(err)}"
                ) from err
            yield RawMessage(meta.topic, meta.msgtype, int(log_ns), header_ns, cdr)

    def deserialize(self, msg: RawMessage) -> Any:
        """Decode a message's CDR into a rosbags dataclass (ROS 2 field layout).

        ROS 1 bags decode with their own definitions, so field names keep ROS 1 spelling where it
        differs (`CameraInfo.K` instead of `.k`); readers of such fields accept both.
        """
        self._check_open()
        decode_type = self._decode_type_of(msg.topic, msg.msgtype)
        try:
            return self._decode_store.deserialize_cdr(msg.cdr, decode_type)
        except _read_errors() as err:
            raise BagError(
                f"{self.path}: message on {msg.topic} cannot be decoded as {msg.msgtype}: "
                f"{_describe(err)}"
            ) from err

    # -- internals ---------------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._reader is None:
            raise BagError(f"{self.path}: bag is not open (use 'with BagMessages(path) as bag')")

    def _prepare_types(self) -> None:
        from rosbags.interfaces import ConnectionExtRosbag1, Nodetype, QosDurability
        from rosbags.typesys import Stores, get_typestore

        reader = self._reader
        is_ros1 = not reader.is2
        if is_ros1:
            ros2_header = get_typestore(Stores.ROS2_JAZZY).fielddefs[HEADER_TYPE]
            store = get_typestore(Stores.EMPTY)
            store.register({**reader.typestore.fielddefs, HEADER_TYPE: ros2_header})
            self._cdr_store = store
            self._decode_store = store
        else:
            self._decode_store = reader.typestore
        self._conns = list(reader.connections)
        self._decode_types: dict[tuple[str, str], str] = {}
        for c in self._conns:
            fields = self._decode_store.fielddefs[c.msgtype][1]
            has_header = bool(fields) and fields[0][1] == (Nodetype.NAME, HEADER_TYPE)
            if isinstance(c.ext, ConnectionExtRosbag1):
                latched = bool(c.ext.latching)
            else:
                latched = any(
                    q.durability == QosDurability.TRANSIENT_LOCAL for q in c.ext.offered_qos_profiles
                )
            msgtype = ROS1_TO_ROS2_MSGTYPE.get(c.msgtype, c.msgtype) if is_ros1 else c.msgtype
            meta = BagConnection(c.topic, msgtype, int(c.msgcount), latched, has_header)
            self._by_rosbags_id[id(c)] = (meta, c.msgtype)
            self._decode_types[(c.topic, msgtype)] = c.msgtype
            self.connections.append(meta)

    def _decode_type_of(self, topic: str, msgtype: str) -> str:
        try:
            return self._decode_types[(topic, msgtype)]
        except KeyError:
            raise BagError(f"{self.path}: no connection {topic} of type {msgtype}") from None

    def _raw_header_stamp_ns(self, raw: bytes | memoryview) -> int | None:
        if self._cdr_store is None:
            return _cdr_header_stamp_ns(raw)
        if len(raw) < 12:  # ROS 1: uint32 seq, uint32 sec, uint32 nsec, little endian
            return None
        sec, nsec = struct.unpack_from("<II", raw, 4)
        return int(sec) * 1_000_000_000 + int(nsec)

    def _to_cdr(self, conn: Any, raw: bytes | memoryview) -> bytes:
        if self._cdr_store is None:
            return bytes(raw)
        return bytes(self._cdr_store.ros1_to_cdr(raw, conn.msgtype))


def _cdr_header_stamp_ns(cdr: bytes | memoryview) -> int | None:
    """`header.stamp` of a CDR message that starts with std_msgs/Header (int32 sec, uint32 nanosec)."""
    if len(cdr) < 12:
        return None
    endian = "<" if cdr[1] & 1 else ">"
    sec, nanosec = struct.unpack_from(f"{endian}iI", cdr, 4)
    return int(sec) * 1_000_000_000 + int(nanosec)


def with_stamps_shifted(msg: RawMessage, shift_ns: int) -> RawMessage:
    """`msg` `shift_ns` later: its log time, and its `header.stamp` rewritten in the CDR bytes when the type starts
    with a Header (a looped bag's later passes, so that time keeps running forward)."""
    if shift_ns == 0:
        return msg
    if msg.header_stamp_ns is None:
        return replace(msg, log_stamp_ns=msg.log_stamp_ns + shift_ns)
    stamp_ns = msg.header_stamp_ns + shift_ns
    cdr = bytearray(msg.cdr)
    if len(cdr) >= 12:
        struct.pack_into(f"{'<' if cdr[1] & 1 else '>'}iI", cdr, 4, *divmod(stamp_ns, 1_000_000_000))
    return replace(msg, log_stamp_ns=msg.log_stamp_ns + shift_ns, header_stamp_ns=stamp_ns, cdr=bytes(cdr))


def _describe(err: BaseException) -> str:
    text = str(err).strip() or type(err).__name__
    return text.splitlines()[0]
