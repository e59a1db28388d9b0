"""Package discovery only (everything else is in pyproject.toml): every kinredund subpackage, plus the
top-level ``robots/`` folder shipped as ``kinredund.robots`` so that an installed wheel finds the URDFs."""

from setuptools import find_packages, setup

setup(
    packages=find_packages(include=["kinredund", "kinredund.*"]) + ["kinredund.robots"],
    package_dir={"kinredund.robots": "robots"},
)
