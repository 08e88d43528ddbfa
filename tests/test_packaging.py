"""What a built wheel holds: every package, and the shipped configs and data found by paths."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest
from setuptools import find_packages

from ebus_env import paths
from ebus_env.config import find_config

ROOT = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_the_package_list_names_every_package_of_the_checkout():
    listed = set(PYPROJECT["tool"]["setuptools"]["packages"])
    found = set(find_packages(str(ROOT), include=["ebus_env*", "agents*"]))
    assert found - listed == set(), "add these packages to pyproject.toml"
    mapped = PYPROJECT["tool"]["setuptools"]["package-dir"]
    for package, folder in mapped.items():
        assert package in listed and (ROOT / folder).is_dir()


@pytest.mark.parametrize("kind", ["bus", "env", "calibration", "agents", "logs"])
def test_every_config_kind_is_found_through_paths(kind):
    names = paths.config_names(kind)
    assert names, kind
    for name in names:
        assert find_config(name, kind) == paths.configs(kind) / f"{name}.yaml"


def test_the_shipped_data_are_covered_by_the_package_data_globs():
    globs = PYPROJECT["tool"]["setuptools"]["package-data"]
    for package, folder in PYPROJECT["tool"]["setuptools"]["package-dir"].items():
        shipped = {p for pattern in globs[package] for p in (ROOT / folder).glob(pattern)}
        files = {p for p in (ROOT / folder).rglob("*") if p.is_file()}
        assert files - shipped == set(), f"files of {folder}/ a wheel would leave out"
    assert (paths.data("cycles", "carculator", "sort2.csv")).is_file()
    assert (paths.trained("ppo_sort2_day") / "model.zip").is_file()


def test_both_packages_say_they_are_typed_in_the_wheel():
    """PEP 561: a ``py.typed`` marker in ``ebus_env`` and ``agents``, shipped by package-data,
    so that a type checker reads the installed packages' annotations."""
    globs = PYPROJECT["tool"]["setuptools"]["package-data"]
    for package in ("ebus_env", "agents"):
        assert (ROOT / package / "py.typed").is_file()
        assert "py.typed" in globs[package]
