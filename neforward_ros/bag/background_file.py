"""A file written by a thread of its own: the bag tool's output recording, so that the copying of
gigabytes into the file system overlaps the computing of the next chunk (a write releases the GIL).

The writes happen in the order they were asked for; :meth:`BackgroundFile.tell` is the position the
file will have once they are done, so the MCAP writer's offsets are right. An error of the thread
(a full disk) is raised by the next call that writes, tells or closes.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import queue
import threading
from typing import BinaryIO

IN_FLIGHT = 64
"""Writes waiting at most (the bag tool's are chunks of about 1 MB): bounded memory."""


class BackgroundFile:
    """``write``, ``tell`` and ``close`` of the binary file ``file``, the writes done by a thread.

    Args:
        file: a binary file open for writing, at the position where writing goes on; closed by
            :meth:`close`.
    """

    def __init__(self, file: BinaryIO) -> None:
        self._file = file
        self._position = file.tell()
        self._queue: queue.Queue[bytes | memoryview | tuple[int, int] | None] = queue.Queue(IN_FLIGHT)
        self._error: BaseException | None = None
        self._reserved = False
        self._thread: threading.Thread | None = threading.Thread(
            target=self._run, name="neforward-bag-write", daemon=True
        )
        self._thread.start()

    def _run(self) -> None:
        while True:
            data = self._queue.get()
            try:
                if data is None:
                    return
                if isinstance(data, tuple):
                    self._allocate(*data)
                elif self._error is None:
                    self._file.write(data)
            except BaseException as exc:  # kept for the caller's next call; the queue keeps draining
                self._error = exc
            finally:
                self._queue.task_done()

    def _allocate(self, offset: int, size: int) -> None:
        try:
            self._file.flush()
            _fallocate(self._file.fileno(), offset, size)
        except (OSError, AttributeError, ValueError):
            pass  # a file system that cannot, or no room: the writes find out

    def reserve(self, size: int) -> None:
        """Have the thread allocate the next ``size`` bytes of the file ahead of the writes (on a
        tmpfs, the memory: the writes then only copy); what is not written by :meth:`close` is cut
        off again. Only a hint: a file system that cannot allocate ahead is written as usual."""
        if size > 0 and self._thread is not None:
            self._reserved = True
            self._queue.put((self._position, size))

    def _raise(self) -> None:
        if self._error is not None:
            raise self._error

    def write(self, data: bytes | bytearray | memoryview) -> int:
        """Write ``data`` (copied unless it is bytes: the caller may change it afterwards)."""
        return self.hand_over(data if isinstance(data, bytes) else bytes(data))

    def hand_over(self, data: bytes | memoryview) -> int:
        """Write ``data`` without copying it: the caller does not change it afterwards."""
        self._raise()
        if self._thread is None:
            raise ValueError("write to a closed file")
        size = len(data) if isinstance(data, bytes) else data.nbytes
        self._queue.put(data)
        self._position += size
        return size

    def tell(self) -> int:
        """The file's position once every write asked for is done."""
        self._raise()
        return self._position

    def flush(self) -> None:
        """Wait for every write asked for; then flush the file."""
        self._queue.join()
        self._raise()
        self._file.flush()

    def _wait(self) -> None:
        if self._thread is None:
            return
        self._queue.put(None)
        self._thread.join()
        self._thread = None

    def close(self) -> None:
        """Wait for every write, then close the file (also after an error, which is then raised)."""
        try:
            self._wait()
            if self._reserved and self._error is None:
                self._file.truncate(self._position)
        finally:
            self._file.close()
        self._raise()

    @property
    def closed(self) -> bool:
        return self._file.closed


def _fallocate(descriptor: int, offset: int, size: int) -> None:
    """Linux's fallocate(2), which fails where the file system cannot allocate ahead (glibc's
    posix_fallocate would then write every block instead: on a network file system, the whole size).

    Raises:
        OSError: not allocated (no such call here, a file system that cannot, no room).
    """
    libc = _libc()
    function = getattr(libc, "fallocate64", None) or getattr(libc, "fallocate", None)
    if function is None:
        raise OSError("no fallocate on this system")
    function.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int64, ctypes.c_int64]
    function.restype = ctypes.c_int
    if function(descriptor, 0, offset, size) != 0:
        number = ctypes.get_errno()
        raise OSError(number, os.strerror(number))


def _libc() -> ctypes.CDLL:
    return ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
