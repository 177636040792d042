from glob import glob

from setuptools import find_packages, setup

package_name = "needle_sim_ros"

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
    ],
    install_requires=["setuptools"],
    extras_require={"test": ["pytest"]},
    zip_safe=True,
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
