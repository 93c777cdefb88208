"""Shared test helpers: the test robots and an accuracy assertion."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

TEST_DIR = Path(__file__).resolve().parent
URDF_DIR = TEST_DIR / "urdf"
CONFIG_DIR = TEST_DIR.parent / "config"
EPOCH_NS = 1_700_000_000 * 10**9
"""A wall-clock epoch (2023-11-14, integer ns) that the tests' stamps start from, as a driver's would."""

TEST_ROBOTS = {
    "planar_2r": URDF_DIR / "planar_2r.urdf",
    "arm_6r": URDF_DIR / "arm_6r.urdf",
    "tree": URDF_DIR / "tree.urdf",
    "prismatic": URDF_DIR / "prismatic.urdf",
    "mimic": URDF_DIR / "mimic.urdf",
    "fixed_between": URDF_DIR / "fixed_between.urdf",
    "humanoid": URDF_DIR / "humanoid.urdf",
    "inertias": URDF_DIR / "inertias.urdf",
    "panda": CONFIG_DIR / "panda.urdf",
}


OPTIONAL = {
    "cyclonedds": "pip install cyclonedds (the no-ROS runtime)",
    "rosbags": "pip install rosbags (ROS 2 message types without ROS)",
    "hypothesis": "pip install hypothesis (a test extra)",
    "scipy": "pip install scipy (a test extra)",
    "pinocchio": "pip install pin (Pinocchio, the test oracle; a test extra)",
    "catkin_pkg": "pip install catkin_pkg (a test extra)",
    "matplotlib": "pip install matplotlib (the plot extra)",
    "distributed": "pip install 'dask[distributed]' (a test extra: the fleet recipe on a Dask cluster)",
}


# What each test module needs beyond the package's core (numpy, yourdfpy, PyYAML).
REQUIREMENTS = {
    "test_bag.py": ("rosbags", "pinocchio"),
    "test_bag_options.py": ("rosbags", "pinocchio"),
    "test_node_and_bag_agree.py": ("rosbags",),
    "test_bag_plot.py": ("matplotlib",),
    "test_fleet.py": ("rosbags", "pinocchio"),
    "test_interrupts.py": ("rosbags", "pinocchio"),
    "test_play.py": ("cyclonedds", "rosbags", "pinocchio"),
    "test_cdr.py": ("hypothesis", "rosbags"),
    "test_dds_node.py": ("cyclonedds", "rosbags"),
    "test_demo.py": ("cyclonedds",),
    "test_derivatives_stream.py": ("hypothesis",),
    "test_dynamics.py": ("pinocchio", "scipy"),
    "test_floating_base.py": ("pinocchio",),
    "test_torques.py": ("pinocchio",),
    "test_pipeline_messages.py": ("scipy", "rosbags", "pinocchio"),
    "test_recursion_pinocchio.py": ("pinocchio",),
    "test_joint_space.py": ("pinocchio",),
    "test_contact.py": ("pinocchio", "rosbags"),
    "test_contact_live.py": ("pinocchio", "rosbags", "cyclonedds"),
}


def missing(*modules: str) -> list[str]:
    return [module for module in modules if importlib.util.find_spec(module) is None]


def require(*modules: str) -> None:
    """Skip the calling test, saying why, when one of these is not installed."""
    for module in missing(*modules):
        pytest.skip(f"{module} is not installed: {OPTIONAL[module]}")


class _Unavailable(pytest.File):
    """A test module whose requirements are missing: reported as skipped, with the reason, and never
    imported. (ROS 2's launch_testing pytest plugin imports every module while collecting, and a
    module-level skip raised there would abort the collection of the whole folder under colcon test.)"""

    reason = ""

    def collect(self):
        pytest.skip(self.reason)


@pytest.hookimpl(tryfirst=True)
def pytest_pycollect_makemodule(module_path, parent):
    absent = missing(*REQUIREMENTS.get(module_path.name, ()))
    if not absent:
        return None
    node = _Unavailable.from_parent(parent, path=module_path)
    node.reason = "; ".join(f"{module} is not installed: {OPTIONAL[module]}" for module in absent)
    return node


class LogRecorder:
    """A log function (``log(level, message)``) that keeps what it is given."""

    def __init__(self) -> None:
        self.lines: list[tuple[int, str]] = []

    def __call__(self, level: int, message: str) -> None:
        self.lines.append((level, message))

    def count(self, text: str) -> int:
        return sum(text in message for _, message in self.lines)


def assert_close(actual: np.ndarray, expected: np.ndarray, rel: float, what: str = "") -> None:
    """|actual - expected| <= rel * max(1, max |expected|), elementwise: relative to the field's scale."""
    actual, expected = np.asarray(actual), np.asarray(expected)
    assert actual.shape == expected.shape, f"{what}: shape {actual.shape} != {expected.shape}"
    scale = max(1.0, float(np.max(np.abs(expected), initial=0.0)))
    error = float(np.max(np.abs(actual - expected), initial=0.0))
    assert error <= rel * scale, f"{what}: max error {error:.3e} exceeds {rel:.1e} x scale {scale:.3e}"


@pytest.fixture(autouse=True, scope="session")
def disk_cache_of_this_session(tmp_path_factory):
    """Message-type facts are cached on disk (neforward_ros.disk_cache): the suite keeps its own, in a
    temporary folder, for itself and every process it starts."""
    import os

    os.environ["NEFORWARD_CACHE"] = str(tmp_path_factory.mktemp("disk_cache"))


@pytest.fixture(autouse=True)
def models_read_not_recalled(request, monkeypatch):
    """In this process every test reads its URDFs (what a test of the reading checks); the disk cache
    of built models is tested by test_model_cache.py, and used by the processes tests start."""
    if "model_cache" not in request.keywords:
        import neforward_ros.model.load as load

        monkeypatch.setattr(load, "stored_model", lambda description, root_link: None)


@pytest.fixture(params=sorted(TEST_ROBOTS))
def robot_path(request) -> Path:
    return TEST_ROBOTS[request.param]


# Reference signal of the issue: a sum of sinusoids 0.2-1.6 Hz, amplitudes 0.05-0.8 rad.
AMPLITUDE = np.array([0.8, 0.3, 0.05])
FREQUENCY = np.array([0.2, 0.7, 1.6])
PHASE = np.array([0.3, 1.1, 2.0])


def reference(t: np.ndarray, shift: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    w = 2 * np.pi * FREQUENCY
    arg = np.outer(t, w) + PHASE + shift
    q = (AMPLITUDE * np.sin(arg)).sum(1)
    return q, (AMPLITUDE * w * np.cos(arg)).sum(1), (-AMPLITUDE * w**2 * np.sin(arg)).sum(1)


def jittered_stamps(n: int, rate: float = 500.0, jitter: float = 0.1, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (np.arange(n) + rng.uniform(-jitter, jitter, n)) / rate


def relative_rms(estimate: np.ndarray, truth: np.ndarray, part: slice = slice(None)) -> float:
    return float(np.sqrt(np.mean((estimate[part] - truth[part]) ** 2)) / np.sqrt(np.mean(truth[part] ** 2)))
