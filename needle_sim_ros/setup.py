import os
import subprocess
import sys
from glob import glob

from setuptools import find_packages, setup
from setuptools.command.install import install

package_name = "needle_sim_ros"

# Compiles the simulator's numba kernels for its default configuration, and those of its tissue models (off by
# default) in every composition a user switches to (bevel tip on/off x seed 002 tip on/off; the axial law, Karnopp
# or LuGre, is a value of the same kernels: both run once), into the kernel cache (NUMBA_CACHE_DIR if set, else
# __pycache__ next to the installed modules), so that the first start of a fresh install loads them.
COMPILE_KERNELS = """
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
import time
from needle_sim_ros.messages.geometry import compile_geometry_kernels
from needle_sim_ros.simulation import compile_kernels, compile_tissue_kernels
defaults = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}
start = time.perf_counter()
compile_kernels(defaults)
compile_geometry_kernels()
for bevel in (True, False):
    for law, profile in (("karnopp", False), ("lugre", True)):
        compile_tissue_kernels({**defaults, "tissue.bevel_tip.enable": bevel, "tissue.shaft.axial_model": law,
                                "tissue.insertion_profile.enable": profile})
seconds = time.perf_counter() - start
print(f"needle_sim_ros: compiled the simulator's numba kernels in {seconds:.0f} s")
"""


class InstallCompilingKernels(install):
    """``install`` (what colcon's ament_python build runs), then compile the numba kernels against the installed
    modules: numba's cache is keyed by the source file, so only the installed files' kernels serve at run time.
    ``NEEDLE_COMPILE_KERNELS=0`` skips it (the first start then compiles, ~1 min)."""

    def run(self) -> None:
        super().run()
        if os.environ.get("NEEDLE_COMPILE_KERNELS", "1") == "0":
            return
        # numba checks only a kernel's own file: a cached caller would keep the old code of a changed callee in
        # another module, so the installed package's kernels are all compiled anew
        kernel_caches = os.path.join(self.install_lib, package_name, "**", "__pycache__", "*.nb[ic]")
        for stale in glob(kernel_caches, recursive=True):
            os.remove(stale)
        path = os.pathsep.join(filter(None, (self.install_lib, os.environ.get("PYTHONPATH"))))
        # cwd: the installed tree, not this source tree (which would shadow it on sys.path)
        result = subprocess.run([sys.executable, "-c", COMPILE_KERNELS], cwd=self.install_lib,
                                env=dict(os.environ, PYTHONPATH=path))
        if result.returncode != 0:
            print("needle_sim_ros: warning: compiling the numba kernels failed; the simulator's first start will "
                  "compile them", file=sys.stderr)


setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        # The package's own config (the repository root's config/ links here); nothing from outside the package.
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/config/experiments", glob("config/experiments/*.yaml")),
        ("share/" + package_name + "/config/foxglove", glob("config/foxglove/*.json")),
        ("share/" + package_name + "/config/batch", glob("config/batch/*.yaml")),
        ("share/" + package_name + "/launch", glob("launch/*.py")),
        ("share/" + package_name + "/rviz", glob("rviz/*.rviz")),
    ],
    install_requires=["setuptools"],
    extras_require={"test": ["pytest"]},
    zip_safe=True,
    cmdclass={"install": InstallCompilingKernels},
    maintainer="needle_sim developers",
    maintainer_email="dev@needle-sim.invalid",
    description="Real-time 3D dynamic ANCF needle simulation for ROS 2 Jazzy.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "needle_simulator = needle_sim_ros.nodes.simulator_node:main",
            "needle_scenario = needle_sim_ros.scenarios.cli:main",
            "needle_compare = needle_sim_ros.nodes.compare_node:main",
            "needle_replay = needle_sim_ros.nodes.replay_node:main",
            "needle_mcap_recover = needle_sim_ros.recording.recovery:main",
            "needle_bringup = needle_sim_ros.nodes.bringup:main",
            "needle_offline = needle_sim_ros.offline.cli:main",
            "needle_make_bags = needle_sim_ros.experiments.make_bags:main",
            "needle_batch = needle_sim_ros.batch.cli:main",
        ],
    },
)
