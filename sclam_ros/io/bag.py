"""rosbag2 reading and writing through `rosbags` (no rclpy needed).

Reading yields the deserialized rosbags messages as they are; turning them into core
inputs is the job of ``sclam_ros.io.messages`` (duck-typed, so the node's rclpy
messages go through the same code). Writing builds messages with the Jazzy type
store's classes, so a bag written here is read by ``ros2 bag`` as well.

Accepted inputs: a rosbag2 folder (``metadata.yaml`` + storage files), or one
``.db3`` / ``.mcap`` storage file (inside its folder, the whole folder is read so
split recordings stay complete; a lone storage file is read on its own). ROS 1
``.bag`` files also open, since ``AnyReader`` handles them for free.
"""
from __future__ import annotations

import logging
from collections import Counter
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path
from typing import Iterable, Iterator, Optional, Sequence

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.typesys import Stores, get_typestore

from sclam_ros.core.inputs import Scan

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
STORAGE_SUFFIXES = (".db3", ".mcap")
# rosbag2 format version written; 9 is what Jazzy's ros2 bag writes.
ROSBAG2_VERSION = 9
NS_PER_S = 1_000_000_000

log = logging.getLogger("sclam")


class BagError(ValueError):
    """A bag that cannot be used as asked; the message says which and why."""


# --- reading -------------------------------------------------------------------------


def _reader_path(path: Path) -> Path:
    """The path AnyReader should open for ``path``, or BagError saying why none fits."""
    if not path.exists():
        raise BagError(f"bag not found: {path}")
    if path.is_dir():
        if not (path / "metadata.yaml").is_file():
            storage = sorted(p.name for p in path.iterdir() if p.suffix in STORAGE_SUFFIXES)
            hint = (
                f"; it holds storage file(s) {', '.join(storage)}: pass one of them directly"
                if storage
                else ""
            )
            raise BagError(f"not a rosbag2 folder (no metadata.yaml): {path}{hint}")
        return path
    if path.suffix in STORAGE_SUFFIXES:
        # Inside a complete bag folder read the folder, so split files are all read.
        return path.parent if (path.parent / "metadata.yaml").is_file() else path
    if path.suffix == ".bag":
        return path
    if path.name == "metadata.yaml":
        return path.parent
    raise BagError(
        f"not a rosbag2: {path} (expected a rosbag2 folder or a "
        f"{' / '.join(STORAGE_SUFFIXES)} file)"
    )


@contextmanager
def open_reader(path) -> Iterator[AnyReader]:
    """``with open_reader(path) as reader:`` an opened ``AnyReader`` on the bag at ``path``.

    Raises BagError for a missing path, something that is not a bag, or a bag that
    cannot be opened (corrupt metadata, unknown storage, ...).
    """
    path = Path(path)
    target = _reader_path(path)
    try:
        reader = AnyReader([target], default_typestore=TYPESTORE)
        reader.open()
    except (AnyReaderError, FileNotFoundError, OSError) as exc:
        raise BagError(f"cannot open bag {path}: {exc}") from None
    except Exception as exc:  # rosbags raises assorted errors on corrupt files
        raise BagError(f"cannot open bag {path}: {type(exc).__name__}: {exc}") from None
    try:
        yield reader
    finally:
        reader.close()


def _describe_topics(reader: AnyReader) -> str:
    lines = [f"  {name} [{info.msgtype}] ({info.msgcount} msgs)" for name, info in reader.topics.items()]
    return "\n".join(lines) if lines else "  (none)"


def _connections_for(reader: AnyReader, topics: Iterable[str], path) -> list:
    topics = list(topics)
    available = reader.topics
    missing = [t for t in topics if t not in available]
    if missing:
        raise BagError(
            f"topic(s) {', '.join(missing)} not in bag {path}; available topics:\n"
            + _describe_topics(reader)
        )
    wanted = set(topics)
    return [c for c in reader.connections if c.topic in wanted]


class ReadCounts:
    """What :func:`iter_messages` met, per topic: messages ``read`` (yielded) and ``corrupt``
    (skipped: they did not deserialize), and how often the storage itself was unreadable.
    ``used``: filled by the consumer (io/recording.py), messages it passed on to the
    calibration (read minus those its checks rejected). ``span``: (from, to) record time (s,
    None: open) of the messages counted; a chunk of a recording (fleet/chunked.py) counts
    its own span only, so that the chunks' counts add up to the recording's."""

    def __init__(self, span=(None, None)):
        self.span = span
        self.read: Counter = Counter()
        self.used: Counter = Counter()
        self.corrupt: Counter = Counter()
        self.unreadable = 0  # storage errors stepped over (their messages are lost uncounted)

    def covers(self, record_time_s: float) -> bool:
        """Whether a message recorded at this time is counted (inside ``span``)."""
        lo, hi = self.span
        return (lo is None or record_time_s >= lo) and (hi is None or record_time_s < hi)

    def as_dict(self) -> dict:
        """{topic: {"read": n, "used": u, "corrupt": m}} for every topic seen."""
        return {t: {"read": self.read[t], "used": self.used[t], "corrupt": self.corrupt[t]}
                for t in sorted(set(self.read) | set(self.corrupt))}


# A storage error ends rosbags' generator; reading restarts after the last good message,
# stepping further ahead each time the same bad part fails again (first by SKIP_NS).
SKIP_NS = 10_000_000  # 10 ms: less than one scan period, so a resume loses little
MAX_RESUMES = 40  # bounded: a bag that fails this often is garbage after every step


def _raw_messages(reader: AnyReader, connections, start, stop, counts: ReadCounts, path):
    """reader.messages(...), restarted past unreadable parts of the storage (a corrupt
    sqlite page, random bytes in an mcap chunk) instead of ending at the first one."""
    begin, skip, last = start, SKIP_NS, None
    for _ in range(MAX_RESUMES):
        progressed = False
        try:
            for item in reader.messages(connections=connections, start=begin, stop=stop):
                last, progressed = item[1], True
                yield item
            return
        # rosbags raises whatever its storage layer meets (OverflowError, ReaderError,
        # sqlite errors, ...): all mean "these bytes are not a bag", never a bug here.
        except Exception as exc:  # noqa: BLE001
            if not counts.unreadable:
                log.warning("bag %s: storage unreadable after t = %.3f s (%s: %s); reading "
                            "resumes after the bad part", path,
                            (last or reader.start_time) / NS_PER_S, type(exc).__name__, exc)
            counts.unreadable += 1
            if progressed:  # retry just after the last good message
                begin, skip = last + 1, SKIP_NS
            else:  # failed again before any message: step further ahead each time
                begin, skip = (reader.start_time if begin is None else begin) + skip, 2 * skip
            if begin >= reader.end_time or (stop is not None and begin >= stop):
                break
    log.warning("bag %s: storage unreadable %d time(s); the messages there are lost, "
                "reading stopped at t = %.3f s", path, counts.unreadable,
                min(begin, reader.end_time) / NS_PER_S)


def iter_messages(
    path, topics: Sequence[str], start: Optional[float] = None, stop: Optional[float] = None,
    counts: Optional[ReadCounts] = None,
) -> Iterator[tuple[str, float, object]]:
    """(topic, record_time_s, message) for ``topics``, in record-time order; with ``start``
    and/or ``stop`` (record time, s) only the messages in [start, stop).

    Raises BagError before yielding anything if a topic is missing from the bag. A message
    that does not deserialize is skipped and counted in ``counts`` (a :class:`ReadCounts`);
    an unreadable part of the storage is stepped over. Both are warned about, and so is a
    complete read that returns fewer messages than the bag's metadata announces.
    """
    if isinstance(topics, str):
        topics = [topics]
    counts = counts if counts is not None else ReadCounts()
    start_ns = None if start is None else stamp_to_ns(start)
    stop_ns = None if stop is None else stamp_to_ns(stop)
    with open_reader(path) as reader:
        connections = _connections_for(reader, topics, path)
        raw = _raw_messages(reader, connections, start_ns, stop_ns, counts, path)
        for connection, timestamp_ns, data in raw:
            topic = connection.topic
            record_time = timestamp_ns / NS_PER_S
            try:
                msg = reader.deserialize(data, connection.msgtype)
            except Exception as exc:  # noqa: BLE001 - corrupt bytes raise assorted errors
                if not counts.corrupt[topic]:
                    log.warning("bag %s: corrupt %s message at t = %.3f s skipped (%s); further "
                                "ones are counted", path, topic, record_time, exc)
                counts.corrupt[topic] += counts.covers(record_time)
                continue
            counts.read[topic] += counts.covers(record_time)
            yield topic, record_time, msg
        if start is None and stop is None:
            _warn_if_short(reader, topics, counts, path)
    for topic, n in sorted(counts.corrupt.items()):
        if n > 1:  # the first one was warned about as it came
            log.warning("bag %s: %d corrupt %s message(s) skipped", path, n, topic)


def _warn_if_short(reader: AnyReader, topics, counts: ReadCounts, path) -> None:
    """A reader that silently returns fewer messages than the metadata announces (random
    bytes in an mcap chunk can make it drop a whole chunk) is worth a warning."""
    for topic in topics:
        announced = reader.topics[topic].msgcount
        found = counts.read[topic] + counts.corrupt[topic]
        if found < announced:
            log.warning("bag %s: topic %s: the metadata announces %d messages, the reader "
                        "returned %d", path, topic, announced, found)


def topic_info(path) -> dict[str, tuple[str, int]]:
    """topic -> (message type, message count)."""
    return dict(_summary(path)[0])


def _time_span_ns(path) -> tuple[int, int]:
    """(first, last) record time of the bag's messages in integer ns; (0, 0) for an empty bag."""
    return _summary(path)[1]


def _summary(path):
    """(((topic, (message type, count)), ...), (first, last) record time ns) of the bag: one
    opening of it for what a calibration asks several times (each opening reads its metadata
    and storage schema: ~40 ms), kept while its files are unchanged."""
    path = Path(path)
    try:
        target = _reader_path(path)
        files = sorted(target.iterdir()) if target.is_dir() else [target]
        signature = tuple((f.name, f.stat().st_mtime_ns, f.stat().st_size) for f in files)
    except OSError:
        signature = None  # open_reader says what is wrong
    if signature is None:
        return _read_summary(path)
    return _cached_summary(str(path.resolve()), signature)


@lru_cache(maxsize=8)
def _cached_summary(path: str, signature) -> tuple:
    return _read_summary(path)


def _read_summary(path) -> tuple:
    with open_reader(path) as reader:
        topics = tuple((name, (info.msgtype, info.msgcount)) for name, info in reader.topics.items())
        # rosbags' end_time is one nanosecond after the last message.
        span = (0, 0) if reader.message_count == 0 else (reader.start_time, reader.end_time - 1)
    return topics, span


def time_span(path) -> tuple[float, float]:
    """(first, last) record time of the bag's messages in seconds; (0, 0) for an empty bag."""
    first, last = _time_span_ns(path)
    return first / NS_PER_S, last / NS_PER_S


def duration_s(path) -> float:
    """Record time from the first to the last message, in seconds (0 for an empty bag).

    Subtracted in integer nanoseconds: two float stamps near 1.7e9 s differ by ~0.2 µs steps."""
    first, last = _time_span_ns(path)
    return max(0, last - first) / NS_PER_S


# --- writing -------------------------------------------------------------------------


def stamp_to_ns(stamp_s: float) -> int:
    return int(round(float(stamp_s) * NS_PER_S))


def time_msg(stamp_s: float):
    """builtin_interfaces/Time of a stamp in seconds (nanosecond resolution)."""
    sec, nanosec = divmod(stamp_to_ns(stamp_s), NS_PER_S)
    return TYPESTORE.types["builtin_interfaces/msg/Time"](sec=int(sec), nanosec=int(nanosec))


def header_msg(stamp_s: float, frame_id: str):
    return TYPESTORE.types["std_msgs/msg/Header"](stamp=time_msg(stamp_s), frame_id=frame_id)


def _quaternion_of_yaw(yaw: float):
    return TYPESTORE.types["geometry_msgs/msg/Quaternion"](
        x=0.0, y=0.0, z=float(np.sin(yaw / 2.0)), w=float(np.cos(yaw / 2.0))
    )


def _pose_msg(pose_xyth):
    types = TYPESTORE.types
    x, y, th = (float(v) for v in pose_xyth)
    return types["geometry_msgs/msg/Pose"](
        position=types["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
        orientation=_quaternion_of_yaw(th),
    )


def _covariance36(covariance) -> np.ndarray:
    """A 6x6 row-major covariance from None, a 36-vector, a 6x6 or a planar 3x3 (x, y, yaw)."""
    out = np.zeros(36)
    if covariance is None:
        return out
    cov = np.asarray(covariance, float)
    if cov.size == 36:
        return cov.reshape(36).copy()
    if cov.shape != (3, 3):
        raise ValueError(f"covariance must be 6x6, 36 values or planar 3x3, got shape {cov.shape}")
    full = np.zeros((6, 6))
    index = [0, 1, 5]  # x, y, yaw in (x, y, z, roll, pitch, yaw)
    full[np.ix_(index, index)] = cov
    return full.reshape(36)


class BagWriter:
    """Write a rosbag2 (sqlite3 or mcap) with the message kinds this package uses.

    ``with BagWriter(path) as bag: bag.write_scan("/scan", scan)``. The folder must
    not exist yet (rosbags refuses to overwrite). Record time defaults to the header
    stamp; pass ``record_time_s`` to model a recorder receiving messages later.
    """

    def __init__(self, path, storage: str = "sqlite3"):
        plugins = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}
        if storage not in plugins:
            raise BagError(f"storage must be one of {sorted(plugins)}, got {storage!r}")
        self.path = Path(path)
        self.storage = storage
        try:
            self._writer = Writer(self.path, version=ROSBAG2_VERSION, storage_plugin=plugins[storage])
        except WriterError as exc:
            raise BagError(str(exc)) from None
        self._connections: dict[str, object] = {}

    # context manager ------------------------------------------------------------------
    def open(self) -> "BagWriter":
        try:
            self._writer.open()
        except WriterError as exc:
            raise BagError(str(exc)) from None
        return self

    def close(self) -> None:
        self._writer.close()

    def __enter__(self) -> "BagWriter":
        return self.open()

    def __exit__(self, exc_type, exc, tb) -> bool:
        self.close()
        return False

    # generic --------------------------------------------------------------------------
    def write(self, topic: str, msgtype: str, msg, record_time_s: float) -> None:
        """Serialize ``msg`` (a type-store instance of ``msgtype``) onto ``topic``."""
        connection = self._connections.get(topic)
        if connection is None:
            connection = self._writer.add_connection(topic, msgtype, typestore=TYPESTORE)
            self._connections[topic] = connection
        elif connection.msgtype != msgtype:
            raise BagError(f"topic {topic} already carries {connection.msgtype}, not {msgtype}")
        self._writer.write(connection, stamp_to_ns(record_time_s), TYPESTORE.serialize_cdr(msg, msgtype))

    # message kinds --------------------------------------------------------------------
    def write_joint_state(
        self, topic, stamp_s, names, positions, velocities=None, record_time_s=None, frame_id=""
    ) -> None:
        msgtype = "sensor_msgs/msg/JointState"
        msg = TYPESTORE.types[msgtype](
            header=header_msg(stamp_s, frame_id),
            name=list(names),
            position=np.asarray(positions, dtype=np.float64),
            velocity=np.asarray([] if velocities is None else velocities, dtype=np.float64),
            effort=np.zeros(0, dtype=np.float64),
        )
        self.write(topic, msgtype, msg, stamp_s if record_time_s is None else record_time_s)

    def write_scan(self, topic, scan: Scan, record_time_s=None, scan_time=None) -> None:
        """A LaserScan from a core ``Scan``; ``scan_time`` defaults to beams × time_increment."""
        msgtype = "sensor_msgs/msg/LaserScan"
        ranges = np.asarray(scan.ranges, dtype=np.float32)
        n = len(ranges)
        msg = TYPESTORE.types[msgtype](
            header=header_msg(scan.stamp, scan.frame_id),
            angle_min=float(scan.angle_min),
            angle_max=float(scan.angle_min + scan.angle_increment * max(n - 1, 0)),
            angle_increment=float(scan.angle_increment),
            time_increment=float(scan.time_increment),
            scan_time=float(scan.time_increment * n if scan_time is None else scan_time),
            range_min=float(scan.range_min),
            range_max=float(scan.range_max),
            ranges=ranges,
            intensities=np.zeros(0, dtype=np.float32),
        )
        self.write(topic, msgtype, msg, scan.stamp if record_time_s is None else record_time_s)

    def write_odometry(
        self,
        topic,
        stamp_s,
        pose_xyth,
        twist_v_w=(0.0, 0.0),
        frame_id="odom",
        child_frame_id="base_link",
        covariance=None,
        twist_covariance=None,
        record_time_s=None,
    ) -> None:
        """nav_msgs/Odometry: planar pose in ``frame_id``, twist (v, ω) in ``child_frame_id``.

        ``twist_v_w`` may also be (vx, vy, ω) for a body that slips sideways.
        """
        msgtype = "nav_msgs/msg/Odometry"
        types = TYPESTORE.types
        twist = [float(v) for v in twist_v_w]
        vx, vy, w = (twist[0], 0.0, twist[1]) if len(twist) == 2 else twist
        msg = types[msgtype](
            header=header_msg(stamp_s, frame_id),
            child_frame_id=child_frame_id,
            pose=types["geometry_msgs/msg/PoseWithCovariance"](
                pose=_pose_msg(pose_xyth), covariance=_covariance36(covariance)
            ),
            twist=types["geometry_msgs/msg/TwistWithCovariance"](
                twist=types["geometry_msgs/msg/Twist"](
                    linear=types["geometry_msgs/msg/Vector3"](x=vx, y=vy, z=0.0),
                    angular=types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=w),
                ),
                covariance=_covariance36(twist_covariance),
            ),
        )
        self.write(topic, msgtype, msg, stamp_s if record_time_s is None else record_time_s)

    def write_pose(self, topic, stamp_s, pose_xyth, frame_id="map", record_time_s=None) -> None:
        """geometry_msgs/PoseStamped of a planar pose."""
        msgtype = "geometry_msgs/msg/PoseStamped"
        msg = TYPESTORE.types[msgtype](header=header_msg(stamp_s, frame_id), pose=_pose_msg(pose_xyth))
        self.write(topic, msgtype, msg, stamp_s if record_time_s is None else record_time_s)


    def write_string(self, topic, text, record_time_s) -> None:
        """std_msgs/String, as robot_state_publisher latches /robot_description."""
        msgtype = "std_msgs/msg/String"
        self.write(topic, msgtype, TYPESTORE.types[msgtype](data=str(text)), record_time_s)

    def write_tf_static(self, stamp_s, transforms, topic="/tf_static", record_time_s=None) -> None:
        """tf2_msgs/TFMessage of static transforms, as robot_state_publisher latches them.

        ``transforms``: (parent, child, (x, y, z), (qx, qy, qz, qw)) each, in 3D so that a
        tilted mount can be written too."""
        msgtype = "tf2_msgs/msg/TFMessage"
        types = TYPESTORE.types
        msg = types[msgtype](transforms=[
            types["geometry_msgs/msg/TransformStamped"](
                header=header_msg(stamp_s, parent),
                child_frame_id=child,
                transform=types["geometry_msgs/msg/Transform"](
                    translation=types["geometry_msgs/msg/Vector3"](
                        x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2])),
                    rotation=types["geometry_msgs/msg/Quaternion"](
                        x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
                ),
            )
            for parent, child, xyz, q in transforms
        ])
        self.write(topic, msgtype, msg, stamp_s if record_time_s is None else record_time_s)
