"""The disk cache of built models (neforward_ros.model.stored): a description seen before gives the
model built from it, without yourdfpy; any change of the description or the root link builds anew."""

from __future__ import annotations

import logging
import os
import subprocess
import sys

import pytest

from neforward_ros import load_model
from neforward_ros.model.stored import stored_model

from conftest import CONFIG_DIR, TEST_ROBOTS

pytestmark = pytest.mark.model_cache

URDFS = sorted(set(TEST_ROBOTS.values()) | set(CONFIG_DIR.glob("*.urdf")))


@pytest.fixture(autouse=True)
def own_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("NEFORWARD_CACHE", str(tmp_path / "cache"))


@pytest.mark.parametrize("path", URDFS, ids=lambda p: p.name)
def test_a_kept_model_equals_the_model_read(path) -> None:
    data = path.read_bytes()
    assert stored_model(data, None) is None
    built = load_model(path)
    kept = stored_model(data, None)
    assert kept is not None and kept == built
    assert dict(kept.link_index) == dict(built.link_index) and kept.parent_joints == built.parent_joints
    assert load_model(path) == built  # from the cache now
    assert load_model(data.decode()) == built  # the same text as a robot_description


def test_the_root_link_and_every_byte_are_part_of_the_key() -> None:
    path = TEST_ROBOTS["panda"]
    whole = load_model(path)
    sub = load_model(path, root_link="panda_link3")
    assert sub.root_link == "panda_link3" and len(sub.link_names) < len(whole.link_names)
    assert load_model(path, root_link="panda_link3") == sub and load_model(path) == whole
    text = path.read_text().replace('<mass value="', '<mass value="1', 1)
    assert load_model(text).mass != whole.mass


def test_the_warnings_of_a_kept_model_are_said_again(caplog) -> None:
    text = (CONFIG_DIR / "panda.urdf").read_text().replace('type="revolute"', 'type="planar"', 1)
    caplog.set_level(logging.WARNING, logger="neforward_ros")
    first = load_model(text)
    said = [r.getMessage() for r in caplog.records]
    caplog.clear()
    assert load_model(text) == first and first.warnings
    assert [r.getMessage() for r in caplog.records] == said


def test_a_kept_model_loads_without_yourdfpy(tmp_path) -> None:
    code = (
        "import sys; from neforward_ros import load_model; "
        f"load_model({str(TEST_ROBOTS['panda'])!r}); print('yourdfpy' in sys.modules, 'trimesh' in sys.modules)"
    )
    environment = {**os.environ, "NEFORWARD_CACHE": str(tmp_path / "fresh")}
    runs = [
        subprocess.run([sys.executable, "-c", code], env=environment, capture_output=True, text=True, timeout=60)
        for _ in range(2)
    ]
    assert [run.stdout.split() for run in runs] == [["True", "True"], ["False", "False"]], runs[-1].stderr


def test_a_damaged_entry_is_read_anew(tmp_path) -> None:
    path = TEST_ROBOTS["panda"]
    built = load_model(path)
    for entry in (tmp_path / "cache" / "models").iterdir():
        entry.write_text('{"format": 4, "value": {"name": 3}}')
    assert stored_model(path.read_bytes(), None) is None
    assert load_model(path) == built
