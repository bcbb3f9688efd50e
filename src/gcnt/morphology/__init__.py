"""Robots as data and as graphs (numpy, mujoco and dm_control only; no torch)."""

from typing import Any

from gcnt.morphology.catalogues import (
    BenchmarkFileError,
    Catalogue,
    DuplicateRobotError,
    UnknownRobotError,
    get_catalogue,
    load_benchmarks,
    morphologies_dir,
    register_catalogue,
    resolve_robots,
    smpenv_robot,
)
from gcnt.morphology.graph import DIST_PAD, WL_BUCKETS, WL_ROUNDS, RobotGraph
from gcnt.morphology.limb_types import GLOBAL_LIMB_TYPES, GLOBAL_TYPE_ID
from gcnt.morphology.robot import Robot, RobotFileError, load_robot, robot_from_xml
from gcnt.morphology.smpenv import SMPENV_ROBOTS, build_mjcf, write_all

__all__ = [
    "BENCHMARKS",
    "DIST_PAD",
    "GLOBAL_LIMB_TYPES",
    "GLOBAL_TYPE_ID",
    "SMPENV_ROBOTS",
    "WL_BUCKETS",
    "WL_ROUNDS",
    "BenchmarkFileError",
    "Catalogue",
    "DuplicateRobotError",
    "Robot",
    "RobotFileError",
    "RobotGraph",
    "UnknownRobotError",
    "build_mjcf",
    "get_catalogue",
    "load_benchmarks",
    "load_robot",
    "morphologies_dir",
    "register_catalogue",
    "resolve_robots",
    "robot_from_xml",
    "smpenv_robot",
    "write_all",
]


def __getattr__(name: str) -> Any:
    # BENCHMARKS is read from the catalogues' split files on first access, not at import.
    if name == "BENCHMARKS":
        from gcnt.morphology.catalogues import load_benchmarks

        return load_benchmarks()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
