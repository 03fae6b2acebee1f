"""examples/wheel_ticks_to_joint_states.py on a bag whose ticks come in a message type
this machine has no package for (its definition only in the bag), and the calibration of
the result against the original JointState recording's."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from sclam_ros.core.params import SclamParams
from sclam_ros.io.bag import iter_messages
from sclam_ros.sim import simulate

REPO = Path(__file__).resolve().parents[1]
TICKS_MSG = "std_msgs/Header header\nint64 left_ticks\nint64 right_ticks\n"
TICKS_TYPE = "my_robot_msgs/msg/WheelTicks"


def _recipe():
    spec = importlib.util.spec_from_file_location(
        "ticks_recipe", REPO / "examples" / "wheel_ticks_to_joint_states.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_ticks_of_another_message_type_become_the_joint_states_they_were(tmp_path):
    sim = tmp_path / "sim"
    simulate(sim, robot="pioneer", duration=6.0, seed=2)
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(TICKS_MSG, TICKS_TYPE))
    Ticks, Header, Time = (store.types[t] for t in (TICKS_TYPE, "std_msgs/msg/Header",
                                                    "builtin_interfaces/msg/Time"))
    custom = tmp_path / "custom"
    joint_states = []
    with Writer(custom, version=8) as writer:
        ticks = writer.add_connection("/wheel_ticks", TICKS_TYPE, typestore=store)
        scans = writer.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=store)
        for topic, t, msg in iter_messages(sim, ["/joint_states", "/scan"]):
            ns = int(round(t * 1e9))
            if topic == "/scan":
                writer.write(scans, ns, store.serialize_cdr(msg, "sensor_msgs/msg/LaserScan"))
                continue
            joint_states.append(msg)
            out = Ticks(header=Header(stamp=Time(sec=msg.header.stamp.sec,
                                                 nanosec=msg.header.stamp.nanosec), frame_id=""),
                        left_ticks=int(msg.position[0]), right_ticks=int(msg.position[1]))
            writer.write(ticks, ns, store.serialize_cdr(out, TICKS_TYPE))

    converted = tmp_path / "converted"
    assert _recipe().main([str(custom), str(converted), "--topic", "/wheel_ticks",
                           "--left", "left_ticks", "--right", "right_ticks"]) == 0
    got = [m for _, _, m in iter_messages(converted, ["/joint_states"])]
    assert len(got) == len(joint_states)
    for a, b in zip(got, joint_states):
        assert (a.header.stamp.sec, a.header.stamp.nanosec) == (b.header.stamp.sec, b.header.stamp.nanosec)
        np.testing.assert_array_equal(a.position, np.round(b.position[:2]))
    assert len(list(iter_messages(converted, ["/scan"]))) == len(list(iter_messages(sim, ["/scan"])))
    params = SclamParams.from_yaml(sim / "params.yaml")
    assert params.left_wheel_joint == "left_wheel_joint"  # the names the recipe writes
