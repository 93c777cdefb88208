"""Plot the true external torques of a simulated recording against what ``neforward bag`` estimated.

Usage: python examples/contact_plot.py RECORDING OUTPUT_RECORDING -o PNG

RECORDING is ``arm_simulator.py``'s (its RECORDING.truth.npz holds the truth); OUTPUT_RECORDING is
``neforward bag``'s on it (with ``publish_torques``, as the calibration's params file sets). The four
joints with the largest true external torques get a panel each: the truth, the estimate, the
pushes' intervals shaded and ~/contact's intervals marked.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from rosbags.rosbag2 import Reader

    from neforward_ros.stamps import stamp_ns
    from neforward_ros.wire.rostypes import deserialize

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("output", type=Path)
    parser.add_argument("-o", "--png", type=Path, required=True)
    args = parser.parse_args()
    truth = np.load(args.recording.with_name(args.recording.name + ".truth.npz"))
    names = [str(n) for n in truth["names"]]
    estimated: dict[int, np.ndarray] = {}
    contact: list[tuple[int, bool]] = []
    with Reader(args.output) as reader:
        for connection, log_time, raw in reader.messages():
            if connection.topic == "/neforward/external_torques":
                message = deserialize(connection.msgtype, raw)
                estimated[stamp_ns(message["header"]["stamp"])] = dict(
                    zip(message["name"], message["effort"], strict=True)
                )
            elif connection.topic == "/neforward/contact":
                contact.append((log_time, bool(deserialize(connection.msgtype, raw)["data"])))
    origin = int(truth["stamps"][0])
    t = (truth["stamps"] - origin) / 1e9
    largest = np.argsort(-np.abs(truth["external"]).max(axis=0))[:4]
    figure, axes = plt.subplots(len(largest), 1, sharex=True, figsize=(10, 2.2 * len(largest)))
    for axis, j in zip(np.atleast_1d(axes), sorted(largest), strict=True):
        name = names[j]
        estimate = np.array([estimated.get(int(s), {}).get(name, np.nan) for s in truth["stamps"]])
        for start, end in truth["intervals"]:
            axis.axvspan((start - origin) / 1e9, (end - origin) / 1e9, color="0.9", lw=0)
        axis.plot(t, truth["external"][:, j], color="black", lw=1.5, label="true Jᵀw")
        axis.plot(t, estimate, color="tab:red", lw=0.8, label="~/external_torques")
        axis.set_ylabel(f"{name}\n[N m]")
        on = None
        for log_time, state in contact:
            if state and on is None:
                on = log_time
            elif not state and on is not None:
                axis.axvspan(
                    (on - origin) / 1e9, (log_time - origin) / 1e9, ymin=0.93, ymax=1.0, color="tab:blue", lw=0
                )
                on = None
    first = np.atleast_1d(axes)[0]
    first.legend(loc="upper right", fontsize=8, ncol=2)
    first.set_title("external torques: truth (Pinocchio simulation) and estimate; grey: pushes, blue bar: ~/contact")
    np.atleast_1d(axes)[-1].set_xlabel("t [s]")
    figure.tight_layout()
    figure.savefig(args.png, dpi=100)
    print(f"wrote {args.png}")


if __name__ == "__main__":
    main()
