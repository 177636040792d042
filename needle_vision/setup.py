import os
import subprocess
import sys
from glob import glob

from setuptools import find_packages, setup
from setuptools.command.install import install

package_name = "needle_vision"

# Compiles the measurement's numba kernels into the kernel cache (NUMBA_CACHE_DIR if set, else __pycache__ next to
# the installed modules), so that the first pairs of a fresh install are not delayed (and dropped) by compilation.
COMPILE_KERNELS = """
from needle_vision.pipeline import compile_kernels
print(f"needle_vision: compiled the measurement's numba kernels in {compile_kernels():.0f} s")
"""


class InstallCompilingKernels(install):
    """``install`` (what colcon's ament_python build runs), then compile the numba kernels against the installed
    modules (numba's cache is keyed by the source file). ``NEEDLE_COMPILE_KERNELS=0`` skips it."""

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
        result = subprocess.run([sys.executable, "-c", COMPILE_KERNELS], cwd=self.install_lib,
                                env=dict(os.environ, PYTHONPATH=path))
        if result.returncode != 0:
            print("needle_vision: warning: compiling the numba kernels failed; the first pairs will compile them",
                  file=sys.stderr)


setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/config/stereo", glob("config/stereo/*.yaml")),
    ],
    install_requires=["setuptools"],
    extras_require={"test": ["pytest"]},
    zip_safe=True,
    cmdclass={"install": InstallCompilingKernels},
    maintainer="needle_sim developers",
    maintainer_email="dev@needle-sim.invalid",
    description="Stereo needle reconstruction for the needle_sim suite.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "needle_stereo = needle_vision.ros.stereo_node:main",
            "needle_stereo_offline = needle_vision.offline:main",
            "needle_stereo_calibrate = needle_vision.calibration.calibrate:main",
        ],
    },
)
