"""rosbag2 writing and reading back (sqlite3 and mcap), and the reader's error messages."""
import shutil

import numpy as np
import pytest

from sclam_ros.io.bag import BagError, BagWriter, duration_s, iter_messages, open_reader, topic_info
from sclam_ros.core.inputs import Scan

T0 = 1_700_000_000.0


def yaw_of(q):
    return np.arctan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y**2 + q.z**2))


def write_sample_bag(path, storage):
    ranges = np.array([1.0, np.inf, 2.5, 19.75], dtype=float)
    with BagWriter(path, storage) as bag:
        for i in range(5):
            stamp = T0 + 0.02 * i
            bag.write_joint_state("/joint_states", stamp, ["left_wheel_joint", "right_wheel_joint"],
                                  [1000.0 + i, 2000.0 - i])
            bag.write_odometry("/ground_truth/odom", stamp, (1.0 + i, -2.0, 3.0), (0.4, -0.7),
                               covariance=np.diag([0.01, 0.02, 0.03]))
        # Recorded later than stamped, as a real recorder does.
        bag.write_scan("/scan", Scan(T0 + 0.013, ranges, -np.pi, -0.5, 0.05, 20.0, 1e-4, "laser"),
                       record_time_s=T0 + 0.05)
        bag.write_pose("/pose", T0 + 0.1, (0.5, 0.25, -1.0))
    return ranges


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_round_trip(tmp_path, storage):
    path = tmp_path / "bag"
    ranges = write_sample_bag(path, storage)
    suffix = ".db3" if storage == "sqlite3" else ".mcap"
    assert (path / "metadata.yaml").is_file() and list(path.glob("*" + suffix))

    info = topic_info(path)
    assert info == {
        "/joint_states": ("sensor_msgs/msg/JointState", 5),
        "/ground_truth/odom": ("nav_msgs/msg/Odometry", 5),
        "/scan": ("sensor_msgs/msg/LaserScan", 1),
        "/pose": ("geometry_msgs/msg/PoseStamped", 1),
    }
    assert duration_s(path) == pytest.approx(0.1, abs=1e-9)

    messages = list(iter_messages(path, ["/joint_states", "/scan", "/ground_truth/odom", "/pose"]))
    times = [t for _, t, _ in messages]
    assert times == sorted(times)
    joint_states = [(t, m) for topic, t, m in messages if topic == "/joint_states"]
    for i, (t, msg) in enumerate(joint_states):
        assert t == pytest.approx(T0 + 0.02 * i, abs=1e-9)
        # Stamps are float seconds: near 1.7e9 s they resolve ~0.24 µs.
        assert msg.header.stamp.sec == int(T0)
        assert abs(msg.header.stamp.nanosec - 20_000_000 * i) < 1000
        assert list(msg.name) == ["left_wheel_joint", "right_wheel_joint"]
        np.testing.assert_array_equal(msg.position, [1000.0 + i, 2000.0 - i])

    (scan_time, scan), = [(t, m) for topic, t, m in messages if topic == "/scan"]
    assert scan_time == pytest.approx(T0 + 0.05, abs=1e-9)  # record time, not the stamp
    assert abs(scan.header.stamp.nanosec - 13_000_000) < 1000 and scan.header.frame_id == "laser"
    np.testing.assert_array_equal(scan.ranges, ranges.astype(np.float32))
    assert scan.angle_increment == -0.5 and scan.angle_max == pytest.approx(-np.pi - 1.5)
    assert scan.time_increment == pytest.approx(1e-4) and scan.range_max == 20.0

    odoms = [m for topic, _, m in messages if topic == "/ground_truth/odom"]
    last = odoms[-1]
    assert last.header.frame_id == "odom" and last.child_frame_id == "base_link"
    assert (last.pose.pose.position.x, last.pose.pose.position.y) == (5.0, -2.0)
    assert yaw_of(last.pose.pose.orientation) == pytest.approx(3.0)
    assert (last.twist.twist.linear.x, last.twist.twist.angular.z) == (0.4, -0.7)
    cov = np.asarray(last.pose.covariance).reshape(6, 6)
    assert (cov[0, 0], cov[1, 1], cov[5, 5], cov[2, 2]) == pytest.approx((0.01, 0.02, 0.03, 0.0))

    (pose,) = [m for topic, _, m in messages if topic == "/pose"]
    assert yaw_of(pose.pose.orientation) == pytest.approx(-1.0)

    # A storage file inside its folder reads the same as the folder.
    storage_file = next(path.glob("*" + suffix))
    assert [t for _, t, _ in iter_messages(storage_file, ["/joint_states"])] == [t for t, _ in joint_states]


def test_lone_storage_file_and_metadata_path(tmp_path):
    write_sample_bag(tmp_path / "bag", "sqlite3")
    lone = tmp_path / "lone.db3"
    shutil.copy(next((tmp_path / "bag").glob("*.db3")), lone)
    assert len(list(iter_messages(lone, "/joint_states"))) == 5
    assert topic_info(tmp_path / "bag" / "metadata.yaml")["/scan"] == ("sensor_msgs/msg/LaserScan", 1)


def test_extra_files_in_bag_folder_are_ignored(tmp_path):
    write_sample_bag(tmp_path / "bag", "mcap")
    (tmp_path / "bag" / "params.yaml").write_text("sclam: {ros__parameters: {}}\n")
    (tmp_path / "bag" / "truth.json").write_text("{}\n")
    assert len(list(iter_messages(tmp_path / "bag", ["/joint_states", "/scan"]))) == 6


def test_missing_topic_lists_available_topics_and_types(tmp_path):
    write_sample_bag(tmp_path / "bag", "sqlite3")
    with pytest.raises(BagError) as err:
        next(iter_messages(tmp_path / "bag", ["/joint_states", "/odom"]))
    text = str(err.value)
    assert "/odom" in text and "not in bag" in text
    assert "/joint_states [sensor_msgs/msg/JointState] (5 msgs)" in text
    assert "/scan [sensor_msgs/msg/LaserScan]" in text


def test_missing_path_and_not_a_bag(tmp_path):
    with pytest.raises(BagError, match="bag not found"):
        topic_info(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match="not a rosbag2 folder"):
        topic_info(tmp_path / "empty")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(BagError, match="not a rosbag2"):
        topic_info(tmp_path / "notes.txt")
    # A folder that only holds a storage file says which one to pass.
    write_sample_bag(tmp_path / "bag", "mcap")
    (tmp_path / "bag" / "metadata.yaml").unlink()
    with pytest.raises(BagError, match=r"bag\.mcap: pass one of them"):
        topic_info(tmp_path / "bag")


def test_corrupt_metadata_is_a_bag_error(tmp_path):
    write_sample_bag(tmp_path / "bag", "sqlite3")
    (tmp_path / "bag" / "metadata.yaml").write_text("rosbag2_bagfile_information: [not: a bag\n")
    with pytest.raises(BagError, match="cannot open bag"):
        with open_reader(tmp_path / "bag"):
            pass


def test_writer_refuses_existing_folder_and_unknown_storage(tmp_path):
    with pytest.raises(BagError, match="storage must be one of"):
        BagWriter(tmp_path / "x", "rosbag1")
    (tmp_path / "exists").mkdir()
    with pytest.raises(BagError, match="exists already"):
        with BagWriter(tmp_path / "exists"):
            pass


def test_one_topic_one_type(tmp_path):
    with BagWriter(tmp_path / "bag") as bag:
        bag.write_pose("/x", T0, (0, 0, 0))
        with pytest.raises(BagError, match="already carries"):
            bag.write_joint_state("/x", T0, ["a"], [1.0])
