"""Parameters of the `needle_simulator` node (declared with descriptors, validated at start)."""
from __future__ import annotations

from needle_sim_ros.model.config import DEFAULTS as MODEL_DEFAULTS
from needle_sim_ros.model.integrators import METHODS
from needle_common.parameters import QOS_CHOICES, TOPIC_CHECK, ParamSpec
from needle_common.transforms import unit_quaternion
from needle_sim_ros.tissue import TISSUE_PARAMETERS


def _model(name: str, *arguments, **options) -> ParamSpec:
    """A parameter of the needle model with the model's default (:data:`needle_sim_ros.model.config.DEFAULTS`)."""
    return ParamSpec(name, MODEL_DEFAULTS[name], *arguments, **options)


NAMED = (bool, "must not be empty")  # a frame

SIMULATOR_PARAMETERS = [
    # Needle (seed 000, Sec. III: stainless steel, r = 0.635 mm, L = 0.27 m).
    _model("needle.length", "Needle length L [m] from the clamp point A to the tip.", 1e-3, 10.0),
    _model("needle.radius", "Outer radius of the circular cross-section [m].", 1e-6, 0.05),
    _model("needle.inner_radius", "Inner radius of a hollow needle [m] (0 = solid; must be < needle.radius).", 0.0,
           0.05),
    _model("needle.youngs_modulus", "Young's modulus E [Pa].", 1e6, 1e12),
    _model("needle.density", "Density rho [kg/m^3].", 1.0, 1e5),
    _model("needle.elements", "Number of ANCF cable elements.", 1, 200),
    _model("needle.element_lengths",
           "Element lengths [m] from the clamp point A to the tip, for a non-uniform mesh (e.g. finer where the tissue "
           "acts); they must sum to needle.length and then set the number of elements. [0.0]: needle.elements "
           "elements of equal length (with fixtures.clamp_interval: nodes at the clamp).", 0.0, 10.0,
           check=(lambda v: list(v) in ([], [0.0]) or all(length > 0 for length in v),
                  "must be [0.0] (uniform) or lengths > 0 [m] summing to needle.length")),
    _model("needle.gravity", "Gravitational acceleration in the world frame [m/s^2].", -100.0, 100.0, length=3),
    _model("needle.axial_gauss_points", "Gauss points per element for the axial strain integral (eq. 12); 2 = "
           "reduced, locking-free (default), 5 = the paper's.", 1, 10),
    _model("needle.bending_gauss_points", "Gauss points per element for the bending integral (eq. 13).", 1, 10),
    _model("needle.start_in_equilibrium", "Start (and restart) the needle at rest in static equilibrium under "
           "gravity and the loads; false: straight (it then drops and swings)."),
    # alpha M damps absolute velocities (a drag alpha m v on a rigidly moving needle, felt at the holder), so it is
    # zero by default; beta K_0 acts on strain rates in a rotation-safe form (needle_sim_ros.model.damping).
    _model("damping.rayleigh_alpha", "Mass-proportional Rayleigh damping alpha [1/s] (C = alpha M + beta K).", 0.0,
           1e4, dynamic=True),
    _model("damping.rayleigh_beta", "Stiffness-proportional Rayleigh damping beta [s] (C = alpha M + beta K).", 0.0,
           1.0, dynamic=True),
    _model("integrator.method", "Implicit integrator.", choices=METHODS),
    _model("integrator.rho_inf", "Spectral radius at infinite frequency (numerical damping; 1 = none).", 0.0, 1.0),
    _model("integrator.dt", "Integration step [s]; the real-time loop runs at 1/dt.", 1e-5, 0.1),
    _model("integrator.newton_tolerance", "Newton convergence bound on the last correction (|dr| / L and |dr_x|).",
           1e-14, 1e-2),
    _model("integrator.max_substep_halvings", "A failed step is retried as 2, 4, ... 2^n sub-steps before it is "
           "reported.", 0, 12),
    _model("integrator.max_newton_iterations", "Newton iterations per step before sub-stepping.", 1, 100),
    _model("fixtures.clamp_interval",
           "Arc-length interval [s_start, s_end] [m] clamped to the world where it lies when the needle starts (seed "
           "000 Fig. 8: [0.6 L, L]). With needle.element_lengths the ends must be mesh nodes; without, the mesh puts "
           "nodes there (one element clamped, the free span's nodes clustered at the holds). [] or [0.0]: none.",
           0.0, 10.0,
           check=(lambda v: len(v) in (0, 1, 2) and (len(v) < 2 or v[0] < v[1]) and (len(v) != 1 or v[0] == 0.0),
                  "must be [] / [0.0] (none) or [s_start, s_end] with s_start < s_end")),
    # Frames (REP 103/105).
    ParamSpec("frames.world", "world", "Fixed frame of base poses, wrench (world copy) and shapes.", check=NAMED),
    ParamSpec("frames.base", "needle_base", "Frame of the needle base at the clamp point A, x along the needle.",
              check=NAMED),
    ParamSpec("frames.tip", "needle_tip", "Frame of the needle tip on TF (child of frames.base), x along the tip "
              "tangent.", check=NAMED),
    ParamSpec("flange_offset.position", [0.0, 0.0, 0.0], "Clamp point A in the flange frame of the incoming pose [m].",
              -10.0, 10.0, length=3),
    ParamSpec("flange_offset.orientation", [0.0, 0.0, 0.0, 1.0],
              "Rotation flange -> needle base frame, quaternion (x, y, z, w).", -1.0, 1.0, length=4,
              check=(lambda q: unit_quaternion(q) is not None, "must be a unit quaternion")),
    # Topics (relative, so they can be remapped and namespaced).
    ParamSpec("topics.base_pose", "base_pose", "Input geometry_msgs/PoseStamped of the needle holder (flange).",
              check=TOPIC_CHECK),
    ParamSpec("topics.base_twist", "base_twist",
              "Optional input geometry_msgs/TwistStamped (world frame) for velocity feed-forward.", check=TOPIC_CHECK),
    ParamSpec("topics.tip_load", "tip_load",
              "Optional input geometry_msgs/WrenchStamped: force on the needle tip (world or base frame), e.g. a "
              "recorded tip mass.", check=TOPIC_CHECK),
    ParamSpec("topics.wrench", "wrench",
              "Output geometry_msgs/WrenchStamped: wrench of the needle on its holder, base frame.", check=TOPIC_CHECK),
    ParamSpec("topics.haptic", "haptic/wrench",
              "Output geometry_msgs/WrenchStamped with haptics.enable: the force the operator should feel (the "
              "needle's wrench on its holder, limited), frame haptics.frame.", check=TOPIC_CHECK),
    ParamSpec("topics.shape", "needle/shape", "Output needle_interfaces/NeedleShape (world frame).", check=TOPIC_CHECK),
    ParamSpec("topics.path", "needle/path", "Output nav_msgs/Path of the centerline.", check=TOPIC_CHECK),
    ParamSpec("topics.marker", "needle/marker", "Output visualization_msgs/Marker tube.", check=TOPIC_CHECK),
    ParamSpec("topics.pose_array", "needle/state/current_shape",
              "Output geometry_msgs/PoseArray (SmartNeedle convention, metres).", check=TOPIC_CHECK),
    ParamSpec("topics.state", "needle/state", "Output needle_interfaces/NeedleState (depth, tip force, energies).",
              check=TOPIC_CHECK),
    ParamSpec("qos.wrench", "sensor_data", "QoS of the wrench output.", choices=QOS_CHOICES),
    ParamSpec("qos.haptic", "reliable",
              "QoS of the haptic output (reliable: what a CRTK driver's servo_cf subscription asks for; the zero "
              "sent on stop is then acknowledged).", choices=QOS_CHOICES),
    ParamSpec("qos.base_pose", "sensor_data", "QoS of the pose input (sensor_data also matches reliable publishers).",
              choices=QOS_CHOICES),
    ParamSpec("rates.shape_hz", 100.0, "Rate of the NeedleShape and NeedleState outputs [Hz].", 0.1, 1000.0,
              dynamic=True),
    ParamSpec("rates.visualization_hz", 10.0, "Rate of the RViz outputs: path, pose array and marker tube [Hz].", 0.01,
              1000.0, dynamic=True),
    ParamSpec("rates.diagnostics_hz", 1.0, "Rate of diagnostic_msgs/DiagnosticArray on /diagnostics [Hz].", 0.1, 100.0,
              dynamic=True),
    ParamSpec("output.shape_samples", 50, "Centerline samples per shape message (at most 1000: more would slow the "
              "wrench loop).", 2, 1000, dynamic=True),
    # Pose input handling (see needle_sim_ros.base_trajectory).
    ParamSpec("pose_input.window", 0.02, "Least-squares window for pose, velocity and acceleration estimates [s].",
              1e-3, 1.0),
    ParamSpec("pose_input.max_extrapolation", 0.01,
              "Longest extrapolation beyond the newest pose before it is held [s].", 0.0, 1.0),
    ParamSpec("pose_input.timeout", 0.1, "Pose age after which the node reports the input as lost (holding) [s].", 1e-3,
              60.0),
    ParamSpec("pose_input.max_position_jump", 0.02, "Largest accepted position change between consecutive poses [m].",
              1e-6, 10.0),
    ParamSpec("pose_input.max_orientation_jump", 0.2,
              "Largest accepted orientation change between consecutive poses [rad].", 1e-6, 3.1416),
    ParamSpec("pose_input.reanchor_after", 10,
              "Consecutive consistent jumped poses after which the needle is reset there.", 1, 10000),
    ParamSpec("pose_input.max_stamp_offset", 0.5,
              "Wall-clock mode: stamps further than this from now are replaced by the receive time [s].", 1e-3, 3600.0),
    ParamSpec("pose_input.twist_timeout", 0.05, "A twist older than this is ignored [s].", 1e-3, 10.0),
    ParamSpec("pose_input.max_position", 100.0, "Poses with a coordinate beyond +-this are rejected (working "
              "volume) [m].", 1e-3, 1e4),
    ParamSpec("pose_input.max_linear_speed", 5.0, "Twists with a faster linear velocity are ignored [m/s].",
              1e-3, 100.0),
    ParamSpec("pose_input.max_angular_speed", 20.0, "Twists with a faster angular velocity are ignored [rad/s].",
              1e-3, 1000.0),
    ParamSpec("pose_input.resume_tolerance", 1e-3, "A pose arriving after a gap longer than pose_input.timeout "
              "farther than this from the held pose restarts the needle at rest there (with a warning) [m].",
              0.0, 10.0),
    # External loads (e.g. the tip mass of seed 000 Fig. 7).
    ParamSpec("loads.tip_force", [0.0, 0.0, 0.0], "Constant force on the tip, world frame [N] (tip mass m: "
              "[0, 0, -9.81 m]); all point loads together at most 20 E I / L^2 (6.8 N for the default needle).",
              -100.0, 100.0, length=3, dynamic=True),
    # Haptic output for hardware in the loop (needle_sim_ros.nodes.haptics; README "Haptics / HIL").
    ParamSpec("haptics.enable", False,
              "Publish the force the operator should feel on topics.haptic, one per step, limited, with a pose "
              "watchdog and a zero on every stop."),
    ParamSpec("haptics.frame", "base",
              "Frame of the haptic wrench (about the clamp point A): 'base' = the arm's base frame, the frame the "
              "poses come in (frames.world), as a CRTK servo_cf takes it; 'tool' = the needle holder frame "
              "(frames.base), for a body-frame servo_cf.", choices=("base", "tool")),
    ParamSpec("haptics.max_force", 3.0, "Largest haptic force [N]; a larger force is scaled down to it (direction "
              "kept) and counted.", 0.0, 100.0, dynamic=True),
    ParamSpec("haptics.max_torque", 0.3, "Largest haptic torque [N m]; a larger torque is scaled down to it "
              "(direction kept) and counted.", 0.0, 10.0, dynamic=True),
    ParamSpec("haptics.pose_timeout", 0.02, "Watchdog: no base pose for this long (wall-clock arrival time) -> the "
              "haptic output is zero and diagnostics ERROR [s].", 1e-3, 1.0),
    ParamSpec("haptics.resume_ramp", 0.5, "When poses return after the watchdog tripped, the haptic output ramps "
              "linearly from zero to the full wrench over this time [s] (0: at once).", 0.0, 10.0),
    # Lifecycle (needle_sim_ros.nodes.lifecycle).
    ParamSpec("autostart", True,
              "Configure and activate at start (a plain node); false: wait for lifecycle transitions (managed, e.g. "
              "by a robot bringup)."),
    # Real-time loop.
    ParamSpec("loop.max_catch_up", 0.05, "Largest lag [s] the loop integrates to catch up; beyond it time is skipped.",
              1e-3, 10.0),
    ParamSpec("loop.ahead_to_pose", True,
              "Wall-clock time: on a base pose, integrate at once the step that ends at or after its stamp (at most "
              "one step past the clock; the base motion extrapolated by less than dt), so its wrench is published "
              "within the step's computation instead of at the step's end time (pose->wrench latency); the step "
              "grid follows the poses' phase (steps end half a step after them) and a step no pose reached is "
              "integrated a quarter period after its end time; false: a step is integrated once its end time has "
              "passed."),
    ParamSpec("loop.busy_wait", 0.0002, "Spin the last part of each period instead of sleeping, for tick accuracy [s].",
              0.0, 0.01),
    ParamSpec("loop.realtime_priority", 50,
              "SCHED_FIFO priority of the integration thread in wall-clock time (1-99; 0 = normal scheduling). Needs "
              "the rtprio limit (e.g. the 'realtime' group); without it the node warns and runs with normal "
              "scheduling.", 0, 99),
    # Needle-tissue interaction (needle_sim_ros.tissue; config/tissue.yaml): checked together when enabled.
    *TISSUE_PARAMETERS,
]

# Structural parameters that the node's construction already used (its topics, QoS, frames, whether it has a haptic
# output): fixed for the node's life. The other structural (not dynamic) ones can be set while the node is
# unconfigured and take effect at configure (needle_common.ros.ros_parameters).
FIXED_AT_CONSTRUCTION = frozenset(spec.name for spec in SIMULATOR_PARAMETERS if spec.name.split(".")[0] in
                                  ("topics", "qos", "frames")) | {"haptics.enable", "autostart"}
