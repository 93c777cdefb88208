"""``neforward bag`` on many recordings: a folder, several cores, one summary, resumable; and the same
per-recording task on a Dask cluster (a LocalCluster)."""

from __future__ import annotations

import shutil

import pytest
from test_bag import read_output, record

from neforward_ros.bag import BagOptions, process_bag
from neforward_ros.bag.fleet import plan, recordings, run_job
from neforward_ros.cli import main


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fleet") / "recordings"
    folder.mkdir()
    for k in range(4):
        record(folder / f"run{k}", seconds=0.6 + 0.1 * k)
    broken = folder / "broken"
    record(broken, seconds=1.0)
    storage = next(broken.glob("*.mcap"))
    storage.write_bytes(storage.read_bytes()[:2000])
    (folder / "notes.txt").write_text("not a recording: ignored")
    return folder


def test_a_folder_of_recordings_on_two_cores_then_resumed(fleet, tmp_path, capsys) -> None:
    out = tmp_path / "out"
    assert main(["bag", str(fleet), "-o", str(out), "--csv", "--jobs", "2"]) == 1  # one recording is broken
    captured = capsys.readouterr()
    assert captured.out.startswith("5 recordings in ") and "4 done" in captured.out and "1 failed" in captured.out
    assert "failed: " in captured.out and "broken" in captured.out and "truncated or corrupt" in captured.out
    assert captured.err.count("\n") == 5  # one line per recording as it finishes
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted([f"run{k}" for k in range(4)] + [f"run{k}.csv" for k in range(4)])
    # each output is what the single-recording tool writes
    process_bag(fleet / "run2", tmp_path / "single", BagOptions(), csv_path=tmp_path / "single.csv")
    assert read_output(out / "run2") == read_output(tmp_path / "single")
    assert (out / "run2.csv").read_text() == (tmp_path / "single.csv").read_text()
    # resumed: the done ones are skipped, a removed one is redone
    shutil.rmtree(out / "run1")
    (out / "run1.csv").unlink()
    assert main(["bag", str(fleet), "-o", str(out), "--csv", "--jobs", "2"]) == 1
    captured = capsys.readouterr()
    assert "1 done" in captured.out and "3 skipped" in captured.out and "1 failed" in captured.out
    assert (out / "run1").exists()
    # a list of recordings works too, and --csv with a path is refused for many
    assert main(["bag", str(fleet / "run0"), str(fleet / "run3"), "-o", str(tmp_path / "two")]) == 0
    assert sorted(p.name for p in (tmp_path / "two").iterdir()) == ["run0", "run3"]
    assert main(["bag", str(fleet), "-o", str(tmp_path / "x"), "--csv", "a.csv"]) == 1
    assert "take no path" in capsys.readouterr().err


def test_the_per_recording_task_on_a_dask_cluster(fleet, tmp_path) -> None:
    pytest.importorskip("distributed", reason="pip install 'dask[distributed]' (a test extra)")
    from distributed import Client, LocalCluster

    jobs = plan(recordings([fleet]), tmp_path, csv=True)
    options = BagOptions()
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        with Client(cluster) as client:
            outcomes = client.gather(client.map(run_job, jobs, options=options))
    assert sorted(o.status for o in outcomes) == ["done"] * 4 + ["failed"]
    done = {o.job.input.name: o for o in outcomes if o.status == "done"}
    assert read_output(tmp_path / "run0") and done["run0"].samples > 0
    # run again on the cluster's results: everything complete is skipped
    assert run_job(jobs[[j.input.name for j in jobs].index("run0")], options).status == "skipped"
