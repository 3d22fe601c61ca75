"""ament_python package: `colcon build` puts the node executables in lib/changing_slam_ros/."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "changing_slam_ros"
NODES = ["detection", "tracking", "local_mapping", "loop_closing", "object_map", "bag_player"]

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={PACKAGE: ["models/*.onnx", "models/*.md", "models/*.npz", "py.typed"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.rviz") + glob("config/*.json")),
        (f"share/{PACKAGE}/launch", glob("launch/*.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="changing_slam_ros maintainers",
    maintainer_email="maintainers@changing-slam-ros.invalid",
    description="Visual SLAM for dynamic and changing environments as a ROS 2 node graph.",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [f"{node} = {PACKAGE}.nodes.{node}_node:main" for node in NODES]
        + ["changing-slam = changing_slam_ros.cli:main"],
    },
)
