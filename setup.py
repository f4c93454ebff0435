"""Package layout: the library lives in src/zcomp_cli; the Blender scripts live at the
repository root in blender_scripts/ (run by a subprocess, never imported by zcomp) and
ship inside the wheel as the data package ``zcomp_cli.blender_scripts``."""
from setuptools import find_packages, setup

setup(
    packages=find_packages("src") + ["zcomp_cli.blender_scripts"],
    package_dir={"": "src", "zcomp_cli.blender_scripts": "blender_scripts"},
)
