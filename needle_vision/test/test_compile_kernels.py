"""The stereo measurement's kernels are compiled before the first real pair: at install and at the node's start."""
from pathlib import Path


def test_the_install_hook_compiles_the_measurement_kernels_against_the_installed_package(run_install_hook):
    """setup.py's install step (what colcon build runs) compiles them with a snippet of its own; on a fresh install
    without it the node's first pairs waited ~50 s for compilation and the main job compared 7 of 10."""
    result = run_install_hook(Path(__file__).resolve().parents[1] / "setup.py", 900)
    assert result.returncode == 0, result.stderr
    assert "compiled the measurement's numba kernels" in result.stdout


READ_ONLY_SNIPPET = """
import numba, numpy as np
from needle_vision import pipeline
from needle_vision.render import NEEDLE_RADIUS, default_rig, make_scene, render_background_pair, render_stereo_pair
from needle_vision.detection import centerline, curves
from needle_vision.matching import correspondence, curve_fit, reconstruction

def signatures():
    return {(module.__name__, name): len(kernel.signatures)
            for module in (centerline, curves, correspondence, reconstruction, curve_fit)
            for name, kernel in vars(module).items() if isinstance(kernel, numba.core.registry.CPUDispatcher)}

pipeline.compile_kernels()
before = signatures()
rig = default_rig()
scene = make_scene(rig, np.random.default_rng(5))
arc = np.linspace(0.0, 0.2, 201)
measuring = pipeline.StereoNeedlePipeline(rig, pipeline.StereoConfig(background_frames=1))
pairs = (render_background_pair(rig, np.random.default_rng(6), scene=scene),
         render_stereo_pair(rig, np.column_stack([arc, 0.1 * arc ** 2, -0.1 * arc]), NEEDLE_RADIUS,
                            np.random.default_rng(7), scene=scene))
for stamp, pair in enumerate(pairs):
    images = [np.asarray(image, np.uint8) for image in pair]
    for image in images:
        image.setflags(write=False)
    result = measuring.process(float(stamp), *images)
assert result.status is pipeline.FrameStatus.MEASURED, result.reason
print({key: (count, signatures()[key]) for key, count in before.items() if signatures()[key] != count})
"""


def test_compiled_kernels_cover_read_only_images():
    """A bag's images are read-only views of the file; after compile_kernels() measuring such a pair, ordered either
    way, compiles no kernel again (before, the first pair of a bag compiled the slice and end kernels for read-only
    arrays, and the first needle ordered against its triangulation step_lengths for reversed ones)."""
    import subprocess
    import sys

    result = subprocess.run([sys.executable, "-c", READ_ONLY_SNIPPET], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "{}"
