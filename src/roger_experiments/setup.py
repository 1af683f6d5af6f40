from setuptools import find_packages, setup

package_name = "roger_experiments"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    description="the paper's experiments without ROS: core loop, scoring, Table 2, training, "
                "Gymnasium env",
    license="Apache-2.0",
)
