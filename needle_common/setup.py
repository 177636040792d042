from setuptools import find_packages, setup

package_name = "needle_common"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    extras_require={"test": ["pytest"]},
    zip_safe=True,
    maintainer="needle_sim developers",
    maintainer_email="dev@needle-sim.invalid",
    description="The base of the needle_sim suite, below needle_sim_ros and needle_vision.",
    license="Apache-2.0",
)
