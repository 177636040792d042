"""Parameters of the `needle_compare` node and of the offline comparison stage (declared with descriptors by the
node, validated at start by both)."""
from __future__ import annotations

from needle_common.parameters import QOS_CHOICES, ParamSpec
from needle_common.transforms import nonzero_quaternion

from needle_sim_ros.recording.mcap_writer import COMPRESSION

#: The compared centerlines as nav_msgs/Path and visualization_msgs/Marker (model frame).
DISPLAY_TOPICS = ("compare/model/path", "compare/model/marker", "compare/measured/path", "compare/measured/marker")
#: The topics the node can record (relative to its namespace).
LOGGABLE_TOPICS = ("model/shape", "measured/shape", "measured/points", "shape_error", "base_pose", "wrench",
                   *DISPLAY_TOPICS)


COMPARE_PARAMETERS = [
    ParamSpec("tolerance", 0.005, "Largest stamp difference [s] between a measured and a model shape that are "
              "compared.", low=0.0, high=10.0),
    ParamSpec("extrinsic.translation", [0.0, 0.0, 0.0], "Camera origin in the model frame [m] (x, y, z): "
              "p_model = R p_camera + t.", length=3),
    ParamSpec("extrinsic.rotation", [0.0, 0.0, 0.0, 1.0], "Camera orientation R in the model frame as a "
              "quaternion (x, y, z, w); normalized here.", length=4,
              check=(nonzero_quaternion, "must be a finite, non-zero quaternion")),
    ParamSpec("model_frame", "", "Expected header.frame_id of model shapes; errors are expressed in it. "
              "Empty: accept any."),
    ParamSpec("measured_frame", "", "Expected header.frame_id of measurements (the camera frame). Empty: accept any."),
    ParamSpec("measured_input", "shape", "Measurement topic: 'shape' = measured/shape (NeedleShape, ordered base to "
              "tip), 'points' = measured/points (PointCloud2 with float32 x, y, z).", choices=("shape", "points")),
    ParamSpec("max_match_distance", 0.0, "Measured samples farther than this [m] from the model centerline are "
              "outliers and not matched; 0 matches all.", low=0.0, high=10.0),
    ParamSpec("model_buffer", 200, "Model shapes kept for pairing [count]; must cover the measurement latency "
              "times the model rate.", low=1, high=100000),
    ParamSpec("qos.inputs", "sensor_data", "QoS of the recorded base_pose and wrench subscriptions: sensor_data "
              "(best effort: matches the simulator's default best-effort wrench and reliable publishers) or "
              "reliable (every message of a reliable publisher, e.g. qos.wrench: reliable in a replay).",
              choices=QOS_CHOICES),
    ParamSpec("summary_path", "", "JSON file written at shutdown with mean/max RMSE and counts. Empty: none."),
    ParamSpec("display.rate", 10.0, "Largest rate [Hz of measurement time] of the compared centerlines as "
              "nav_msgs/Path and Marker tubes on compare/{model,measured}/{path,marker} (model frame); 0: none.",
              low=0.0, high=1000.0),
    ParamSpec("display.tube_radius", 0.000635, "Radius [m] of the Marker tubes (the needle's).", low=1e-6, high=0.1),
    ParamSpec("log.tf", True, "Also record /tf and /tf_static (needs tf2_msgs; without it the log has no TF)."),
    ParamSpec("log.path", "", "MCAP recording: a '.mcap' file, or a rosbag2 bag directory (any other path; may be "
              "split). Empty: no recording."),
    ParamSpec("log.topics", list(LOGGABLE_TOPICS), "Topics recorded (relative to the node namespace), a subset of "
              + ", ".join(LOGGABLE_TOPICS) + ".", check=(lambda v: set(v) <= set(LOGGABLE_TOPICS), "unknown topic")),
    ParamSpec("log.compression", "zstd", "Chunk compression of the recording.", choices=COMPRESSION),
    ParamSpec("log.chunk_size", 1 << 20, "Uncompressed chunk size [bytes] at which a chunk is written to disk.",
              low=1024, high=1 << 30),
    ParamSpec("log.chunk_interval", 1.0, "Longest time [s] a chunk stays in memory (data lost on a crash).",
              low=0.0, high=3600.0),
    ParamSpec("log.max_file_size", 0, "Split a bag directory into a new file past this size [bytes]; 0 = never.",
              low=0, high=1 << 50),
    ParamSpec("log.max_file_duration", 0.0, "Split a bag directory into a new file past this duration [s]; "
              "0 = never.", low=0.0, high=1e7),
    ParamSpec("log.overwrite", False, "Replace an existing recording at log.path instead of refusing to start."),
]
