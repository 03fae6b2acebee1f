from glob import glob

from setuptools import find_packages, setup

package_name = "sclam_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "bench", "bench.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/launch_configs", glob("launch_configs/*")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="sclam_ros developers",
    maintainer_email="sclam-ros@example.com",
    description="Simultaneous calibration, localization and mapping for differential-drive robots",
    license="LGPL-3.0-or-later",
    entry_points={
        "console_scripts": [
            "sclam = sclam_ros.cli.main:main",
            "sclam_node = sclam_ros.ros.node:main",
        ],
    },
)
