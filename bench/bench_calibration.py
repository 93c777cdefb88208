"""Calibration and contact on real arms' recordings (``../shared/realdata``), as a user runs them.

Franka Panda (``panda_gaz_trajectory1``, measured joint torques): ``neforward calibrate`` on the first
60 % of the recording (default options), then ``neforward bag --params`` on exactly the last 40 %:
per joint, the RMS external torque in this free motion relative to the RMS measured torque, against
the figures of the model Gaz et al. identified from this very data (RA-L 2019): the target is at most
theirs on every joint, with no contact reported.

UR10e (motor currents): ``neforward calibrate`` on the three unloaded 50 s excitation runs (default
options; with ``--gains``, the drive gains of the README given as effort scales), then ``neforward
bag --params`` on every other recording: the contact episodes each reports (free motion: none;
``push_pose_1``: the arm held still and pushed by hand). With ``--leave-one-out``: three
calibrations, each on two of the three runs, then the held-out run (a free motion the calibration did
not see, as a user's other recordings are: no contact wanted) and ``push_pose_1`` (its four pushes).

Usage: python bench/bench_calibration.py [--realdata ../shared/realdata] [--gains] [--leave-one-out]
"""

from __future__ import annotations

import argparse
import importlib.metadata
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader, StoragePlugin, Writer

from neforward_ros.wire.rostypes import typestore

GAZ = (0.175, 0.035, 0.039, 0.031, 0.148, 0.138, 0.242)
UR_GAINS = (10.0, 10.6956, 8.4566, 9.0029, 9.48, 10.1232)
UR_JOINTS = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
UR_CALIBRATION = ("ur-20_02_12-50sec_12harm", "ur-20_02_19_14harm50sec", "ur-20_02_19_15harm50sec")


def panda_urdf() -> Path:
    for f in importlib.metadata.files("example-robot-data") or []:
        if str(f).endswith("panda_description/urdf/panda.urdf"):
            return Path(str(f.locate()))
    raise SystemExit("pip install example-robot-data: its panda_description/urdf/panda.urdf is the Panda's URDF")


def neforward(*arguments: str) -> str:
    done = subprocess.run(
        [str(Path(sys.executable).with_name("neforward")), *arguments], capture_output=True, text=True, check=False
    )
    if done.returncode != 0:
        raise SystemExit(f"neforward {' '.join(arguments)} failed:\n{done.stderr}")
    return done.stdout + done.stderr


def split(recording: Path, first: Path, last: Path, fraction: float = 0.6) -> int:
    """The first ``fraction`` of the messages and exactly the rest, as two recordings; returns the rest's count."""
    with Reader(recording) as reader:
        connection = reader.connections[0]
        messages = [(t, bytes(raw)) for _, t, raw in reader.messages()]
    cut = len(messages) - round(len(messages) * (1.0 - fraction))
    for path, part in ((first, messages[:cut]), (last, messages[cut:])):
        with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            out = writer.add_connection(connection.topic, connection.msgtype, typestore=typestore())
            for t, raw in part:
                writer.write(out, t, raw)
    return len(messages) - cut


def series(path: Path, topic_end: str) -> tuple[np.ndarray, np.ndarray]:
    """(stamps ns, efforts) of a JointState topic of a recording."""
    store = typestore()
    stamps, values = [], []
    with Reader(path) as reader:
        chosen = [c for c in reader.connections if c.topic.endswith(topic_end)]
        for connection, _, raw in reader.messages(connections=chosen):
            message = store.deserialize_cdr(raw, connection.msgtype)
            stamps.append(message.header.stamp.sec * 10**9 + message.header.stamp.nanosec)
            values.append(np.asarray(message.effort, dtype=float))
    return np.asarray(stamps, dtype=np.int64), np.asarray(values)


def external_relative(recording: Path, output: Path) -> tuple[np.ndarray, int]:
    """Per arm joint (the first 7), the RMS of ``output``'s external torques relative to the RMS of the
    measured torques of ``recording`` at the same stamps; and how many samples had them."""
    measured_t, measured = series(recording, "/joint_states")
    out_t, external = series(output, "external_torques")
    at = np.searchsorted(measured_t, out_t)
    ok = np.isfinite(external[:, :7]).all(axis=1)
    relative = np.sqrt(np.mean(external[ok, :7] ** 2, axis=0)) / np.sqrt(np.mean(measured[at[ok], :7] ** 2, axis=0))
    return relative, int(ok.sum())


def contacts(report: str) -> list[str]:
    return [line for line in report.splitlines() if line.startswith("contact: ")]


def panda(realdata: Path, folder: Path) -> None:
    urdf = panda_urdf()
    count = split(realdata / "panda_gaz_trajectory1", folder / "first60", folder / "last40")
    print(neforward("calibrate", str(folder / "first60"), "--urdf", str(urdf), "-o", str(folder / "panda.yaml")))
    report = neforward(
        "bag", str(folder / "last40"), "--urdf", str(urdf), "--params", str(folder / "panda.yaml"), "-o",
        str(folder / "panda_out"),
    )  # fmt: skip
    relative, written = external_relative(folder / "last40", folder / "panda_out")
    print(f"Panda: calibrate on the first 60 %, bag --params on the last 40 % ({count} messages); "
          f"{written} samples with external torques")  # fmt: skip
    print("joint            " + " ".join(f"{k:>7}" for k in range(1, 8)))
    print("external/measured" + " ".join(f"{x:7.3f}" for x in relative))
    print("Gaz et al.       " + " ".join(f"{x:7.3f}" for x in GAZ))
    print("ratio            " + " ".join(f"{x / g:7.2f}" for x, g in zip(relative, GAZ, strict=True)))
    met = all(x <= g for x, g in zip(relative, GAZ, strict=True))
    found = contacts(report)
    print(f"at most Gaz et al.'s on every joint: {'met' if met else 'NOT met'}; contacts reported: {len(found)}")


def ur10e(realdata: Path, folder: Path, gains: bool) -> None:
    urdf = realdata / "ur10e.urdf"
    extra = []
    if gains:
        for name, gain in zip(UR_JOINTS, UR_GAINS, strict=True):
            extra += ["--effort-scale", f"{name}={gain}"]
    params = folder / "ur.yaml"
    print(neforward("calibrate", *(str(realdata / r) for r in UR_CALIBRATION), "--urdf", str(urdf), "-o",
                    str(params), *extra))  # fmt: skip
    for recording in sorted(p for p in realdata.iterdir() if p.is_dir() and p.name.startswith("ur-")):
        if recording.name in UR_CALIBRATION:
            continue
        report = neforward("bag", str(recording), "--urdf", str(urdf), "--params", str(params), "-o",
                           str(folder / f"out-{recording.name}"))  # fmt: skip
        found = contacts(report)
        spans = "; ".join(line.removeprefix("contact: from ").split(" (")[0] for line in found)
        print(f"{recording.name:<28} {len(found)} contact episode(s) {spans}")


def ur10e_held_out(realdata: Path, folder: Path) -> None:
    """Calibrate on two of the three excitation runs (default options), then the third and push_pose_1."""
    urdf = realdata / "ur10e.urdf"
    for held in UR_CALIBRATION:
        params = folder / f"ur-without-{held}.yaml"
        used = [r for r in UR_CALIBRATION if r != held]
        neforward("calibrate", *(str(realdata / r) for r in used), "--urdf", str(urdf), "-o", str(params))
        for recording in (held, "ur-20_01_22-push_pose_1"):
            report = neforward("bag", str(realdata / recording), "--urdf", str(urdf), "--params", str(params), "-o",
                               str(folder / f"out-{held}-{recording}"))  # fmt: skip
            found = contacts(report)
            spans = "; ".join(line.removeprefix("contact: from ").split(" (")[0] for line in found)
            print(f"calibrated without {held:<26} {recording:<26} {len(found)} contact episode(s) {spans}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--realdata", default=str(Path(__file__).resolve().parents[2] / "shared" / "realdata"))
    parser.add_argument("--gains", action="store_true", help="give the UR10e's drive gains as effort scales")
    parser.add_argument("--only", choices=("panda", "ur10e"))
    parser.add_argument(
        "--leave-one-out", action="store_true", help="UR10e: calibrate on two excitation runs, check the third"
    )
    parser.add_argument(
        "--keep", metavar="DIR", help="write the recordings and params here (an empty folder) and keep them"
    )
    args = parser.parse_args()
    realdata = Path(args.realdata)
    if not realdata.is_dir():
        raise SystemExit(f"no {realdata}: the real recordings (see the brief) are not here")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.keep) if args.keep else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        if args.leave_one_out:
            ur10e_held_out(realdata, folder)
            return
        if args.only in (None, "panda"):
            panda(realdata, folder)
        if args.only in (None, "ur10e"):
            ur10e(realdata, folder, args.gains)


if __name__ == "__main__":
    main()
