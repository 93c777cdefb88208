"""The package's layout, as docs/architecture.md's module map describes it: layers that import only downwards,
no import cycles, the bag tool and the runtimes sharing the computation and never each other's
internals, no module importing a command-line module, one module importing rclpy, and the core
importable without ROS or a middleware."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "neforward_ros"

LAYERS = (
    ("errors", "logs", "stamps", "rotations", "terminal", "ctrl_c", "disk_cache", "resources"),
    ("model",),
    ("kinematics", "wire"),
    ("estimation",),
    ("parameters",),
    ("computation",),
    ("interface",),
    ("node",),
    ("bag", "dds", "ros_node", "node_entry", "demo"),
    ("calibration",),
    ("cli", "command", "__main__"),
)
"""Bottom up: a module imports from its own layer or those below, never from above."""

APPLICATIONS = {"bag": "bag", "dds": "dds", "ros_node": "rclpy", "node_entry": "rclpy"}
"""The bag tool and the two runtimes: each imports what is below them, never another one's modules
(the demo drives the no-ROS runtime as a user would, and may use its DDS helpers)."""

COMMAND_LINE = ("neforward_ros.cli", "neforward_ros.command", "neforward_ros.__main__", "neforward_ros.bag.arguments",
                "neforward_ros.bag.commands", "neforward_ros.dds.commands",
                "neforward_ros.calibration.commands")  # fmt: skip
"""Modules that read a command line: only the command line itself imports them."""


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports() -> dict[str, set[str]]:
    """Each module of the package -> the package modules it imports (at any level of its code)."""
    modules = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        targets = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("neforward_ros"):
                for alias in node.names:
                    full = f"{node.module}.{alias.name}"
                    targets.add(full if full in modules else node.module)
            elif isinstance(node, ast.Import):
                targets.update(a.name for a in node.names if a.name.startswith("neforward_ros"))
        graph[name] = {t for t in targets if t in modules and t != name and t != "neforward_ros"}
    return graph


def top(module: str) -> str:
    """The first name under the package: ``neforward_ros.bag.read`` -> ``bag``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def layer(module: str) -> int:
    for number, names in enumerate(LAYERS):
        if top(module) in names:
            return number
    raise AssertionError(f"{module} is in no layer of the module map: add it to LAYERS and docs/architecture.md")


def test_no_import_cycles() -> None:
    graph = imports()
    state: dict[str, int] = {}
    cycles = []

    def visit(module: str, path: list[str]) -> None:
        state[module] = 1
        for target in sorted(graph[module]):
            if state.get(target) == 1:
                cycles.append(" -> ".join([*path[path.index(target) :], target]))
            elif target not in state:
                visit(target, [*path, target])
        state[module] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_every_module_imports_only_its_own_layer_and_those_below() -> None:
    upward = [
        f"{module} ({LAYERS[layer(module)][0]}...) imports {target} ({LAYERS[layer(target)][0]}...)"
        for module, targets in imports().items()
        if module != "neforward_ros"
        for target in targets
        if layer(target) > layer(module)
    ]
    assert not upward, "imports against the layers:\n" + "\n".join(upward)


def test_the_bag_tool_and_the_runtimes_never_import_each_others_internals() -> None:
    crossing = [
        f"{module} imports {target}"
        for module, targets in imports().items()
        for target in targets
        if top(module) in APPLICATIONS
        and top(target) in APPLICATIONS
        and APPLICATIONS[top(target)] != APPLICATIONS[top(module)]
    ]
    assert not crossing, "\n".join(crossing)


def test_no_module_imports_a_command_line_module() -> None:
    importing = [
        f"{module} imports {target}"
        for module, targets in imports().items()
        for target in targets
        if target in COMMAND_LINE and module not in ("neforward_ros.cli", "neforward_ros.command",
                                                     "neforward_ros.__main__", "neforward_ros.bag.commands")
    ]  # fmt: skip
    assert not importing, "\n".join(importing)


def test_only_the_rclpy_adapter_imports_rclpy() -> None:
    importing = [
        module_name(p)
        for p in PACKAGE.rglob("*.py")
        if any(
            isinstance(n, (ast.Import, ast.ImportFrom))
            and any((getattr(n, "module", None) or a.name).split(".")[0] == "rclpy" for a in n.names)
            for n in ast.walk(ast.parse(p.read_text()))
        )
    ]
    assert importing == ["neforward_ros.ros_node"]


def test_the_core_imports_without_ros_cyclonedds_or_rosbags() -> None:
    code = (
        "import sys; import neforward_ros.node.pipeline, neforward_ros.node.handlers, "
        "neforward_ros.computation.compute, neforward_ros.bag.compute; "
        "bad = [m for m in ('rclpy', 'cyclonedds', 'rosbags', 'matplotlib') if m in sys.modules]; print(bad)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert done.stdout.strip() == "[]", done.stdout + done.stderr
