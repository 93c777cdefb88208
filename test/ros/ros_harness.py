"""The ROS suite's harness: a real ROS 2 Jazzy, the package built with colcon, processes and clients.

Nothing here imports rclpy: everything ROS runs in its own process with ROS 2's Python and the
environment of ``source /opt/ros/jazzy/setup.bash`` plus the test workspace's ``install/setup.bash``,
as a ROS user's shell would have. The test process only starts those processes, reads what they
print or write, and computes the expected values with neforward_ros itself.

Every process runs on a loopback-only Cyclone DDS configuration with a domain id of its test, in
its own process group (so that SIGINT reaches it as Ctrl-C in a terminal would), with its output in
a log file, and is stopped when its test ends.
"""

from __future__ import annotations

import itertools
import json
import os
import random
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

ROS_SETUP = Path(os.environ.get("NEFORWARD_ROS_SETUP", "/opt/ros/jazzy/setup.bash"))
REPO = Path(__file__).resolve().parents[2]
CLIENT = Path(__file__).with_name("rclpy_client.py")
PANDA = REPO / "config" / "panda.urdf"
COPY_IGNORE = shutil.ignore_patterns(
    ".git",
    ".venv*",
    "build",
    "install",
    "log",
    "__pycache__",
    ".pytest_cache",
    ".ruff_cache",
    ".hypothesis",
    "*.egg-info",
)
DEPENDENCIES = ("rclpy", "numpy", "yaml", "rosbags", "cyclonedds")

_DOMAINS = itertools.count(random.randint(20, 60))


def why_not_runnable() -> str | None:
    """None when the ROS suite can run here, else the reason it is skipped."""
    if not ROS_SETUP.is_file():
        return (
            f"ROS 2 Jazzy is not installed ({ROS_SETUP} is missing): the ROS suite needs it "
            "(../shared/ros2/install.sh, or apt install ros-jazzy-ros-base)"
        )
    return None


def sourced(scripts: list[Path], base: dict[str, str]) -> dict[str, str]:
    """The environment after ``source``-ing each script in bash, as a ROS user's shell does."""
    command = "set +u; " + " && ".join(f"source {shlex.quote(str(s))}" for s in scripts) + " && env -0"
    done = subprocess.run(["bash", "-c", command], env=base, capture_output=True, timeout=60, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"sourcing {scripts} failed: {done.stderr.decode()}")
    return dict(item.split("=", 1) for item in done.stdout.decode().split("\0") if "=" in item)


def ros_python(environment: dict[str, str]) -> str:
    """The Python that ROS 2 runs on, with the package's dependencies: NEFORWARD_ROS_PYTHON (``make
    test`` sets it to its .venv-ros), else this interpreter when it can import rclpy and colcon
    (``colcon test``), else Debian's python3."""
    chosen = os.environ.get("NEFORWARD_ROS_PYTHON")
    if chosen:
        return chosen
    probe = subprocess.run(
        [sys.executable, "-c", "import rclpy, colcon_core"], env=environment, capture_output=True, check=False
    )
    return sys.executable if probe.returncode == 0 else "/usr/bin/python3"


def missing_dependencies(python: str, environment: dict[str, str]) -> list[str]:
    code = "import importlib.util, sys; print(' '.join(m for m in sys.argv[1:] if importlib.util.find_spec(m) is None))"
    done = subprocess.run(
        [python, "-c", code, *DEPENDENCIES], env=environment, capture_output=True, text=True, timeout=60, check=False
    )
    return done.stdout.split() if done.returncode == 0 else [f"{python} does not run: {done.stderr.strip()}"]


class Workspace:
    """The package built by colcon in a temporary workspace, with ROS 2's Python."""

    def __init__(self, root: Path) -> None:
        self.root = root
        base = sourced([ROS_SETUP], dict(os.environ))
        self.python = ros_python(base)
        missing = missing_dependencies(self.python, base)
        if missing:
            raise DependencyMissingError(
                f"the ROS Python {self.python} lacks {', '.join(missing)}: `make test` prepares .venv-ros with "
                "them; elsewhere pip install rosbags cyclonedds into the Python ROS 2 runs on"
            )
        shutil.copytree(REPO, root / "src" / "neforward_ros", ignore=COPY_IGNORE, symlinks=True)
        self.colcon_list = self._colcon(base, "list")
        self.build_output = self._colcon(base, "build", "--event-handlers", "console_direct-")
        self.environment = sourced([ROS_SETUP, root / "install" / "setup.bash"], base)
        # As an activated virtual environment would: its scripts (xacro) come first on PATH.
        self.environment["PATH"] = f"{Path(self.python).parent}{os.pathsep}{self.environment['PATH']}"
        self.environment.pop("ROS_DOMAIN_ID", None)
        self.environment["PYTHONUNBUFFERED"] = "1"

    def _colcon(self, environment: dict[str, str], *arguments: str) -> str:
        done = subprocess.run(
            [self.python, "-m", "colcon", *arguments],
            cwd=self.root,
            env=environment,
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )
        if done.returncode != 0:
            raise RuntimeError(f"colcon {' '.join(arguments)} failed:\n{done.stdout}\n{done.stderr}")
        return done.stdout


class DependencyMissingError(RuntimeError):
    pass


class Process:
    """A process of a test, in its own process group, its output in a log file."""

    def __init__(self, command: list[str], environment: dict[str, str], log_path: Path, cwd: Path) -> None:
        self.command = command
        self.log_path = log_path
        self._log = open(log_path, "w")
        # SIGINT at its default whatever the suite inherited (a background job of a non-interactive
        # shell ignores it): interrupt() sends it as a terminal's Ctrl-C would.
        self.popen = subprocess.Popen(
            command, stdout=self._log, stderr=subprocess.STDOUT, env=environment, cwd=cwd, start_new_session=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )  # fmt: skip

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def alive(self) -> bool:
        return self.popen.poll() is None

    def wait_for(self, text: str, timeout: float = 30.0) -> None:
        deadline = time.monotonic() + timeout
        while text not in self.log():
            if not self.alive():
                raise AssertionError(
                    f"{self.command[:3]} exited ({self.popen.returncode}) before {text!r}:\n{self.log()}"
                )
            if time.monotonic() > deadline:
                raise AssertionError(f"no {text!r} from {self.command[:3]} in {timeout} s:\n{self.log()}")
            time.sleep(0.05)

    def interrupt(self, timeout: float = 20.0) -> int:
        """Ctrl-C, as a terminal sends it: SIGINT to the whole process group. Returns the exit code."""
        if self.popen.poll() is None:
            try:
                os.killpg(self.popen.pid, signal.SIGINT)
                self.popen.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                os.killpg(self.popen.pid, signal.SIGKILL)
                self.popen.wait()
            except ProcessLookupError:
                pass
        self._log.close()
        return self.popen.returncode

    def kill(self) -> None:
        if self.popen.poll() is None:
            try:
                os.killpg(self.popen.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.popen.wait()
        self._log.close()


class Graph:
    """One test's ROS graph: its own domain id, its processes, stopped at the end."""

    def __init__(self, workspace: Workspace, dds_config: Path, directory: Path) -> None:
        self.workspace = workspace
        self.directory = directory
        self.domain = next(_DOMAINS)
        self.environment = {
            **workspace.environment,
            "ROS_DOMAIN_ID": str(self.domain),
            "CYCLONEDDS_URI": dds_config.as_uri(),
        }
        self.processes: list[Process] = []

    def start(self, *command: str) -> Process:
        log_path = self.directory / f"process{len(self.processes)}-{Path(command[0]).name}.log"
        process = Process(list(command), self.environment, log_path, self.directory)
        self.processes.append(process)
        return process

    def run(self, *command: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
        return subprocess.run(
            list(command),
            env=self.environment,
            cwd=self.directory,
            capture_output=True,
            text=True,
            timeout=timeout,
            check=False,
            start_new_session=True,
        )

    def ros2(self, *arguments: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
        return self.run("ros2", *arguments, timeout=timeout)

    def client(self, plan: dict, timeout: float = 120.0) -> dict[str, list[dict]]:
        """Run the rclpy client on a plan; returns what it received, per topic."""
        number = len(list(self.directory.glob("plan*.json")))
        plan_path = self.directory / f"plan{number}.json"
        out_path = self.directory / f"received{number}.json"
        plan_path.write_text(json.dumps(plan))
        done = self.run(
            self.workspace.python, str(CLIENT), "stream", "--plan", str(plan_path), "--out", str(out_path),
            timeout=timeout,
        )  # fmt: skip
        assert done.returncode == 0, f"client failed ({done.returncode}):\n{done.stdout}\n{done.stderr}\n" + "\n".join(
            p.log() for p in self.processes
        )
        return json.loads(out_path.read_text())

    def feeder(self, plan: dict) -> Process:
        """The rclpy client publishing a plan in the background (records nothing) until stopped."""
        number = len(list(self.directory.glob("plan*.json")))
        plan_path = self.directory / f"plan{number}.json"
        plan_path.write_text(json.dumps({**plan, "record": {}}))
        out = self.directory / f"received{number}.json"
        return self.start(self.workspace.python, str(CLIENT), "stream", "--plan", str(plan_path), "--out", str(out))

    def latch(self, urdf: Path, topic: str = "/robot_description") -> Process:
        """A separate process publishing the robot description, transient local, until stopped."""
        process = self.start(self.workspace.python, str(CLIENT), "latch", "--urdf", str(urdf), "--topic", topic)
        process.wait_for("published")
        return process

    def stop_all(self) -> None:
        for process in reversed(self.processes):
            process.interrupt(timeout=10.0)
