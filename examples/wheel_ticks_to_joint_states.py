"""Recipe: a rosbag2 whose wheel ticks come in another message type (per-wheel tick counts
in a robot's own message) turned into one `sclam calibrate` reads: /joint_states with the
two wheels' counts as positions, and the scans copied.

    python examples/wheel_ticks_to_joint_states.py BAG OUT --topic /wheel_ticks \
        --left left_ticks --right right_ticks [--scan-topic /scan]

then, in the parameters file, ``ticks_per_revolution`` (the counts per wheel turn) and
``encoder_wrap`` (the counter's modulus, if it wraps), and ``sclam calibrate OUT --params
...``. The bag must carry its message definitions (rosbag2 records them; rosbags reads
them), so the robot's message package need not be installed. ``--left`` and ``--right``
name fields of the message, dotted for nested ones (``wheels.left``); a stamp comes from
the message's ``header`` when it has one, else from its record time.
"""
from __future__ import annotations

import argparse
import sys

from sclam_ros.io.bag import BagWriter, iter_messages
from sclam_ros.io.messages import laser_scan_to_scan, stamp_to_sec


def field(msg, dotted: str):
    for name in dotted.split("."):
        msg = getattr(msg, name)
    return float(msg)


def convert(bag, out, topic, left, right, scan_topic="/scan",
            joints=("left_wheel_joint", "right_wheel_joint")) -> int:
    """Write OUT; returns the number of tick messages converted."""
    count = 0
    with BagWriter(out) as writer:
        for name, record_time, msg in iter_messages(bag, [topic, scan_topic]):
            if name == scan_topic:
                writer.write_scan(scan_topic, laser_scan_to_scan(msg), record_time_s=record_time)
                continue
            stamp = stamp_to_sec(msg.header.stamp) if hasattr(msg, "header") else record_time
            writer.write_joint_state("/joint_states", stamp, joints,
                                     [field(msg, left), field(msg, right)],
                                     record_time_s=record_time)
            count += 1
    return count


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag")
    ap.add_argument("out")
    ap.add_argument("--topic", required=True, help="the tick messages' topic")
    ap.add_argument("--left", required=True, help="field of the left wheel's count")
    ap.add_argument("--right", required=True, help="field of the right wheel's count")
    ap.add_argument("--scan-topic", default="/scan")
    args = ap.parse_args(argv)
    n = convert(args.bag, args.out, args.topic, args.left, args.right, args.scan_topic)
    print(f"wrote {args.out}: {n} tick messages as /joint_states, scans from {args.scan_topic}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
