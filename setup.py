"""Packages of the wheel: the library, and the checkout's data folders as mjendo/_data/<folder>.

models/ (scenes, stomach mesh and targets, shipped policies) and train/ (the
training config) stay at the top of the checkout, where users look for them;
each of their folders is mapped to a package under ``mjendo._data`` so an
installed wheel carries them (mjendo/paths.py finds them in either place).
"""

from pathlib import Path

from setuptools import setup

HERE = Path(__file__).parent
packages, package_dir, package_data = ["mjendo"], {}, {}
for folder in ("models", "train"):
    for d in sorted(p for p in [HERE / folder, *(HERE / folder).rglob("*")] if p.is_dir()):
        rel = d.relative_to(HERE)
        name = ".".join(["mjendo", "_data", *rel.parts])
        packages.append(name)
        package_dir[name] = rel.as_posix()
        package_data[name] = ["*"]

setup(packages=packages, package_dir=package_dir, package_data=package_data)
