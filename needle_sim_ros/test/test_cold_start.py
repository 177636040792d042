"""Cold start (issue #12): after `compile_kernels` the node's pose path compiles nothing more."""
import json
import sys
from pathlib import Path

import pytest

from geometry_msgs.msg import PoseStamped
from numba.core.dispatcher import Dispatcher
from rclpy.serialization import serialize_message

from needle_common.cdr import pose_stamped
from needle_sim_ros.messages.geometry import compile_geometry_kernels, tube_triangles
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
from needle_sim_ros.simulation import compile_kernels, simulation_from_parameters, step_wrenches

DEFAULTS = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}


def compiled_specializations() -> dict[str, int]:
    """Number of compiled signatures of every numba kernel of the package loaded so far (those with any)."""
    return {f"{module_name}.{name}": len(kernel.signatures)
            for module_name, module in list(sys.modules.items()) if module_name.startswith("needle_sim_ros")
            for name, kernel in vars(module).items() if isinstance(kernel, Dispatcher) and kernel.signatures}


def test_poses_decoded_like_the_node_does_need_no_kernel_beyond_compile_kernels():
    compile_kernels(DEFAULTS)
    compiled = compiled_specializations()
    sim = simulation_from_parameters(DEFAULTS)
    message = PoseStamped()
    message.header.frame_id = "world"
    wrenches = []
    for k in range(20):
        t = 1.0 + 1e-3 * k
        message.header.stamp.sec, message.header.stamp.nanosec = 1, k * 1_000_000
        message.pose.position.x, message.pose.position.z, message.pose.orientation.w = 0.4 + 1e-5 * k, 0.3, 1.0
        pose = pose_stamped(serialize_message(message))  # the node's decoding: read-only views of the buffer
        sim.offer_pose(pose.stamp_ns * 1e-9, pose.position, pose.orientation)
        wrenches += step_wrenches(sim.advance(t + 1e-3, deterministic=False))
    sim.data.grid_origin += 0.4e-3  # as lock_phase shifts the grid to the poses: a step of 1.4 dt on its own
    wrenches += step_wrenches(sim.advance(1.023, deterministic=False))
    assert len(wrenches) >= 17
    assert compiled_specializations() == compiled


def test_the_outputs_need_no_kernel_beyond_compile_kernels():
    """The node's outputs (shape, energies, the RViz tube) after compile_kernels and compile_geometry_kernels, as
    its on_configure calls them: nothing compiles in the output thread (that would hold the GIL for a second)."""
    compile_kernels(DEFAULTS)
    compile_geometry_kernels()
    compiled = compiled_specializations()
    sim = simulation_from_parameters(DEFAULTS)
    sim.offer_pose(1.0, [0.4, 0.0, 0.3], [0.0, 0.0, 0.0, 1.0])
    sim.advance(1.002, deterministic=False)
    shape = sim.shape(DEFAULTS["output.shape_samples"])
    sim.energies()
    tube = tube_triangles(shape.line.points, shape.line.tangents, sim.model.props.radius)
    assert tube.shape == (6 * 8 * (DEFAULTS["output.shape_samples"] - 1), 3)
    assert compiled_specializations() == compiled


def test_an_insertion_needs_no_kernel_beyond_compile_kernels_with_the_tissue_on():
    """With the tissue enabled, compile_kernels also compiles the tissue models' kernels: a needle pushed into
    the tissue by the node's pose path compiles nothing more."""
    p = {**DEFAULTS, "tissue.enable": True}
    compile_kernels(p)
    compiled = compiled_specializations()
    sim = simulation_from_parameters(p)
    tip_start = p["tissue.entry_point"][0] - 1e-3              # 1 mm before the surface, 6 mm/s into the tissue
    for k in range(400):
        t = 1.0 + 1e-3 * k
        sim.offer_pose(t, [tip_start - sim.model.props.length + 6e-6 * k, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])
        sim.advance(t + 1e-3, deterministic=False)
    readout = sim.tissue_readout()
    assert readout.insertion_depth > 5e-4 and sim.statistics.failed_steps == 0
    assert compiled_specializations() == compiled


# After the install hook's snippet, in its process: the kernel signatures that ``compile_kernels`` -- what the node's
# on_configure runs -- needs for each tissue setting a user can switch to (every composition of its parts) beyond
# those the hook compiled (or loaded from the cache).
TISSUE_SWITCHES = """
import itertools, json, sys
from numba.core.dispatcher import Dispatcher
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
from needle_sim_ros.simulation import compile_kernels
from needle_sim_ros.tissue.factory import AXIAL_MODELS

def signatures():
    return {(name, kernel_name): {str(signature) for signature in kernel.signatures}
            for name, module in list(sys.modules.items()) for kernel_name, kernel in list(vars(module).items())
            if isinstance(kernel, Dispatcher)}

hooked = signatures()
defaults = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}
beyond = {}
for law, lateral, bevel, profile in itertools.product(AXIAL_MODELS, (True, False), (True, False), (True, False)):
    compile_kernels({**defaults, "tissue.enable": True, "tissue.shaft.axial_model": law,
                     "tissue.shaft.lateral_support": lateral, "tissue.bevel_tip.enable": bevel,
                     "tissue.insertion_profile.enable": profile})
    setting = f"{law}, lateral {lateral}, bevel {bevel}, profile {profile}"
    for key, found in signatures().items():
        for signature in found - hooked.get(key, set()):
            beyond.setdefault(".".join(key), {})[signature] = setting
            hooked.setdefault(key, set()).add(signature)
print(json.dumps(beyond))
"""


@pytest.mark.slow
def test_the_install_hook_covers_every_tissue_setting_a_node_can_switch_to(run_install_hook):
    """setup.py's install step (what colcon build runs) compiles the kernels with a snippet of its own: it runs
    against the installed package (a stale import there would only print a warning at build time and leave every
    fresh install compiling at first start), and whatever tissue laws a user switches on (axial law x lateral
    support x bevel tip x seed 002 profile), the node's configure needs no kernel it did not compile (which would
    take up to a minute with the node unresponsive). Checked on what the hook's own process compiled or loaded, so
    that no other test's compilation in the shared cache can stand in for it (before: a cache filled from empty,
    ~6 min of every CI run); the build fills its cache from empty with the same snippet."""
    result = run_install_hook(Path(__file__).resolve().parents[1] / "setup.py", 1200, TISSUE_SWITCHES)
    assert result.returncode == 0, result.stderr
    assert "compiled the simulator's numba kernels" in result.stdout
    assert json.loads(result.stdout.splitlines()[-1]) == {}
