"""Every custom needle_interfaces message with all fields set to distinct, non-default values.

Used on both sides of the cross-process round-trip test, so both agree on what was sent.
"""
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from needle_interfaces.msg import NeedleShape, NeedleState, ShapeError
from std_msgs.msg import Header


def _header(seq: int) -> Header:
    return Header(stamp=Time(sec=1700000000 + seq, nanosec=123456789), frame_id=f"frame_{seq}")


def needle_shape() -> NeedleShape:
    n = 7
    return NeedleShape(
        header=_header(1),
        source=NeedleShape.SOURCE_STEREO,
        points=[Point(x=0.01 * i, y=-0.002 * i, z=1e-4 * i * i) for i in range(n)],
        tangents=[Vector3(x=0.99, y=0.1 * i / n, z=-0.05) for i in range(n)],
        arc_length=[0.0101 * i for i in range(n)],
        uncertainty=[1e-4 * (i + 1) for i in range(n)],
        tip_pose=Pose(position=Point(x=0.27, y=-0.01, z=0.03), orientation=Quaternion(x=0.1, y=0.2, z=0.3, w=0.927)),
        length=0.2701,
    )


def shape_error() -> ShapeError:
    return ShapeError(
        header=_header(2),
        model_stamp=Time(sec=11, nanosec=22),
        measurement_stamp=Time(sec=33, nanosec=44),
        rmse=4.3e-4,
        max_error=9.9e-4,
        tip_error=7.5e-4,
        matched_samples=5,
        errors=[1e-4, 2e-4, 3e-4, 4e-4, 9.9e-4],
        arc_length=[0.0, 0.05, 0.1, 0.2, 0.27],
    )


def needle_state() -> NeedleState:
    return NeedleState(
        header=_header(3),
        insertion_depth=0.09,
        inserted_length=0.0905,
        tip_force=Vector3(x=-0.5, y=0.25, z=0.125),
        axial_force=1.75,
        kinetic_energy=1e-6,
        elastic_energy=2.5e-3,
    )


SAMPLES = {"shape": needle_shape, "error": shape_error, "state": needle_state}
