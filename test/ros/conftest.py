"""Fixtures of the ROS suite: the colcon-built workspace (once per session) and a graph per test.

Skipped, with the reason, where ROS 2 Jazzy is not installed. ``make test`` sets
NEFORWARD_REQUIRE_ROS=1 when it finds ROS 2, which turns a missing dependency into a failure: CI
cannot pass by skipping this suite.
"""

from __future__ import annotations

import os

import pytest

from neforward_ros.dds.loopback import write_config

from .ros_harness import DependencyMissingError, Graph, Workspace, why_not_runnable

REQUIRED = os.environ.get("NEFORWARD_REQUIRE_ROS") == "1"


def _unavailable(reason: str) -> None:
    if REQUIRED:
        pytest.fail(f"NEFORWARD_REQUIRE_ROS=1 but {reason}")
    pytest.skip(reason)


@pytest.fixture(scope="session")
def workspace(tmp_path_factory) -> Workspace:
    reason = why_not_runnable()
    if reason:
        _unavailable(reason)
    try:
        return Workspace(tmp_path_factory.mktemp("ros_ws"))
    except DependencyMissingError as exc:
        _unavailable(str(exc))
        raise


@pytest.fixture(scope="session")
def dds_config(tmp_path_factory):
    return write_config(tmp_path_factory.mktemp("dds_ros"))


@pytest.fixture
def graph(workspace, dds_config, tmp_path):
    graph = Graph(workspace, dds_config, tmp_path)
    yield graph
    graph.stop_all()
