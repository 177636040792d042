from glob import glob

from setuptools import find_packages, setup

package_name = "needle_vision"

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
