"""``neforward bag`` speed against rosbags alone, measured in one run.

Writes a 60 s, 500 Hz recording of the bundled arm's joint states (7 arm joints and the finger,
positions only, MCAP), then times (a) rosbags reading and deserializing every JointState message
(``Typestore.deserialize_cdr``), the peer, and (b) the whole ``neforward bag`` run: reading,
estimation, recursion, writing link_states and com_states to a new MCAP recording. Prints both and
their ratio; then (c) the whole command as users run it, in its own process, process start and
imports included, against the same in-process peer: warm, with the cache of an earlier run on the
URDF (compiled kernels, message-type facts; target at most 2), and cold, with an empty cache (target
at most 3). Python's bytecode cache is on for the command, as in any install. Interleaved repeats;
medians.

With ``--long`` (what ``make bench`` also runs): a 10-minute recording (300,000 joint states,
positions only), and the peer is a whole Python process that reads and deserializes it with rosbags
(process start and imports included, as for the command): targets at most 1.5 warm and 1.8 cold;
the accelerations of the long run are checked against the exact ones.

Usage: python bench/bench_bag.py [--seconds 60] [--repeats 3] [--long]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader, StoragePlugin, Writer

sys.path.insert(0, str(Path(__file__).resolve().parent))
from motion_family import EPOCH_NS

from neforward_ros import load_model
from neforward_ros.bag import BagOptions, process_bag
from neforward_ros.interface import topics
from neforward_ros.stamps import time_message
from neforward_ros.wire import cdr
from neforward_ros.wire.rostypes import typestore

URDF = Path(__file__).resolve().parent.parent / "config" / "panda.urdf"


def make_recording(path: Path, seconds: float) -> int:
    model = load_model(URDF)
    names = list(model.joint_names)
    count = int(seconds * 500)
    rng = np.random.default_rng(0)
    t = (np.arange(count) + rng.uniform(-0.1, 0.1, count)) / 500.0
    q = 0.4 * np.sin(np.outer(t, np.linspace(1.0, 4.0, len(names))))
    q[:, -1] *= 0.05  # the finger, in m
    store = typestore()
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection("/joint_states", topics.JOINT_STATE_TYPE, typestore=store)
        for k in range(count):
            stamp = EPOCH_NS + round(t[k] * 1e9)
            contents = {"header": {"stamp": time_message(stamp)}, "name": names, "position": q[k].tolist()}
            writer.write(connection, stamp, cdr.encode(topics.JOINT_STATE_TYPE, contents))
    return count


def rosbags_alone(path: Path) -> float:
    store = typestore()
    start = time.perf_counter()
    with Reader(path) as reader:
        for connection, _, raw in reader.messages():
            store.deserialize_cdr(raw, connection.msgtype)
    return time.perf_counter() - start


PEER_SCRIPT = """
import sys
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
store = get_typestore(Stores.ROS2_JAZZY)
with Reader(sys.argv[1]) as reader:
    for connection, _, raw in reader.messages():
        store.deserialize_cdr(raw, connection.msgtype)
"""


def installed() -> dict[str, str]:
    """The environment of both timed processes: Python's bytecode cache on, as in an install (pip
    compiles it; colcon too). This machine's shell may turn it off (PYTHONDONTWRITEBYTECODE), which
    would time the compilation of every module; the peer and the command run alike."""
    return {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def rosbags_process(path: Path) -> float:
    """The peer of the long run: a whole Python process reading and deserializing every message."""
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", PEER_SCRIPT, str(path)], env=installed(), check=True, capture_output=True)
    return time.perf_counter() - start


def check_accelerations(recording: Path, output: Path, seconds: float) -> float:
    """The largest error of the link accelerations written, relative to the largest exact one, on the
    last tenth of the run (the recording's joint motion is known in closed form)."""
    from neforward_ros import forward_recursion
    from neforward_ros.interface.topics import LINK_STATES

    model = load_model(URDF)
    store = typestore()
    stamps, accels = [], []
    epoch_s = EPOCH_NS / 1e9
    with Reader(output) as reader:
        connections = [c for c in reader.connections if c.topic.endswith(LINK_STATES.lstrip("~"))]
        for connection, _, raw in reader.messages(connections=connections):
            message = store.deserialize_cdr(raw, connection.msgtype)
            t = message.header.stamp.sec + message.header.stamp.nanosec * 1e-9
            if t < epoch_s + 0.9 * seconds:
                continue
            stamps.append(t - epoch_s)
            accels.append([[a.linear.x, a.linear.y, a.linear.z] for a in message.points[0].accelerations])
    t = np.asarray(stamps)
    w = np.linspace(1.0, 4.0, len(model.joint_names))
    q = 0.4 * np.sin(np.outer(t, w))
    qd = 0.4 * np.cos(np.outer(t, w)) * w
    qdd = -0.4 * np.sin(np.outer(t, w)) * w**2
    for column in (q, qd, qdd):
        column[:, -1] *= 0.05
    exact_in_root = forward_recursion(model, q, qd, qdd).in_root().accel
    return float(np.abs(np.asarray(accels) - exact_in_root).max() / np.abs(exact_in_root).max())


def verdict(every_run_met: bool) -> str:
    return "met in every run" if every_run_met else "NOT met in every run"


def long_run(folder: Path, repeats: int) -> None:
    seconds = 600.0
    count = make_recording(folder / "long", seconds)
    neforward_command(folder / "long", folder / "long-out", folder / "cache")  # the URDF seen once
    error = check_accelerations(folder / "long", folder / "long-out", seconds)
    peer, warm, cold = [], [], []
    for k in range(repeats):
        os.sync()
        peer.append(rosbags_process(folder / "long"))
        os.sync()
        warm.append(neforward_command(folder / "long", folder / "long-out", folder / "cache"))
        os.sync()
        cold.append(neforward_command(folder / "long", folder / "long-out", folder / f"empty-cache-long-{k}"))
    a, b, c = (statistics.median(x) for x in (peer, warm, cold))
    print(f"{count} joint states ({seconds:g} s at 500 Hz, 8 joints, positions only), median of {repeats}")
    print(f"a whole Python process reading and deserializing it with rosbags: {a:.2f} s  (runs: "
          f"{', '.join(f'{x:.2f}' for x in peer)})")  # fmt: skip
    for what, runs, ratio, target in (("warm", warm, b / a, 1.5), ("cold", cold, c / a, 1.8)):
        pairs = [x / y for x, y in zip(runs, peer, strict=True)]  # each run against the peer run beside it
        print(f"`neforward bag`, {what}: {statistics.median(runs):.2f} s, ratio {ratio:.2f} (target <= {target:g}); "
              f"runs: {', '.join(f'{x:.2f}' for x in runs)}; each against the peer's run beside it: "
              f"{', '.join(f'{x:.2f}' for x in pairs)} ({verdict(max(pairs) <= target)})")  # fmt: skip
    print(
        f"link accelerations on the last minute against the exact ones: largest error {100 * error:.2g} % of "
        "the largest acceleration"
    )


def neforward_bag(path: Path, output: Path) -> float:
    shutil.rmtree(output, ignore_errors=True)
    start = time.perf_counter()
    process_bag(path, output, BagOptions(urdf=str(URDF)))
    return time.perf_counter() - start


def neforward_command(path: Path, output: Path, cache: Path) -> float:
    """The whole command as a user runs it, process start included, with the model cache at ``cache``."""
    shutil.rmtree(output, ignore_errors=True)
    environment = installed()
    environment["NEFORWARD_CACHE"] = str(cache)
    command = [
        str(Path(sys.executable).with_name("neforward")),
        "bag",
        str(path),
        "-o",
        str(output),
        "--urdf",
        str(URDF),
    ]
    start = time.perf_counter()
    subprocess.run(command, env=environment, check=True, capture_output=True)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--dir",
        default="/dev/shm" if Path("/dev/shm").is_dir() else None,
        help="where the recordings go (default: /dev/shm, a tmpfs, when there is one: the comparison is of "
        "computing, and the peer writes nothing; give a folder on disk to include the disk's speed)",
    )
    parser.add_argument("--long", action="store_true", help="the 10-minute recording against a whole rosbags process")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="neforward-bench-bag-", dir=args.dir))
    try:
        if args.long:
            long_run(folder, args.repeats)
            return
        count = make_recording(folder / "in", args.seconds)
        neforward_command(folder / "in", folder / "out", folder / "cache")  # the warm cache: seen the URDF once
        peer, ours, command, first = [], [], [], []
        for k in range(args.repeats):
            # Each timed run starts with no earlier run's output still being written back to disk.
            os.sync()
            peer.append(rosbags_alone(folder / "in"))
            os.sync()
            ours.append(neforward_bag(folder / "in", folder / "out"))
            os.sync()
            first.append(neforward_command(folder / "in", folder / "out", folder / f"empty-cache-{k}"))
            os.sync()
            command.append(neforward_command(folder / "in", folder / "out", folder / "cache"))
        a, b, c, d = (statistics.median(x) for x in (peer, ours, command, first))
        print(f"{count} joint states ({args.seconds:g} s at 500 Hz, 8 joints), median of {args.repeats}, in {folder}")
        print(f"rosbags read + deserialize, in process: {a:.2f} s")
        print(f"neforward bag in process (read, estimate, recursion, write 2 x {count} messages): {b:.2f} s")
        print(f"  ratio to rosbags alone: {b / a:.2f}")
        print(f"`neforward bag` as users run it, process start included, warm (the URDF seen before): {c:.2f} s")
        print(f"  ratio to rosbags alone: {c / a:.2f} (target <= 2)")
        print(f"  the same, cold (an empty cache: no compiled kernels, no type facts): {d:.2f} s, ratio {d / a:.2f} "
              "(target <= 3)")  # fmt: skip
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
