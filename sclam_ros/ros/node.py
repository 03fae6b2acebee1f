"""``sclam_node``: online calibration on the live ROS graph.

The node is a thin shell around :class:`sclam_ros.online.calibrator.OnlineCalibrator`: it declares the
parameters of :class:`sclam_ros.core.params.SclamParams`, converts messages, and publishes what the
calibrator knows. The calibrator (scan registration, window solves) runs in a child process
(online/process.py): the subscription callbacks only integrate and publish ~/odom and hand the
messages over, so odometry never waits for a registration or a solve.

Subscribes
  ``joint_states_topic`` (sensor_msgs/JointState, reliable), or ``odometry_topic``
  (nav_msgs/Odometry, the base's wheel odometry, turned back into wheel rotations with the
  nominal values) when that is set, and ``scan_topic`` (sensor_msgs/LaserScan, sensor-data QoS).
Publishes (``~`` is the node name, ``/sclam`` by default)
  ``~/odom``             nav_msgs/Odometry ``odom_frame`` → ``base_frame``, one per JointState
                         accepted (the first at the origin with zero twist), with its stamp,
                         integrated with the current calibration; the pose covariance holds
                         the wheel noise accumulated along the path plus the calibration's own
                         uncertainty propagated through the whole path. A parameter the
                         data has not observed is integrated at its nominal value.
  ``~/laser_pose``       geometry_msgs/PoseWithCovarianceStamped, the laser on ``base_frame``;
                         covariance slots x, y, yaw (z, roll, pitch are fixed by the planar model);
                         stamped with the time of the newest scan the estimate includes.
                         A coordinate the data has not observed is the nominal one with its
                         prior variance (x, y: 4 m², yaw: (π/2)² rad²): that is its flag.
  ``~/wheel_parameters`` std_msgs/Float64MultiArray, a 3 × 3 row-major matrix::

                             [r_l,   r_r,   b,            # row "value"  (m)
                              σ_r_l, σ_r_r, σ_b,          # row "sigma"  (m)
                              o_r_l, o_r_r, o_b]          # row "observable" (1 or 0)

                         ``layout.dim`` names the rows ("value,sigma,observable") and the
                         columns ("wheel_radius_left,wheel_radius_right,wheel_base"). A
                         parameter the data has not observed (observable 0) is at its
                         nominal value with its prior σ.
  ``/diagnostics``       diagnostic_msgs/DiagnosticArray at 1 Hz (wall clock): window fill
                         (radii window, and its part kept as poses), radius changes detected
                         and the last change χ² (online/change_detector.py),
                         observability of each parameter (core/observability.py: an
                         unobserved one is at nominal, ``<name>_observable`` false), rejected
                         input by reason, last solve converged (WARN after 3 unconverged in a
                         row), scan matches confirmed of those made (WARN that the σ may be
                         too small where a noisy laser has most unconfirmed, as outdoors),
                         ``odom_published`` and ``odom_unanswered_<reason>``: every JointState
                         is answered on ~/odom or counted there by why not (not the two
                         wheel joints, a stamp repeated or going backwards), so the two add
                         up to ``joint_states_received`` (``odometry_received`` with
                         ``odometry_topic``).
                         A value not known yet (no estimate, no change test) is absent: never "nan".
  ``~/laser_pose`` and ``~/wheel_parameters`` are transient-local: a late subscriber gets the last one.
Services (std_srvs/Trigger)
  ``~/reset_window``       forget the window's keyframes (radii restart from their current value)
  ``~/reset_calibration``  back to the nominal calibration, all information dropped
  ``~/save_calibration``   write a parameters YAML with the current estimate to ``calibration_file``;
                           a parameter the data has not observed keeps its nominal (the
                           parameters file's, e.g. previously saved) value, named in the file
                           and in the response
Parameters
  every field of SclamParams (same names, defaults, units in the descriptions), plus
  ``calibration_file`` (default ``sclam_calibration.yaml``, relative to the working directory),
  and ``publish_tf`` (default false): also broadcast odom → ``base_frame`` on /tf and
  ``base_frame`` → the scan's frame on /tf_static (re-sent when it changes), if tf2_msgs is
  importable (ros/tf.py); without it the node says so once and publishes no TF.
  At runtime ``window_distance``, ``wheel_noise``, ``lateral_noise``, ``odom_frame``,
  ``base_frame`` and ``calibration_file`` can be changed; the others are read-only.
Zero configuration (ros/description.py)
  Each of ``left_wheel_joint``, ``right_wheel_joint``, ``wheel_radius_left``,
  ``wheel_radius_right``, ``wheel_base``, ``laser_x``, ``laser_y``, ``laser_yaw`` that the
  parameters (files, ``-p``) do not set is read from the latched ``/robot_description``
  (std_msgs/String, reliable, transient local) as ``sclam calibrate BAG`` reads it
  (io/zero_config.py), the laser's mount as the chain from ``base_frame`` to the first scan's
  frame; the parameter is declared then, with that value. Until then nothing is calibrated
  and every input is counted as ``waiting_for_description`` (rejected and, for the wheels,
  ``odom_unanswered``). A description without the two wheel joints is one error line, an
  ERROR in /diagnostics and ``robot_description_errors`` counted; a later one is read again.
  A laser the description does not place is one warning naming the fix and the parameters'
  values are kept: the node does not read /tf_static.
"""
from __future__ import annotations

import dataclasses
import gc
from dataclasses import fields

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.time import Time
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import JointState, LaserScan
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, String
from std_srvs.srv import Trigger

from sclam_ros.core.inputs import Rejections
from sclam_ros.core.params import (
    CALIBRATION_KEYS,
    NODE_NAME,
    ParamsError,
    SclamParams,
    check_parameter_value,
)
from sclam_ros.io.messages import (
    MessageRejected,
    check_scan,
    joint_state_to_raw,
    laser_scan_to_scan,
    odometry_to_pose,
)
from sclam_ros.frontend.odometry_wheels import WheelsFromOdometry
from sclam_ros.online.odometry import OdometryIntegrator
from sclam_ros.ros.description import FromDescription
from sclam_ros.ros.planar import covariance36, set_yaw
from sclam_ros.ros.parameters import declare_parameters, read_params, warn_unknown_parameters
from sclam_ros.ros.tf import TfBroadcaster
from sclam_ros.online.process import CalibratorProcess
from sclam_ros.online.status import (
    OK,
    WHEEL_PARAMETER_COLUMNS,
    WHEEL_PARAMETER_ROWS,
    diagnostic_status,
    wheel_parameters_data,
)

WARN_THROTTLE_S = 5.0
# The reason an input is dropped before the calibration has its wheel geometry.
WAITING = "waiting_for_description"


# Sensor-data QoS (best effort: matches every laser driver) with a history of about a
# second of scans instead of its 5: a scan lost costs the calibration an edge, and on a
# busy 2-core computer the executor can be away for longer than 5 scan periods
# (docs/decisions/runtime.md).
SCAN_QOS = QoSProfile(depth=50, reliability=qos_profile_sensor_data.reliability,
                      durability=qos_profile_sensor_data.durability,
                      history=qos_profile_sensor_data.history)


# --- the node -------------------------------------------------------------------------------


class SclamNode(Node):
    def __init__(self, node_name: str = NODE_NAME, **kwargs):
        super().__init__(node_name, **kwargs)
        # The wheel geometry and laser mount the parameters leave out: declared once the
        # robot description gives them (ros/description.py), with these descriptors.
        self._undeclared = declare_parameters(self)
        warn_unknown_parameters(self)
        self.params = read_params(self)
        self.calibration_file = self.get_parameter("calibration_file").value
        self.laser_frame = None  # header.frame_id of the scans, once one came
        self.rejections = Rejections()  # message conversion; the calibrator counts its own
        # JointStates ~/odom did not answer, by reason: with odom_published they add up to
        # joint_states_received.
        self.unanswered = Rejections()
        self.odom_published = 0
        # The wheel input: the base's odometry turned back into wheel rotations, or JointState.
        self.wheel_input = "odometry" if self.params.odometry_topic else "joint_states"
        self.received = {self.wheel_input: 0, "scan": 0}
        self.calibrator = None  # until the parameters are complete (_start)
        self.description = (FromDescription(self._undeclared, self.params.base_frame)
                            if self._undeclared else None)
        self.estimates = 0

        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.odom_pub = self.create_publisher(Odometry, "~/odom", 50)
        self.laser_pub = self.create_publisher(PoseWithCovarianceStamped, "~/laser_pose", latched)
        self.wheel_pub = self.create_publisher(Float64MultiArray, "~/wheel_parameters", latched)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.tf = (TfBroadcaster.create(self) if self.get_parameter("publish_tf").value
                   else None)
        if self.params.odometry_topic:
            self.create_subscription(Odometry, self.params.odometry_topic,
                                     self._on_wheel_odometry, 200)
            self.get_logger().info(
                f"wheel input: {self.params.odometry_topic} (nav_msgs/Odometry), turned back "
                "into wheel rotations with the nominal radii and wheel base, which must be "
                "those the odometry was computed with; a heading fused from an IMU is not the "
                "wheels' (docs/robot_inputs.md)")
        else:
            self.create_subscription(JointState, self.params.joint_states_topic,
                                     self._on_joint_state, 200)
        self.create_subscription(LaserScan, self.params.scan_topic, self._on_scan, SCAN_QOS)
        self.create_service(Trigger, "~/reset_window", self._reset_window)
        self.create_service(Trigger, "~/reset_calibration", self._reset_calibration)
        self.create_service(Trigger, "~/save_calibration", self._save_calibration)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        # Wall clock: diagnostics keep coming when sim time stands still.
        self.create_timer(1.0, self.publish_diagnostics, clock=Clock(clock_type=ClockType.STEADY_TIME))
        if self.description is None:
            self._start({})
            return
        # As robot_state_publisher publishes it: latched, so a late subscriber gets it.
        self.create_subscription(String, self.description.source, self._on_description, latched)
        self.get_logger().info(
            f"not set in the parameters: {', '.join(sorted(self._undeclared))}: waiting for "
            f"{self.description.source} to read them from (inputs until then are counted "
            f"as {WAITING}, not used)")

    def _start(self, inferred):
        """Declare the parameters left out (with the ``inferred`` values, else the
        defaults) and start calibrating."""
        for name, descriptor in sorted(self._undeclared.items()):
            self.declare_parameter(name, inferred.get(name, getattr(self.params, name)),
                                   descriptor)
        self._undeclared = {}
        self.params = read_params(self)
        self.odometry = OdometryIntegrator(self.params, rejections=self.unanswered)
        self.wheels_from_odometry = (WheelsFromOdometry(self.params)
                                     if self.params.odometry_topic else None)
        # Last: its reader thread publishes through the node's publishers.
        self.calibrator = CalibratorProcess(self.params, self._publish_estimate,
                                            self._calibrator_failed)
        # Everything allocated so far (rclpy, numpy, scipy, KISS-ICP, the node) lives as
        # long as the process: keep it out of the cyclic collector's full passes. Without
        # this a full collection walks it all and stalls callbacks and solver
        # (docs/decisions/runtime.md).
        gc.freeze()
        self.get_logger().info(
            f"calibrating from {self.params.joint_states_topic} ({self.params.left_wheel_joint}, "
            f"{self.params.right_wheel_joint}) and {self.params.scan_topic}"
        )

    def _on_description(self, msg: String):
        if self.calibrator is not None:
            return  # the parameters are read-only: a new description needs a restart
        if not self.description.read(msg.data):
            self.get_logger().error(f"cannot calibrate: {self.description.error}")
            return
        self._start_from_description()

    def _start_from_description(self):
        found = self.description.values(self.laser_frame)
        if found is None:
            return  # no usable description yet, or no scan to name the laser's frame
        values, line, warning = found
        try:
            dataclasses.replace(self.params, **values).validate()
        except ParamsError as exc:  # a cylinder no wheel has
            self.description.refuse(f"{self.description.source}: {exc}")
            self.get_logger().error(f"cannot calibrate: {self.description.error}")
            return
        self.get_logger().info(f"from {line}")
        if warning:
            self.get_logger().warn(warning)
        self._start(values)

    def destroy_node(self):
        if self.calibrator is not None:
            self.calibrator.stop()
        return super().destroy_node()

    # --- parameters ---------------------------------------------------------------------
    def _on_set_parameters(self, parameters) -> SetParametersResult:
        defaults = {f.name: f.default for f in fields(SclamParams)}
        for p in parameters:
            if p.name == "calibration_file":
                if not isinstance(p.value, str) or not p.value:
                    return SetParametersResult(successful=False,
                                               reason="calibration_file must be a non-empty path")
                continue
            if p.name in defaults:
                reason = check_parameter_value(p.name, p.value, defaults[p.name])
                if reason:
                    return SetParametersResult(successful=False, reason=reason)
        for p in parameters:
            if p.name == "calibration_file":
                self.calibration_file = p.value
            elif p.name in defaults:
                value = p.value if isinstance(defaults[p.name], str) else float(p.value)
                setattr(self.params, p.name, value)
                if self.calibrator is None:
                    continue  # it starts with self.params
                if p.name == "window_distance":
                    self.calibrator.set_window_distance(value)
                else:
                    self.calibrator.set_param(p.name, value)
        return SetParametersResult(successful=True)

    # --- input --------------------------------------------------------------------------
    def _reject(self, reason: str, detail: str):
        self.rejections.add(reason)
        self.get_logger().warn(f"input dropped ({reason}): {detail}",
                               throttle_duration_sec=WARN_THROTTLE_S)

    def _on_joint_state(self, msg: JointState):
        self._on_wheels(msg, lambda: joint_state_to_raw(msg, self.params))

    def _on_wheel_odometry(self, msg: Odometry):
        def wheel_angles():
            stamp, pose, yaw_rate = odometry_to_pose(msg, self.params)
            return (stamp, *self.wheels_from_odometry.add(stamp, pose, yaw_rate))
        self._on_wheels(msg, wheel_angles)

    def _on_wheels(self, msg, wheel_angles):
        """One wheel-input message: ``wheel_angles()`` gives (stamp, left, right) or raises
        MessageRejected; answered on ~/odom and handed to the calibrator."""
        self.received[self.wheel_input] += 1
        if self.calibrator is None:
            self.unanswered.add(WAITING)
            self._reject(WAITING, self._waiting_for())
            return
        try:
            stamp, left, right = wheel_angles()
        except MessageRejected as exc:
            self.unanswered.add(exc.reason)
            self._reject(exc.reason, exc.detail)
            return
        published = self.odom_published
        try:
            self._publish_odometry(msg, stamp, left, right)
            self.calibrator.add_encoder(stamp, left, right)
        except Exception as exc:  # never let one message take the node down
            if self.odom_published == published:
                self.unanswered.add("internal_error")
            self._reject("internal_error", f"{type(exc).__name__}: {exc}")

    def _on_scan(self, msg: LaserScan):
        self.received["scan"] += 1
        try:
            scan = laser_scan_to_scan(msg)
            self.laser_frame = scan.frame_id
            if self.calibrator is None:
                self._start_from_description()  # when it waits for the laser's frame
            if self.calibrator is None:
                self._reject(WAITING, self._waiting_for())
                return
            check_scan(scan)  # the bag path's gate too (io/recording.py)
            self.calibrator.add_scan(scan)
        except MessageRejected as exc:  # bad geometry, empty, bad stamp: counted under its reason
            self._reject(exc.reason, exc.detail)
        except Exception as exc:
            self._reject("internal_error", f"{type(exc).__name__}: {exc}")

    def _calibrator_failed(self, message: str):
        self._reject("internal_error", message)

    # --- output -------------------------------------------------------------------------
    def _odometry_calibration(self):
        status = self.calibrator.status  # one reference: calibration and σ of one moment
        k = np.asarray(status.calibration[:3], float)
        estimate = status.estimate
        k_cov = estimate.covariance[:3, :3] if estimate is not None else np.zeros((3, 3))
        return k, k_cov

    def _publish_odometry(self, msg, stamp, left, right):
        k, k_cov = self._odometry_calibration()
        if not self.odometry.add(stamp, left, right, k, k_cov):
            return  # refused: counted in self.unanswered by the integrator's stream
        odom = Odometry()
        odom.header.stamp = msg.header.stamp
        odom.header.frame_id = self.params.odom_frame
        odom.child_frame_id = self.params.base_frame
        pose = self.odometry.pose
        odom.pose.pose.position.x = float(pose[0])
        odom.pose.pose.position.y = float(pose[1])
        set_yaw(odom.pose.pose.orientation, float(pose[2]))
        odom.pose.covariance = covariance36(self.odometry.covariance(k_cov))
        twist = self.odometry.twist
        odom.twist.twist.linear.x = float(twist[0])
        odom.twist.twist.linear.y = float(twist[1])
        odom.twist.twist.angular.z = float(twist[2])
        odom.twist.covariance = covariance36(self.odometry.twist_cov)
        self.odom_pub.publish(odom)
        self.odom_published += 1
        if self.tf is not None:
            self.tf.odometry(odom.header.stamp, odom.header.frame_id, odom.child_frame_id, pose)

    def _publish_estimate(self, estimate):
        """~/laser_pose and ~/wheel_parameters (called on the calibrator's reader thread)."""
        self.estimates += 1
        laser = PoseWithCovarianceStamped()
        # The data's time, not the publication's: the calibration as of the newest scan in
        # the solved window (REP-103 stamps; lets a subscriber see how old the estimate is).
        laser.header.stamp = Time(nanoseconds=int(round(estimate.stamp * 1e9))).to_msg()
        laser.header.frame_id = self.params.base_frame
        laser.pose.pose.position.x = float(estimate.values["laser_x"])
        laser.pose.pose.position.y = float(estimate.values["laser_y"])
        set_yaw(laser.pose.pose.orientation, float(estimate.values["laser_yaw"]))
        laser.pose.covariance = covariance36(np.asarray(estimate.covariance)[3:, 3:])
        self.laser_pub.publish(laser)
        if self.tf is not None and self.laser_frame:
            self.tf.laser(laser.header.stamp, self.params.base_frame, self.laser_frame,
                          [estimate.values[k] for k in ("laser_x", "laser_y", "laser_yaw")])

        wheels = Float64MultiArray()
        wheels.layout.dim = [
            MultiArrayDimension(label=",".join(WHEEL_PARAMETER_ROWS), size=len(WHEEL_PARAMETER_ROWS),
                                stride=len(WHEEL_PARAMETER_ROWS) * len(WHEEL_PARAMETER_COLUMNS)),
            MultiArrayDimension(label=",".join(WHEEL_PARAMETER_COLUMNS),
                                size=len(WHEEL_PARAMETER_COLUMNS), stride=len(WHEEL_PARAMETER_COLUMNS)),
        ]
        wheels.data = wheel_parameters_data(estimate)
        self.wheel_pub.publish(wheels)

    def _waiting_for(self) -> str:
        """What the node waits for before it calibrates."""
        if self.description.error:
            return f"cannot calibrate: {self.description.error}"
        if self.description.read_one:
            return f"waiting for a scan on {self.params.scan_topic} to name the laser's frame"
        return (f"waiting for {self.description.source} to read "
                f"{', '.join(sorted(self._undeclared))} from")

    def _waiting_status(self):
        """(level, message, values) before the calibration has its wheel geometry."""
        values = {f"{name}_received": n for name, n in self.received.items() if name != "scan"}
        values["scans_received"] = self.received["scan"]
        values["rejected_total"] = self.rejections.total()
        for reason, n in sorted(self.rejections.counts.items()):
            values[f"rejected_{reason}"] = n
        level = DiagnosticStatus.ERROR if self.description.error else DiagnosticStatus.WARN
        return level, self._waiting_for(), values

    def diagnostic_status(self) -> DiagnosticStatus:
        if self.calibrator is None:
            level, message, values = self._waiting_status()
        else:
            rejections = Rejections(self.rejections.counts + self.calibrator.rejections.counts)
            level, message, values = diagnostic_status(self.calibrator.status, self.params,
                                                       self.received, rejections,
                                                       self.calibrator.config)
            level = DiagnosticStatus.OK if level == OK else DiagnosticStatus.WARN
            # Messages handed to the calibrator process and not yet taken: stays near 0 when
            # it keeps up with the sensors.
            values["calibrator_backlog"] = self.calibrator.backlog
            if not self.calibrator.alive:
                level = DiagnosticStatus.ERROR
                message = self.calibrator.failure or "calibrator process not running"
        values["odom_published"] = self.odom_published
        for reason, n in sorted(self.unanswered.counts.items()):
            values[f"odom_unanswered_{reason}"] = n
        if self.description is not None:
            values["robot_description_errors"] = self.description.errors
        status = DiagnosticStatus(level=level, name=f"{self.get_name()}: calibration",
                                  message=message, hardware_id=self.get_name())
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        return status

    def publish_diagnostics(self):
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [self.diagnostic_status()]
        self.diag_pub.publish(array)

    # --- services -----------------------------------------------------------------------
    def _not_calibrating(self, response) -> bool:
        """True, with the response saying why, while the node waits for the description."""
        if self.calibrator is None:
            response.success, response.message = False, f"not calibrating: {self._waiting_for()}"
        return self.calibrator is None

    def _reset_window(self, request, response):
        if self._not_calibrating(response):
            return response
        self.calibrator.reset_window()
        response.success, response.message = True, "window cleared"
        self.get_logger().info("window reset")
        return response

    def _reset_calibration(self, request, response):
        if self._not_calibrating(response):
            return response
        self.calibrator.reset_calibration()
        response.success, response.message = True, "calibration back to nominal"
        self.get_logger().info("calibration reset to nominal")
        return response

    def current_params(self, status=None) -> SclamParams:
        """The parameters with the current calibration in place of the nominal one (where
        the data has not observed a parameter, the calibrator reports the nominal value)."""
        status = self.calibrator.status if status is None else status
        values = dict(zip(CALIBRATION_KEYS, map(float, status.calibration)))
        return self.params.with_calibration(values)

    def _save_calibration(self, request, response):
        if self._not_calibrating(response):
            return response
        status = self.calibrator.status  # one reference: values and flags of one moment
        unobserved = [k for k in CALIBRATION_KEYS if not status.observable[k]]
        kept = ""
        if status.estimate is not None and unobserved:
            kept = "; not observed by the data, kept at their nominal values: " + ", ".join(unobserved)
        try:
            header = "# written by sclam_node ~/save_calibration\n"
            if status.estimate is None:
                header += "# no estimate yet: these are the nominal values\n"
            elif unobserved:
                header += f"# {kept[2:]}\n"
            self.current_params(status).write_yaml(self.calibration_file, self.get_name(), header)
        except (OSError, ParamsError) as exc:
            response.success, response.message = False, f"cannot write {self.calibration_file}: {exc}"
            return response
        response.success, response.message = True, f"calibration written to {self.calibration_file}{kept}"
        self.get_logger().info(response.message)
        return response
