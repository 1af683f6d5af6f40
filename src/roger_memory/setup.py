from setuptools import find_packages, setup

package_name = "roger_memory"

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
        "back-propagation associative memory with winner-take-all and a "
        "persistent long-term memory"),
    license="Apache-2.0",
    entry_points={
        "console_scripts": ["roger-memory = roger_memory.memory_node:main"],
    },
)
