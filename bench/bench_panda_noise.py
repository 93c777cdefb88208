"""Where the Panda's free-motion external torque comes from: the observer's output on the last 40 % of
``panda_gaz_trajectory1`` with the params ``neforward calibrate`` fitted on the first 60 %, on the
recording as logged and on copies of it changed one way each, against the figures of Gaz et al.

- as logged: what ``bench/bench_calibration.py --only panda`` prints;
- velocities low-passed at 20 Hz, zero-phase (offline, both ways in time: a bound no causal filter
  reaches, not an option of the tool): how much of it is the recorded velocities' noise above 20 Hz;
- positions, velocities and efforts low-passed alike, causally (second-order Butterworth at 8 Hz;
  ``velocity_cutoff`` 0): the noise gone without the momentum's lag, for an output about 28 ms late;
- samples re-timed on the driver's 1 ms grid (each interval the nearest whole number of
  milliseconds to what the positions and velocities say, the repeated samples dropped): whether the
  stamps' jitter matters;
- ``-p external_torques.gain:=100.0``: the observer's bandwidth lowered (10 ms time constant).

Also printed: the intervals the data say (sum v dq / sum v^2 over the joints, while the arm moves; repeats left out)
against the stamps'.

Usage: python bench/bench_panda_noise.py [--realdata ../shared/realdata] [--keep DIR]
"""

from __future__ import annotations

import argparse
import copy
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
from bench_calibration import GAZ, external_relative, neforward, panda_urdf, split
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from scipy.signal import butter, filtfilt, lfilter

from neforward_ros.stamps import split_stamp, stamp_ns
from neforward_ros.wire.rostypes import typestore

RATE = 1000.0
"""Hz: the Panda's control rate (its samples lie on a grid of this period)."""
SPEED = 0.5
"""(rad/s)^2: the least sum of squared joint speeds at which an interval is read from the data."""


def messages(path: Path) -> tuple[object, list[tuple[int, object]]]:
    store = typestore()
    with Reader(path) as reader:
        connection = reader.connections[0]
        return connection, [(t, store.deserialize_cdr(raw, connection.msgtype)) for _, t, raw in reader.messages()]


def write(path: Path, connection, rows: list[tuple[int, object]]) -> None:
    store = typestore()
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        out = writer.add_connection(connection.topic, connection.msgtype, typestore=store)
        for t, message in rows:
            writer.write(out, t, store.serialize_cdr(message, connection.msgtype))


def filtered(fields: tuple[str, ...], cutoff: float, causal: bool) -> Callable[[list], list]:
    def change(rows: list) -> list:
        b, a = butter(2, cutoff / (RATE / 2.0), "low")
        for name in fields:
            x = np.array([getattr(m, name) for _, m in rows])
            y = lfilter(b, a, x - x[0], axis=0) + x[0] if causal else filtfilt(b, a, x, axis=0)
            for (_, m), row in zip(rows, y, strict=True):
                setattr(m, name, np.asarray(row, dtype=float))
        return rows

    return change


def intervals(rows: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per consecutive pair: the stamps' interval, the data's, and whether the arm moved enough."""
    t = np.array([stamp_ns(m.header.stamp) for _, m in rows]) / 1e9
    q = np.array([m.position for _, m in rows])
    v = np.array([m.velocity for _, m in rows])
    dq, mean_v = np.diff(q, axis=0), 0.5 * (v[1:] + v[:-1])
    speed = np.sum(mean_v**2, axis=1)
    data = np.sum(mean_v * dq, axis=1) / np.maximum(speed, 1e-12)
    return np.diff(t), data, (speed > SPEED) & np.any(dq != 0.0, axis=1)


def retimed(rows: list) -> list:
    stamps, data, moving = intervals(rows)
    period = 1.0 / RATE
    out, now = [rows[0]], stamp_ns(rows[0][1].header.stamp)
    for k in range(1, len(rows)):
        if np.array_equal(rows[k][1].position, rows[k - 1][1].position):
            continue  # a repeat: the same sample again
        step = max(1, round(data[k - 1] / period)) * period if moving[k - 1] else stamps[k - 1]
        now += round(step * 1e9)
        message = rows[k][1]
        message.header.stamp.sec, message.header.stamp.nanosec = split_stamp(now)
        out.append((now, message))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--realdata", default=str(Path(__file__).resolve().parents[2] / "shared" / "realdata"))
    parser.add_argument("--keep", metavar="DIR", help="write the recordings and params here and keep them")
    args = parser.parse_args()
    realdata = Path(args.realdata)
    if not realdata.is_dir():
        raise SystemExit(f"no {realdata}: the real recordings (see the brief) are not here")
    urdf = panda_urdf()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.keep) if args.keep else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        params = folder / "panda.yaml"
        if not params.exists():
            split(realdata / "panda_gaz_trajectory1", folder / "first60", folder / "last40")
            neforward("calibrate", str(folder / "first60"), "--urdf", str(urdf), "-o", str(params))
        connection, rows = messages(folder / "last40")
        stamps, data, moving = intervals(rows)
        print(f"intervals while moving ({moving.sum()} of {len(stamps)}): stamps' 1/50/99th percentile "
              + " ".join(f"{x * 1e3:.2f}" for x in np.percentile(stamps[moving], (1, 50, 99)))
              + " ms; the data's within 0.05 ms of a whole ms: "
              + f"{np.mean(np.abs(data[moving] * 1e3 - np.round(data[moving] * 1e3)) < 0.05):.1%}")  # fmt: skip
        variants: list[tuple[str, Callable[[list], list] | None, tuple[str, ...]]] = [
            ("as logged", None, ()),
            ("velocities zero-phase 20 Hz", filtered(("velocity",), 20.0, causal=False), ()),
            ("all inputs causal 8 Hz", filtered(("position", "velocity", "effort"), 8.0, causal=True),
             ("-p", "external_torques.velocity_cutoff:=0.0")),
            ("re-timed on the 1 ms grid", retimed, ()),
            ("gain 100 /s", None, ("-p", "external_torques.gain:=100.0")),
        ]  # fmt: skip
        print(f"{'':30}" + " ".join(f"{k:>6}" for k in range(1, 8)) + "   worst ratio to Gaz et al.")
        for k, (label, change, extra) in enumerate(variants):
            recording = folder / "last40"
            if change is not None:
                recording = folder / f"variant{k}"
                if not recording.exists():
                    write(recording, connection, change(copy.deepcopy(rows)))
            output = folder / f"out{k}"
            if not output.exists():
                neforward("bag", str(recording), "--urdf", str(urdf), "--params", str(params), "-o", str(output),
                          *extra)  # fmt: skip
            found, _ = external_relative(recording, output)
            worst = max(x / g for x, g in zip(found, GAZ, strict=True))
            print(f"{label:30}" + " ".join(f"{x:6.3f}" for x in found) + f"   {worst:.2f}")
        print(f"{'Gaz et al.':30}" + " ".join(f"{x:6.3f}" for x in GAZ))


if __name__ == "__main__":
    main()
