"""Publish a rosbag2 recording on the live ROS graph (the engine of ``sclam play``).

Every topic whose message type rclpy can import is published with its original timing
(record times, scaled by --rate), so ``sclam_node`` can be tried without a robot::

    sclam_node --ros-args -p use_sim_time:=true --params-file BAG/params.yaml &
    sclam play BAG --clock

Messages are converted field by field from the rosbags dataclasses to rclpy messages
(``rosbags_to_rclpy``), so any message type works, not just the ones sclam reads.
"""
from __future__ import annotations

import array
import importlib
import signal
import time

import numpy as np

_CLASSES: dict = {}


def rclpy_class(msgtype: str):
    """'sensor_msgs/msg/JointState' → sensor_msgs.msg.JointState (ImportError if unknown)."""
    if msgtype not in _CLASSES:
        package, kind, name = msgtype.split("/")
        module = importlib.import_module(f"{package}.{kind}")
        _CLASSES[msgtype] = getattr(module, name)
    return _CLASSES[msgtype]


def _class_of_slot(slot_type):
    """rclpy class of a rosidl NamespacedType (e.g. the element type of a sequence)."""
    return rclpy_class("/".join(list(slot_type.namespaces) + [slot_type.name]))


def rosbags_to_rclpy(msg, cls):
    """Copy a rosbags message into a new rclpy message of class ``cls``, recursively."""
    out = cls()
    for (name, _), slot in zip(cls.get_fields_and_field_types().items(), cls.SLOT_TYPES):
        value = getattr(msg, name)
        current = getattr(out, name)
        if hasattr(current, "get_fields_and_field_types"):
            setattr(out, name, rosbags_to_rclpy(value, type(current)))
        elif isinstance(current, array.array):
            setattr(out, name, array.array(
                current.typecode, np.asarray(value, dtype=np.dtype(current.typecode)).tobytes()))
        elif isinstance(current, np.ndarray):
            setattr(out, name, np.asarray(value, dtype=current.dtype))
        elif isinstance(current, list):
            element = getattr(slot, "value_type", None)
            if element is not None and hasattr(element, "namespaces"):
                item_cls = _class_of_slot(element)
                setattr(out, name, [rosbags_to_rclpy(v, item_cls) for v in value])
            else:
                setattr(out, name, [v.item() if isinstance(v, np.generic) else v for v in value])
        elif isinstance(current, bytes):
            setattr(out, name, bytes(value))
        else:
            setattr(out, name, value.item() if isinstance(value, np.generic) else value)
    return out


def _wait_for_subscribers(node, publishers, timeout, executor):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if all(p.get_subscription_count() > 0 for p in publishers.values()):
            return True
        executor.spin_once(timeout_sec=0.05)
    return False


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def play(args) -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.qos import QoSProfile
    from rclpy.signals import SignalHandlerOptions
    from rosgraph_msgs.msg import Clock

    from sclam_ros.io.bag import BagError, iter_messages, topic_info

    # A missing, corrupt or unsuitable bag is a BagError: `sclam` makes it one line, exit 2.
    info = topic_info(args.bag)
    wanted = args.topics or sorted(info)
    missing = [t for t in wanted if t not in info]
    if missing:
        raise BagError(f"topic(s) {', '.join(missing)} not in {args.bag}; "
                       f"available: {', '.join(sorted(info))}")
    classes = {}
    for topic in wanted:
        try:
            classes[topic] = rclpy_class(info[topic][0])
        except (ImportError, AttributeError, ValueError):
            print(f"sclam play: skipping {topic}: no rclpy type {info[topic][0]}")
    if not classes:
        raise BagError(f"nothing to publish: no topic of {args.bag} has a message type rclpy knows")

    # rclpy's own handlers would shut the context down under a running publish loop (the
    # next publish raises); a plain KeyboardInterrupt for SIGINT and SIGTERM alike leaves
    # through the `finally` below instead: the counts are printed, the exit is clean.
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("sclam_play")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    qos = QoSProfile(depth=1000)  # reliable: also reaches best-effort subscribers
    publishers = {t: node.create_publisher(cls, t, qos) for t, cls in classes.items()}
    clock_pub = node.create_publisher(Clock, "/clock", 100) if args.clock else None
    counts = dict.fromkeys(classes, 0)
    previous_sigterm = signal.signal(signal.SIGTERM, _interrupt)
    try:
        if args.wait_for_subscribers > 0 and not _wait_for_subscribers(
                node, publishers, args.wait_for_subscribers, executor):
            print("sclam play: not every topic has a subscriber; playing anyway")
        while True:
            start_wall, first = None, None
            for topic, record_t, msg in iter_messages(args.bag, list(classes)):
                if first is None:
                    start_wall, first = time.monotonic(), record_t
                due = start_wall + (record_t - first) / args.rate
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)  # pacing the playback is the job here
                if clock_pub is not None:
                    clock = Clock()
                    clock.clock.sec, ns = divmod(int(round(record_t * 1e9)), 1_000_000_000)
                    clock.clock.nanosec = ns
                    clock_pub.publish(clock)
                publishers[topic].publish(rosbags_to_rclpy(msg, classes[topic]))
                counts[topic] += 1
            if not args.loop:
                break
        # Let reliable publishers deliver the tail before the process goes away.
        for pub in publishers.values():
            pub.wait_for_all_acked(rclpy.duration.Duration(seconds=2.0))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        signal.signal(signal.SIGTERM, previous_sigterm)
        node.destroy_node()
        rclpy.try_shutdown()
    print("sclam play: published " + ", ".join(f"{t}: {n}" for t, n in sorted(counts.items())))
    return 0
