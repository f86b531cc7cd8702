"""Package discovery: `cli/` installs as `avatarkit.cli`, `schemas/` as `avatarkit.schemas`.

The rest of the metadata lives in pyproject.toml. A computed list (rather than a static one)
means a new sub-package never needs an edit here.
"""
from setuptools import find_packages, setup

packages = find_packages(include=["avatarkit", "avatarkit.*"])
packages += ["avatarkit.cli" + p[len("cli"):] for p in find_packages(include=["cli", "cli.*"])]
packages += ["avatarkit.schemas"]

setup(packages=packages, package_dir={"avatarkit.cli": "cli", "avatarkit.schemas": "schemas"})
