"""The bag tool's output file written by a thread of its own (neforward_ros/bag/background_file.py)."""

from __future__ import annotations

import io

import pytest

from neforward_ros.bag.background_file import BackgroundFile, _fallocate


def test_writes_land_in_order_and_tell_counts_them_before_they_are_done(tmp_path) -> None:
    path = tmp_path / "out.bin"
    raw = path.open("wb")
    raw.write(b"head")
    file = BackgroundFile(raw)
    assert file.tell() == 4
    expected = b"head"
    for k in range(200):
        data = bytes([k % 256]) * (k * 997 % 5000 + 1)
        buffer = bytearray(data)
        file.write(buffer)
        buffer[:] = b"\0" * len(buffer)  # changed after the call: the write took a copy
        expected += data
        assert file.tell() == len(expected)
    view = memoryview(b"handed over")
    file.hand_over(view)
    expected += b"handed over"
    file.flush()
    assert path.read_bytes() == expected
    file.write(b"!")
    file.close()
    assert path.read_bytes() == expected + b"!"
    assert file.closed
    with pytest.raises(ValueError):
        file.write(b"late")


def test_room_reserved_ahead_is_cut_back_to_what_was_written(tmp_path) -> None:
    path = tmp_path / "out.bin"
    with (tmp_path / "probe").open("wb") as probe:
        try:
            _fallocate(probe.fileno(), 0, 4096)
        except OSError as exc:
            pytest.skip(f"the file system of {tmp_path} does not allocate ahead ({exc}): nothing to cut back")
    file = BackgroundFile(path.open("wb"))
    file.write(b"a" * 10)
    file.reserve(1 << 20)
    file.write(b"b" * 5)
    file.flush()
    assert path.stat().st_size >= 1 << 20  # allocated ahead (fallocate extends the file)
    file.close()
    assert path.read_bytes() == b"a" * 10 + b"b" * 5


class _Full(io.BytesIO):
    def write(self, data) -> int:  # a disk that fills after 100 bytes
        if self.tell() + len(data) > 100:
            raise OSError(28, "No space left on device")
        return super().write(data)


def test_an_error_of_the_thread_is_raised_by_a_later_call_and_by_close() -> None:
    file = BackgroundFile(_Full())
    file.write(b"x" * 60)
    file.write(b"y" * 60)  # fails in the thread
    with pytest.raises(OSError, match="No space"):
        for _ in range(100):  # raised by one of the next calls once the thread has failed
            file.flush()
            file.write(b"z")
    with pytest.raises(OSError, match="No space"):
        file.close()
