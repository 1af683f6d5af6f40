from setuptools import find_packages, setup

package_name = "roger_bringup"

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
    description="launcher: orchestrator, roger command line, monitor, recorder and view nodes",
    license="Apache-2.0",
    entry_points={
        "console_scripts": ["roger = roger_bringup.cli:main"],
    },
)
