"""`needle_simulator`: the ANCF needle in real time, driven by base-pose topics, publishing wrench and shape.

Thin ROS layer over :class:`needle_sim_ros.simulation.NeedleSimulation`. A dedicated thread runs the fixed-rate loop:
each tick takes the poses that arrived (:mod:`needle_sim_ros.nodes.polling`) and advances the model by elapsed clock
time; the executor serves the tip load, services and parameters; an output thread publishes shapes, visualization
and diagnostics. With ``haptics.enable`` each step also yields the operator's force on ``topics.haptic``
(:mod:`needle_sim_ros.haptics`), and every stop publishes a zero wrench there first. Time
(:mod:`needle_sim_ros.clock_loop`): with ``use_sim_time`` the node follows ``/clock`` deterministically; in
wall-clock mode up to now, extrapolating the newest pose up to ``pose_input.max_extrapolation``.
"""
from __future__ import annotations

import gc
import math
import os
import sys
import threading
import time

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseArray, PoseStamped, TwistStamped, WrenchStamped
from nav_msgs.msg import Path
from needle_interfaces.msg import NeedleShape, NeedleState
from needle_interfaces.srv import ApplyPointLoad, ClearPointLoads
from rclpy.duration import Duration
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker

from needle_common.cdr import pose_stamped
from needle_common.parameters import ParameterError

from needle_sim_ros.base_trajectory import PoseVerdict
from needle_sim_ros.haptics import ZERO, HapticShaper
from needle_sim_ros.inputs import USED_POSES, InputRejected, SimulatorInputs, rejected_poses
from needle_sim_ros.messages import cdr
from needle_common.transforms import conjugate, multiply, quaternion_matrix, quaternions_from_x_axes
from needle_sim_ros.messages.centerline_display import COLORS, path_and_tube
from needle_sim_ros.messages.geometry import compile_geometry_kernels
from needle_sim_ros.messages.shape import model_shape_cdr, time_msg
from needle_sim_ros.model import BaseMotion, State, elastic_energy, kinetic_energy, model_shape
from needle_sim_ros.nodes.diagnostics import ERROR, OK, WARN, HealthMonitor
from needle_sim_ros.nodes.lifecycle import autostart, when_configured
from needle_common.ros.input_status import InputStatus
from needle_common.ros.ros_parameters import declare_all, guard_dynamic_updates, qos_profile
from needle_sim_ros.nodes.polling import MessageWaiter, PolledCallbackGroup, drain
from needle_common.ros.runner import run_node
from needle_common.ros.tf_output import TfOutput, transform_stamped
from needle_sim_ros.parameters.simulator import FIXED_AT_CONSTRUCTION, SIMULATOR_PARAMETERS
from needle_sim_ros.simulation import (
    LATE_POSE_WAIT, apply_tip_force, compile_kernels, model_builder_from_parameters, simulation_from_parameters,
    step_wrenches)

WARN_PERIOD = 2.0  # [s] throttle of repeated input warnings
ZERO_ACK_WAIT = 0.5  # [s] longest wait for the haptic subscribers to acknowledge the zero sent at exit


class NeedleSimulatorNode(LifecycleNode):
    """Managed node (:mod:`needle_sim_ros.nodes.lifecycle`): configure builds the model, activate starts integrating
    from the next base pose, deactivate holds the last state, cleanup frees the model."""

    def __init__(self) -> None:
        super().__init__("needle_simulator")
        self.p = declare_all(self, SIMULATOR_PARAMETERS, lifecycle_fixed=FIXED_AT_CONSTRUCTION)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.sim = None
        self.inputs: SimulatorInputs | None = None  # the input rules around self.sim
        self.active = False
        self.configure_error = ""
        self.use_sim_time = self.get_parameter("use_sim_time").value
        self.counters = {verdict: 0 for verdict in PoseVerdict}
        self.counters_other = {"wrong_frame": 0, "stamp_replaced": 0, "twist_rejected": 0, "tip_load_rejected": 0}
        self.started_at = math.nan  # stamp [s] of the pose the needle last (re)started at
        self.activated_at = math.nan  # node clock [s] at the last activation
        self.start_received_at = math.nan  # system clock [s] when that pose reached this process (middleware)
        self.deadline_misses = 0
        self.catch_up_steps = 0
        self.health = HealthMonitor()
        self._warned_at: dict[str, float] = {}

        topics = {k.split(".", 1)[1]: v for k, v in self.p.items() if k.startswith("topics.")}
        self.wrench_pub = self.create_publisher(WrenchStamped, topics["wrench"], qos_profile(self.p["qos.wrench"], 100))
        self.shape_pub = self.create_publisher(NeedleShape, topics["shape"], 10)
        self.path_pub = self.create_publisher(Path, topics["path"], 10)
        self.marker_pub = self.create_publisher(Marker, topics["marker"], 10)
        self.pose_array_pub = self.create_publisher(PoseArray, topics["pose_array"], 10)
        self.state_pub = self.create_publisher(NeedleState, topics["state"], 10)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.haptic_pub = (self.create_publisher(WrenchStamped, topics["haptic"],
                                                 qos_profile(self.p["qos.haptic"], 100))
                           if self.p["haptics.enable"] else None)
        self.haptics: HapticShaper | None = None
        self._haptic_lock = threading.Lock()  # the loop's haptic wrenches vs. the zero of a stop
        self._haptic_live = False  # the loop may publish haptic wrenches (active, not stopping)
        self._clipped_reported = 0  # clipped components at the previous diagnostics report
        self.tf = TfOutput(self)  # world -> base (the base pose), base -> tip (the deformed needle's tip)
        # Poses and twists are taken by the integration loop itself at each tick (see nodes.polling).
        polled = PolledCallbackGroup()
        self._polled = [
            self.create_subscription(PoseStamped, topics["base_pose"], self.on_pose,
                                     qos_profile(self.p["qos.base_pose"], 100), callback_group=polled, raw=True),
            self.create_subscription(TwistStamped, topics["base_twist"], self.on_twist,
                                     qos_profile(self.p["qos.base_pose"], 100), callback_group=polled)]
        self._pose_waiter = MessageWaiter(self._polled, self.context)
        inputs = InputStatus(self, accepting=lambda: self.active)
        inputs.track(self._polled[0])
        inputs.track(self._polled[1], self.create_subscription(WrenchStamped, topics["tip_load"], self.on_tip_load, 10),
                     optional=True)  # twist and tip load: OK without a publisher
        configured = lambda: self.sim is not None  # noqa: E731
        self.create_service(Trigger, "~/reset", when_configured(configured, self.on_reset))
        self.create_service(ApplyPointLoad, "~/apply_point_load", when_configured(configured, self.on_apply_point_load))
        self.create_service(ClearPointLoads, "~/clear_point_loads",
                            when_configured(configured, self.on_clear_point_loads))
        guard_dynamic_updates(self, SIMULATOR_PARAMETERS, self.on_parameters_changed,
                              unconfigured=lambda: self.sim is None, fixed=FIXED_AT_CONSTRUCTION)
        self._next_output = {"shape": 0.0, "visualization": 0.0, "diagnostics": 0.0}
        self._loop = threading.Thread(target=self.run_loop_or_zero, name="needle_integration", daemon=True)
        self._outputs = threading.Thread(target=self.run_outputs, name="needle_outputs", daemon=True)
        # The output thread's work comes in pieces of up to ~1 ms; a short GIL switch interval lets the integration
        # thread take over within 0.2 ms instead of Python's default 5 ms.
        sys.setswitchinterval(2e-4)
        if self.p["autostart"]:
            autostart(self)
        self.get_logger().info(
            "needle_simulator ready ("
            f"{'active' if self.active else 'unconfigured: waiting for lifecycle transitions'}): "
            f"{self.p['needle.elements']} elements, dt = {self.p['integrator.dt'] * 1e3:g} ms, "
            f"{'simulated' if self.use_sim_time else 'wall-clock'} time; base poses on "
            f"'{self.resolve_topic_name(topics['base_pose'])}'"
            + (f"; haptic output on '{self.haptic_pub.topic_name}' ({self.p['haptics.frame']} frame)"
               if self.haptic_pub is not None else ""))

    # -- lifecycle -------------------------------------------------------------------------------------------
    def on_configure(self, state) -> TransitionCallbackReturn:
        """Load the parameters in force, check them together and build the model (compiling the kernels)."""
        try:
            self.p = {spec.name: spec.validate(self.get_parameter(spec.name).value) for spec in SIMULATOR_PARAMETERS}
            sim = simulation_from_parameters(self.p)
        except (ParameterError, ValueError) as error:
            self.configure_error = (str(error) if isinstance(error, ParameterError)
                                    else f"tissue parameters: {error}")
            self.get_logger().error(f"configure failed: {self.configure_error}")
            return TransitionCallbackReturn.FAILURE
        # Before any topic is active: once active the node steps at full speed from the first pose.
        start = time.perf_counter()
        compile_kernels(self.p)
        compile_geometry_kernels()
        self.get_logger().info(f"compiled/loaded the numerical kernels in {time.perf_counter() - start:.1f} s")
        with self._lock:
            self.sim, self.props = sim, sim.model.props
            self.inputs = self.simulator_inputs()
            if self.use_sim_time:
                # Simulated time: one shape per step that crosses the 1/shape_hz grid, stamped with that step's
                # time, so a replay yields every shape whatever the machine load (the output thread only visualizes).
                self.sim.after_step = self.publish_shape_on_grid
        # Everything built so far (modules, compiled kernels, the model) lives until cleanup: keep it out of the
        # garbage collector's full passes, which would otherwise stall the loop for milliseconds now and then.
        gc.collect()
        gc.freeze()
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        """Integrate again, starting straight at the next base pose (poses received while inactive are dropped:
        also those still queued, e.g. while the kernels loaded, whose lag would be skipped at the first steps)."""
        with self._lock:
            self.sim.trajectory.clear()
            self.sim.discard_state()
            self.activated_at = self.now_seconds()
            dropped = sum(drain(subscription, run_callback=False) for subscription in self._polled)
            self.active = True
        if self.haptic_pub is not None:
            with self._haptic_lock:
                self.haptics = HapticShaper(self.p["haptics.max_force"], self.p["haptics.max_torque"],
                                            self.p["haptics.pose_timeout"], self.p["haptics.resume_ramp"],
                                            world_frame=self.p["haptics.frame"] == "base")
                self._haptic_live, self._clipped_reported = True, 0
        if dropped:
            self.get_logger().info(f"dropped {dropped} base pose/twist message(s) received before activation")
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        """Hold (also at shutdown): no more steps, wrenches or shapes; the last state stays (``~/reset`` and loads
        still work); the haptic output sends zero."""
        with self._lock:
            self.active = False
        self.zero_haptics()
        return TransitionCallbackReturn.SUCCESS

    on_shutdown = on_deactivate

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        with self._lock:
            self.active, self.sim, self.inputs = False, None, None
        self.zero_haptics()
        gc.unfreeze()
        gc.collect()
        return TransitionCallbackReturn.SUCCESS

    # -- construction helpers --------------------------------------------------------------------------------
    def warn_throttled(self, key: str, message: str) -> None:
        now = time.monotonic()
        if now - self._warned_at.get(key, -np.inf) >= WARN_PERIOD:
            self._warned_at[key] = now
            self.get_logger().warning(message)

    def simulator_inputs(self) -> SimulatorInputs:
        """The input rules around the configured simulation, with the parameters in force."""
        return SimulatorInputs(self.sim, self.p["frames.world"], self.p["frames.base"],
                               math.inf if self.use_sim_time else self.p["pose_input.max_stamp_offset"])

    def now_seconds(self) -> float:
        if not self.use_sim_time:
            return time.time()  # the ROS clock without simulated time is the system clock; 10x cheaper
        return self.get_clock().now().nanoseconds * 1e-9

    # -- inputs ----------------------------------------------------------------------------------------------
    def on_pose(self, data: bytes, info: dict) -> None:
        """A serialized PoseStamped (the subscription is raw: decoding it is ~10x cheaper than rclpy's objects) and
        its message info (the middleware's reception time: when the pose reached this process, for the haptic
        watchdog, however late the loop takes it)."""
        if not self.active:  # lifecycle: poses count from activation on
            return
        pose = pose_stamped(data)
        received, own_stamp = self.now_seconds(), pose.stamp_ns * 1e-9
        try:
            with self._lock:
                started = self.sim.started
                verdict, stamp, replaced = self.inputs.offer_pose(pose.frame_id, own_stamp, pose.position,
                                                                  pose.orientation, received)
                self.counters[verdict] += 1
        except InputRejected as error:
            self.counters_other[error.kind] += 1
            self.warn_throttled(error.kind, f"ignoring {error}")
            return
        if replaced:
            self.counters_other["stamp_replaced"] += 1
            self.warn_throttled("stamp", f"base pose stamp {own_stamp:.3f} s is unset or {own_stamp - received:+.3f} s "
                                         "from now: using the receive time instead")
        if self.haptics is not None and verdict in USED_POSES:
            age = max(time.time() - info["received_timestamp"] * 1e-9, 0.0)  # system clock, as rmw stamps it
            self.haptics.pose_arrived(time.monotonic() - age)
        if (self.sim.started and not started) or verdict in (PoseVerdict.RESTARTED, PoseVerdict.REANCHORED):
            self.started_at, self.start_received_at = stamp, info["received_timestamp"] * 1e-9
        if self.sim.started and not started:
            self.get_logger().info(f"first base pose received (stamp {stamp:.6f} s): needle initialised at rest at it")
        if verdict is PoseVerdict.NORMALIZED:
            self.warn_throttled("normalized", "base pose quaternion was not unit length: normalized")
        elif verdict is PoseVerdict.RESTARTED:
            self.get_logger().warning(f"base pose after a gap of more than {self.p['pose_input.timeout']:g} s, "
                                      f"more than {self.p['pose_input.resume_tolerance']:g} m from the held pose: "
                                      "needle restarted at rest at it")
        elif verdict is PoseVerdict.REANCHORED:
            self.get_logger().warning("base pose jumped and stayed there: needle restarted at rest at the new pose")
        elif verdict not in (PoseVerdict.ACCEPTED,):
            self.warn_throttled(verdict.name, f"base pose {verdict.value}; keeping the previous trajectory")

    def on_twist(self, msg: TwistStamped) -> None:
        if not self.active:
            return
        try:
            with self._lock:
                self.inputs.on_twist(msg, self.now_seconds())
        except InputRejected as error:
            self.counters_other[error.kind] += 1
            self.warn_throttled(error.kind, f"ignoring {error}")

    def on_tip_load(self, msg: WrenchStamped) -> None:
        """A force on the tip from a topic (a recorded experiment's tip mass); replaces the previous one."""
        try:
            with self._lock:
                if self.sim is None:
                    return
                self.inputs.on_tip_load(msg)
        except InputRejected as error:
            self.counters_other[error.kind] += 1
            self.warn_throttled(error.kind, f"ignoring tip load: {error}")

    # -- services and parameters -----------------------------------------------------------------------------
    def on_reset(self, request, response):
        with self._lock:
            latest = self.sim.trajectory.latest
            if latest is None:
                response.success, response.message = False, "no base pose received yet"
                return response
            t = self.sim.state.t if self.sim.started else latest.t
            self.sim.reset(self.sim.base_motion_at(t), t)
        response.success, response.message = True, "needle reset to the straight state at the current base pose"
        return response

    def on_apply_point_load(self, request, response):
        force = (request.force.x, request.force.y, request.force.z)
        try:
            with self._lock:
                self.inputs.set_point_load(request.name or "default", request.arc_length, request.frame_id, force)
        except InputRejected as error:
            response.success, response.message = False, str(error)
            return response
        response.success = True
        response.message = f"load '{request.name or 'default'}' applied at s = {request.arc_length:g} m"
        return response

    def on_clear_point_loads(self, request, response):
        with self._lock:
            response.removed = self.sim.clear_point_loads(list(request.names))
        response.success, response.message = True, f"removed {response.removed} load(s)"
        return response

    def on_parameters_changed(self, changed: dict) -> None:
        with self._lock:
            if "loads.tip_force" in changed and self.sim is not None:
                apply_tip_force(self.sim, changed["loads.tip_force"])  # first: a load it cannot carry refuses all
            self.p.update(changed)
            if self.haptics is not None:
                self.haptics.max_force = self.p["haptics.max_force"]
                self.haptics.max_torque = self.p["haptics.max_torque"]
            if self.sim is None:  # unconfigured: configure builds with the new values
                return
            self.inputs = self.simulator_inputs()
            if {"damping.rayleigh_alpha", "damping.rayleigh_beta"} & changed.keys():
                self.sim.stepper.rebuild_model(model_builder_from_parameters(self.p))

    # -- the real-time loop ----------------------------------------------------------------------------------
    def start(self) -> None:
        self._loop.start()
        self._outputs.start()

    def run_loop_or_zero(self) -> None:
        """The integration thread: :meth:`run_loop`; should it ever end other than by shutdown (an error no
        iteration caught), the haptic output is zeroed: nothing would render otherwise, nor tell the arm."""
        try:
            self.run_loop()
        finally:
            if not self._stop.is_set() and rclpy.ok():
                self.get_logger().error("the integration loop ended: haptic output zeroed, no more steps")
                self.zero_haptics()

    def finish(self) -> None:
        """Stop the loop and output threads, then send the haptic zero and wait briefly for its acknowledgement
        (also when the process ends by SIGINT/SIGTERM or an exception: :func:`needle_common.ros.runner.run_node`
        keeps the context alive until this ran)."""
        self._stop.set()
        for thread in (self._loop, self._outputs):
            if thread.is_alive():
                thread.join(timeout=2.0)
        self._pose_waiter.close()
        self.zero_haptics(wait=ZERO_ACK_WAIT)

    def zero_haptics(self, wait: float = 0.0) -> None:
        """Stop the haptic output: the loop publishes no more haptic wrenches until the next activation, and one zero
        wrench goes out now; ``wait`` > 0: wait up to that long [s] until every reliable subscriber acknowledged it."""
        if self.haptic_pub is None or not self.context.ok():  # a context shut down can publish nothing
            return
        with self._haptic_lock:
            self._haptic_live = False
            self.haptic_pub.publish(cdr.wrench_stamped_many(self.haptic_frame, [(self.now_seconds(), ZERO, ZERO)])[0])
        if wait > 0.0 and not self.haptic_pub.wait_for_all_acked(Duration(nanoseconds=int(wait * 1e9))):
            self.get_logger().warning(f"the haptic zero was not acknowledged by every subscriber within {wait:g} s")

    @property
    def haptic_frame(self) -> str:
        return self.p["frames.world"] if self.p["haptics.frame"] == "base" else self.p["frames.base"]

    def run_outputs(self) -> None:
        """Shapes, visualization and diagnostics at their rates, off the integration thread. Between outputs the
        thread sleeps until the next is due (2-20 ms) and takes the GIL from the integration thread only with work."""
        wait = 0.002
        while not self._stop.wait(wait) and rclpy.ok():
            try:
                now = self.now_seconds()
                if self.active and self.sim.started:
                    self.publish_periodic_outputs(now)
                self.publish_diagnostics_if_due(now)
                wait = min(max(min(self._next_output.values()) - now, 0.002), 0.02)
            except Exception as error:  # noqa: BLE001 - outputs must outlive any single bad iteration
                if self._stop.is_set() or not rclpy.ok():
                    break
                self.warn_throttled("outputs", f"publishing outputs failed: {error!r}")

    @property
    def ahead_to_pose(self) -> bool:
        """loop.ahead_to_pose, in wall-clock time (simulated time steps on its clock only: deterministic)."""
        return self.p["loop.ahead_to_pose"] and not self.use_sim_time

    def run_loop(self) -> None:
        """Ticks until shutdown. In wall-clock time a tick is timed to the next step's end time, so it integrates one
        step and publishes its wrench at once (a step integrated more than a period late is a deadline miss); with
        ``loop.ahead_to_pose`` a pose wakes the loop between ticks (a tick waits ``LATE_POSE_WAIT`` of a period more for
        a late pose: ``ClockLoop.lock_phase``). In simulated time ticks come every dt."""
        period = self.p["integrator.dt"]
        busy = self.p["loop.busy_wait"]
        grace = LATE_POSE_WAIT * period if self.ahead_to_pose else 0.0
        if not self.use_sim_time:  # simulated time needs no tick accuracy
            self.request_realtime_priority(self.p["loop.realtime_priority"])
        deadline = time.perf_counter()
        ready = self._polled  # the subscriptions to take messages from at the next iteration
        while not self._stop.is_set() and rclpy.ok():
            try:
                self.loop_iteration(ready)
            except Exception as error:  # noqa: BLE001 - the loop must outlive any single bad iteration
                if self._stop.is_set() or not rclpy.ok():
                    break
                self.warn_throttled("loop", f"integration loop iteration failed: {error!r}")
            if not self.use_sim_time and self.active and self.sim.started:
                deadline = time.perf_counter() + (self.sim.next_step_end + grace - self.now_seconds())
            else:
                deadline += period
            remaining = deadline - time.perf_counter()
            ready = self._polled
            if remaining < -10 * period:  # far behind (e.g. suspended): re-phase instead of bursting
                deadline = time.perf_counter()
            elif remaining > busy:
                if not self.ahead_to_pose:
                    time.sleep(remaining - busy)
                elif woken := self.wait_for_pose(remaining - busy):
                    ready = woken
                    continue  # a pose mid-period: its step at once
            while time.perf_counter() < deadline:
                pass

    def wait_for_pose(self, timeout: float) -> list:
        """Wait up to ``timeout`` [s] for a message on the polled subscriptions: those with one (none: timed out);
        sleeps instead if the wait set fails (e.g. the context shutting down under it)."""
        try:
            return self._pose_waiter.wait(timeout)
        except Exception as error:  # noqa: BLE001 - rcl errors of a wait set whose context is going away
            if not (self._stop.is_set() or not rclpy.ok()):
                self.warn_throttled("wait", f"waiting for poses failed, sleeping instead: {error!r}")
            time.sleep(timeout)
            return []

    def request_realtime_priority(self, priority: int) -> None:
        """Put the calling (integration) thread under SCHED_FIFO with the given priority, if asked and allowed."""
        if priority <= 0:
            return
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))  # 0: the calling thread on Linux
        except (OSError, AttributeError) as error:
            self.get_logger().warning(f"loop.realtime_priority {priority}: SCHED_FIFO not permitted ({error}); "
                                      "running with normal scheduling (grant rtprio, e.g. the 'realtime' group)")
            return
        self.get_logger().info(f"integration thread runs with SCHED_FIFO priority {priority}")

    def loop_iteration(self, ready: list | None = None) -> None:
        """One tick: take the messages that arrived (on the ``ready`` polled subscriptions, default all), integrate
        up to the clock, publish the wrench of every step."""
        for subscription in self._polled if ready is None else ready:
            drain(subscription)
        now = self.now_seconds()
        with self._lock:
            if not self.active:
                return
            started = self.sim.started
            failed, skipped = self.sim.statistics.failed_steps, self.sim.statistics.skipped_time
            records = self.sim.advance(now, self.use_sim_time, self.ahead_to_pose) if started else []
            failed, skipped = self.sim.statistics.failed_steps - failed, self.sim.statistics.skipped_time - skipped
        if skipped:
            self.warn_throttled("skipped", f"the integration lagged more than loop.max_catch_up: {skipped:.3f} s of "
                                           "simulated time skipped (diagnostics: skipped_time_s)")
        if failed:
            self.warn_throttled("failed", f"{failed} step(s) failed even after sub-stepping (point loads: "
                                          f"{len(self.sim.point_loads)}): needle reset straight at the base pose")
        if started and not self.sim.started:
            self.get_logger().warning(f"clock jumped back to {now:.3f} s: waiting for a new first pose")
        if self.use_sim_time:  # simulated time has no deadline: several steps per tick are its catch-up
            self.catch_up_steps += max(len(records) - 1, 0)
        else:  # a step integrated more than a period after its end time (not one integrated ahead to a pose)
            self.deadline_misses += sum(1 for record in records if record.t < now - self.sim.dt)
        # the wrench of each step on the holder, base frame, stamped with the step's end time (as CDR bytes)
        for data in cdr.wrench_stamped_many(self.p["frames.base"], step_wrenches(records)):
            self.wrench_pub.publish(data)
        if self.haptic_pub is not None:
            self.publish_haptics(records, now)

    # -- outputs ---------------------------------------------------------------------------------------------
    def publish_haptics(self, records, now: float) -> None:
        """The haptic wrench of each step (frame, watchdog gain, limits); none stepped while the watchdog holds the
        output (e.g. a paused /clock, no first pose yet): one zero, so that zero keeps coming at the step rate."""
        with self._haptic_lock:
            shaper = self.haptics
            if not self._haptic_live or shaper is None:
                return
            clipped = shaper.clipped_forces + shaper.clipped_torques
            wall = time.monotonic()
            if records:
                wrenches = list(shaper.shape(shaper.frame_wrenches(records), wall))
            elif shaper.silent(wall):
                wrenches = [(now, ZERO, ZERO)]
            else:
                return
            for data in cdr.wrench_stamped_many(self.haptic_frame, wrenches):
                self.haptic_pub.publish(data)
        if shaper.clipped_forces + shaper.clipped_torques > clipped:
            self.warn_throttled("saturated", f"haptic wrench saturated at haptics.max_force "
                                             f"{self.p['haptics.max_force']:g} N / max_torque "
                                             f"{self.p['haptics.max_torque']:g} N m (clipped so far: "
                                             f"{shaper.clipped_forces} forces, {shaper.clipped_torques} torques)")

    def due(self, key: str, now: float, rate: float) -> bool:
        """True once per 1/rate of clock time (also after the clock jumped backwards, e.g. a looping bag)."""
        next_time = self._next_output[key]
        if next_time - 2.0 / rate <= now < next_time:
            return False
        self._next_output[key] = now + 1.0 / rate
        return True

    def publish_shape_on_grid(self, record) -> None:
        """Integration thread, lock held: publish the shape of a step that reached the next shape time."""
        rate = self.p["rates.shape_hz"]
        if record.t + 1e-9 < self._next_output["shape"] and record.t > self._next_output["shape"] - 2.0 / rate:
            return
        self._next_output["shape"] = (np.floor(record.t * rate + 1e-6) + 1.0) / rate
        if self.shape_subscribed():
            self.publish_shape(self.snapshot(*self.take_state()))

    def shape_subscribed(self) -> bool:
        """Whether anything subscribes to the shape outputs (shape, state, TF): outputs nobody takes are not
        computed (with the shape and visualization outputs on, the latency p99 was 0.1-0.6 ms higher)."""
        return (self.shape_pub.get_subscription_count() > 0 or self.state_pub.get_subscription_count() > 0
                or self.tf.has_subscribers())

    def take_state(self) -> tuple:
        """(model, a copy of the state, tissue readout): all the outputs need, taken with the lock held."""
        state = self.sim.state
        return (self.sim.model, State(state.q.copy(), state.qd.copy(), state.qdd, state.t, base=self.sim.base),
                self.sim.tissue_readout())

    def snapshot(self, model, state: State, readout) -> dict:
        """Shape output and energies of a state copy (computed outside the lock)."""
        orientation = None if state.base is None else state.base.orientation
        return {"shape": model_shape(model, state.q, state.t, self.p["output.shape_samples"], orientation),
                "base": state.base, "energies": (kinetic_energy(model, state.qd), elastic_energy(model, state.q)),
                "readout": readout}

    def publish_shape(self, snap: dict) -> None:
        shape, frame = snap["shape"], self.p["frames.world"]
        stamp = time_msg(shape.t)
        self.shape_pub.publish(model_shape_cdr(shape, frame))
        readout = snap["readout"]
        tissue = (np.zeros(6) if readout is None else
                  np.array([readout.insertion_depth, readout.inserted_length, *readout.tip_force, readout.axial_force]))
        self.state_pub.publish(cdr.needle_state(stamp.sec, stamp.nanosec, frame, *tissue, *snap["energies"]))
        base = snap["base"]
        if base is not None:
            world, base_frame, tip = self.p["frames.world"], self.p["frames.base"], self.p["frames.tip"]
            self.tf.send([transform_stamped(stamp, world, base_frame, base.position, base.orientation),
                          transform_stamped(stamp, base_frame, tip, *tip_in_base(base, shape.tip_position,
                                                                                  shape.tip_orientation))])

    def publish_periodic_outputs(self, now: float) -> None:
        shape_due = (not self.use_sim_time and self.due("shape", now, self.p["rates.shape_hz"])
                     and self.shape_subscribed())
        visualization_due = (self.due("visualization", now, self.p["rates.visualization_hz"])
                             and any(publisher.get_subscription_count() > 0
                                     for publisher in (self.path_pub, self.pose_array_pub, self.marker_pub)))
        if not (shape_due or visualization_due):
            return
        with self._lock:
            if not self.sim.started:
                return
            taken = self.take_state()
        snap = self.snapshot(*taken)
        if shape_due:
            self.publish_shape(snap)
        if visualization_due:
            stamp, frame, line = time_msg(snap["shape"].t), self.p["frames.world"], snap["shape"].line
            orientations = quaternions_from_x_axes(line.tangents)
            path, marker = path_and_tube(stamp.sec, stamp.nanosec, frame, "needle", line.points, line.tangents,
                                         orientations, self.props.radius, COLORS["model"])
            self.path_pub.publish(path)
            self.marker_pub.publish(marker)
            self.pose_array_pub.publish(cdr.pose_array(stamp.sec, stamp.nanosec, frame, line.points, orientations))

    def publish_diagnostics_if_due(self, now: float) -> None:
        """Counters of the loop and inputs, and a level with a message that clears when its cause does
        (:mod:`needle_sim_ros.nodes.diagnostics`)."""
        if not self.due("diagnostics", now, self.p["rates.diagnostics_hz"]):
            return
        with self._lock:
            sim = self.sim
            values = {"lifecycle": "active" if self.active else ("inactive" if sim is not None else "unconfigured"),
                      "deadline_misses": self.deadline_misses, "catch_up_steps": self.catch_up_steps,
                      **{f"poses_{v.name.lower()}": n for v, n in self.counters.items()},
                      **{f"poses_{k}" if k in ("wrong_frame", "stamp_replaced") else k: n
                         for k, n in self.counters_other.items()}}
            if sim is not None:
                stats = sim.statistics
                values.update({
                    "steps": stats.steps, **stats.take_step_time_ms(empty=0.0),
                    "max_newton_iterations": stats.max_newton_iterations, "failed_steps": stats.failed_steps,
                    "poses_late_for_their_step": stats.late_poses,
                    "started_at_s": f"{self.started_at:.6f}",  # an epoch time in full, not .6g
                    "activated_at_s": f"{self.activated_at:.6f}",
                    "start_received_at_s": f"{self.start_received_at:.6f}", "skipped_time_s": stats.skipped_time,
                    "pose_age_s": sim.pose_age(self.now_seconds()), "point_loads": len(sim.point_loads)})
                stats.max_newton_iterations = 0
            started = sim is not None and sim.started
        rejected = {"rejected_poses": rejected_poses(self.counters) + self.counters_other["wrong_frame"],
                    "rejected_twists": self.counters_other["twist_rejected"],
                    "rejected_tip_loads": self.counters_other["tip_load_rejected"]}
        health = self.health.assess({**values, **rejected}, started, values.get("pose_age_s", float("inf")),
                                    self.p["pose_input.timeout"], active=self.active)
        status = DiagnosticStatus(level=bytes([health.level]),
                                  name=f"{self.get_fully_qualified_name()}: integration",
                                  message=health.message, hardware_id="needle_sim", values=key_values(values))
        statuses = [status] if self.haptic_pub is None else [status, self.haptic_status()]
        self.diagnostics_pub.publish(DiagnosticArray(header=Header(stamp=self.get_clock().now().to_msg()),
                                                     status=statuses))

    def haptic_status(self) -> DiagnosticStatus:
        """``<node>: haptics``: ERROR while the watchdog holds the output at zero after poses came, WARN before the
        first pose and when wrenches were clipped since the previous report, OK otherwise."""
        shaper, values = self.haptics, {"frame": self.haptic_frame, "max_force_n": self.p["haptics.max_force"],
                                        "max_torque_nm": self.p["haptics.max_torque"]}
        if not self.active or shaper is None:
            level, message = OK, "inactive (lifecycle): output zero"
        else:
            wall = time.monotonic()
            silence = wall - shaper.last_pose
            clipped = shaper.clipped_forces + shaper.clipped_torques
            newly_clipped, self._clipped_reported = clipped - self._clipped_reported, clipped
            values.update(clipped_forces=shaper.clipped_forces, clipped_torques=shaper.clipped_torques,
                          watchdog_trips=shaper.watchdog_trips,
                          pose_silence_s=silence if shaper.poses_seen else float("inf"))
            if not shaper.poses_seen:
                level, message = WARN, "waiting for the first base pose: output zero"
            elif silence > shaper.pose_timeout:
                level, message = ERROR, f"watchdog: no base pose for {silence:.3f} s: output zero"
            elif newly_clipped > 0:
                level, message = WARN, f"saturated: {newly_clipped} wrench component(s) clipped since the last report"
            else:
                level, message = OK, "rendering"
        return DiagnosticStatus(level=bytes([level]), name=f"{self.get_fully_qualified_name()}: haptics",
                                message=message, hardware_id="needle_sim", values=key_values(values))


def tip_in_base(base: BaseMotion, tip_position: np.ndarray, tip_orientation: np.ndarray) -> tuple:
    """Tip pose relative to the base frame: p = R_b^T (p_tip - p_b), q = q_b^* q_tip."""
    orientation = np.asarray(base.orientation, dtype=float)
    position = quaternion_matrix(orientation).T @ (np.asarray(tip_position, dtype=float) - base.position)
    return position, multiply(conjugate(orientation), np.asarray(tip_orientation, dtype=float))


def key_values(values: dict) -> list[KeyValue]:
    return [KeyValue(key=k, value=f"{v:.6g}" if isinstance(v, float) else str(v)) for k, v in values.items()]


def main(args=None) -> int:
    return run_node(NeedleSimulatorNode, "needle_simulator", args, SIMULATOR_PARAMETERS)


if __name__ == "__main__":
    sys.exit(main())
