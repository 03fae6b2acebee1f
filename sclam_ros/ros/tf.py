"""sclam_node's optional TF output (parameter ``publish_tf``): odom → base_link from the
calibrated odometry on /tf, and base_link → laser from the calibration on /tf_static.

Published as tf2_ros' broadcasters do (tf2_msgs/TFMessage; /tf_static transient-local, depth
1) without needing tf2_ros itself. tf2_msgs is not among the ROS 2 PyPI wheels this package
installs from: without it the node says so once and publishes no TF.
"""
from __future__ import annotations

from geometry_msgs.msg import TransformStamped
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from sclam_ros.ros.planar import set_yaw

try:
    from tf2_msgs.msg import TFMessage
except ImportError:  # a ROS install has it; the PyPI wheels do not
    TFMessage = None

TF_MISSING = ("publish_tf is true, but tf2_msgs is not importable (not in the PyPI wheels; "
              "install ros-jazzy-tf2-msgs): TF is not published; ~/odom and ~/laser_pose are")
STATIC_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _transform(stamp, parent, child, pose) -> TransformStamped:
    tf = TransformStamped()
    tf.header.stamp = stamp
    tf.header.frame_id = parent
    tf.child_frame_id = child
    tf.transform.translation.x = float(pose[0])
    tf.transform.translation.y = float(pose[1])
    set_yaw(tf.transform.rotation, float(pose[2]))
    return tf


class TfBroadcaster:
    """Publishers of /tf and /tf_static on ``node``; :meth:`create` gives None (and logs why,
    once) when tf2_msgs is missing."""

    def __init__(self, node):
        self.tf_pub = node.create_publisher(TFMessage, "/tf", 100)
        self.static_pub = node.create_publisher(TFMessage, "/tf_static", STATIC_QOS)
        self._laser = None  # (parent, child, pose) last sent on /tf_static

    @classmethod
    def create(cls, node):
        if TFMessage is None:
            node.get_logger().warn(TF_MISSING)
            return None
        return cls(node)

    def odometry(self, stamp, odom_frame, base_frame, pose) -> None:
        self.tf_pub.publish(TFMessage(transforms=[_transform(stamp, odom_frame, base_frame, pose)]))

    def laser(self, stamp, base_frame, laser_frame, pose) -> None:
        """Latched: sent again only when the pose or a frame name changes, so /tf_static
        carries one message per calibration instead of one per window solve."""
        key = (base_frame, laser_frame, tuple(round(float(v), 9) for v in pose))
        if key == self._laser:
            return
        self._laser = key
        self.static_pub.publish(
            TFMessage(transforms=[_transform(stamp, base_frame, laser_frame, pose)]))
