from setuptools import find_packages, setup

package_name = "roger_sim"

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
    description=(
        "pybullet simulator of Roger-the-Crab: robot, servo controllers, Phong "
        "retinas, haptics, world files"),
    license="Apache-2.0",
    entry_points={
        "console_scripts": ["roger-sim = roger_sim.sim_node:main"],
    },
)
