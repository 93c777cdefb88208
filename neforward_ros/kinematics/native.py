"""The generated kernels as machine code: the same straight-line arithmetic, compiled with the system's
C compiler and called through ctypes.

The recursions are generated per model as straight-line Python (:mod:`.codegen`): on Python floats
for one sample, on numpy arrays for a batch, one vectorised operation per number. Here the same
function is translated, statement by statement and operation by operation, into C (a loop over the
samples around the straight-line body) and compiled into a shared library, kept in the disk cache
(:mod:`neforward_ros.disk_cache`, ``kernels/``) under a hash of its source: a model seen before is
loaded in a millisecond. The C keeps Python's order of operations and is compiled without
floating-point contraction (``-ffp-contract=off``) or fast-math, and sin and cos are the C
library's, as Python's are: the numbers are bitwise those of the Python kernel (tested).

Where there is no C compiler (``cc``, or ``$CC``), or ``NEFORWARD_NATIVE=off``, or the compiler
fails, every call takes the Python kernel: slower, never different. When to compile is the
kernel's call (:class:`neforward_ros.kinematics.codegen.Kernel`).
"""

from __future__ import annotations

import ast
import atexit
import ctypes
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import threading
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from neforward_ros import disk_cache

QUICK = ("-O0",)
"""Flags of the build made while a call waits: compiled in a tenth of a second for a 13-link arm."""
OPTIMIZED = ("-O1",)
"""Flags of the build made in a thread meanwhile: -O1, for these long straight-line bodies faster to
compile than -O2 and as fast to run (0.45 us against 1.1 us a sample at -O0, the 13-link arm)."""
COMMON = ("-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math")
"""No floating-point contraction and no fast-math: Python's operations, in Python's order."""

_OPERATORS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/"}
_MATH = ("sin", "cos", "copysign")


def c_source(python_source: str, name: str) -> tuple[str, tuple[str, ...], int]:
    """The C translation of a generated kernel: (source, its array inputs in order, outputs per sample).

    The Python function ``name(a, b, ..., sin, cos)`` indexes its inputs with constants
    (``q[3]``) or unpacks them (``w0x, ..., a0z = root``), assigns temporaries, and returns one tuple.
    The C function is ``void name(long count, const double *a, long a_stride, ..., double *out)``:
    for each of ``count`` samples it reads input ``a`` at ``a + sample * a_stride`` (a stride of 0
    broadcasts one row to every sample) and writes the tuple's values to ``out + sample * outputs``.
    """
    function = ast.parse(python_source).body[0]
    assert isinstance(function, ast.FunctionDef) and function.name == name
    inputs = tuple(a.arg for a in function.args.args if a.arg not in _MATH)

    def expression(node: ast.expr) -> str:
        if isinstance(node, ast.BinOp) and type(node.op) in _OPERATORS:
            return f"({expression(node.left)} {_OPERATORS[type(node.op)]} {expression(node.right)})"
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            return f"(-{expression(node.operand)})"
        if isinstance(node, ast.Name):
            return node.id
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)):
            return repr(float(node.value))
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in _MATH:
            return f"{node.func.id}({', '.join(expression(a) for a in node.args)})"
        if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Name):
            index = node.slice
            assert isinstance(index, ast.Constant) and isinstance(index.value, int)
            return f"{node.value.id}[{index.value}]"
        raise ValueError(f"cannot translate {ast.dump(node)}")

    body: list[str] = []
    outputs = 0
    for statement in function.body:
        if isinstance(statement, ast.Assign):
            target = statement.targets[0]
            if isinstance(target, ast.Tuple):  # w0x, w0y, ... = root
                assert isinstance(statement.value, ast.Name)
                body += [
                    f"    const double {element.id} = {statement.value.id}[{k}];"  # type: ignore[attr-defined]
                    for k, element in enumerate(target.elts)
                ]
            else:
                assert isinstance(target, ast.Name)
                body.append(f"    const double {target.id} = {expression(statement.value)};")
        elif isinstance(statement, ast.Return):
            assert isinstance(statement.value, ast.Tuple)
            values = statement.value.elts
            outputs = len(values)
            body += [f"    o[{k}] = {expression(value)};" for k, value in enumerate(values)]
        else:
            raise ValueError(f"cannot translate {ast.dump(statement)}")
    parameters = ", ".join(f"const double *{a}_base, long {a}_stride" for a in inputs)
    rows = "".join(f"    const double *{a} = {a}_base + s * {a}_stride;\n" for a in inputs)
    source = (
        f"#include <math.h>\n\nvoid {name}(long count, {parameters}, double *out) {{\n"
        f"  for (long s = 0; s < count; ++s) {{\n{rows}    double *o = out + s * {outputs};\n"
        + "\n".join(body)
        + "\n  }\n}\n"
    )
    return source, inputs, outputs


class NativeFunction:
    """A compiled kernel: ``function(arrays, count)`` -> (count, outputs) array.

    Each input array is (count, width) or (width,) (one row for every sample), float64; None for an
    input the kernel does not read."""

    def __init__(self, function: ctypes._CFuncPtr, inputs: tuple[str, ...], outputs: int) -> None:
        function.argtypes = [ctypes.c_long] + [ctypes.c_void_p, ctypes.c_long] * len(inputs) + [ctypes.c_void_p]
        function.restype = None
        self._function = function
        self.inputs = inputs
        self.outputs = outputs

    def __call__(self, arrays: Sequence[np.ndarray | None], count: int) -> np.ndarray:
        out = np.empty((count, self.outputs))
        arguments: list[int] = [count]
        kept = []  # the contiguous copies live until the call returns
        for array in arrays:
            if array is None:
                arguments += [0, 0]
                continue
            array = np.ascontiguousarray(array, dtype=float)
            kept.append(array)
            arguments += [array.ctypes.data, array.shape[-1] if array.ndim == 2 else 0]
        self._function(*arguments, out.ctypes.data)
        return out


def compiler() -> str | None:
    """The C compiler to use, or None (no compiler, or ``NEFORWARD_NATIVE=off``)."""
    if os.environ.get("NEFORWARD_NATIVE", "").lower() in ("0", "off", "false", "no"):
        return None
    return shutil.which(os.environ.get("CC") or "cc") or shutil.which("gcc")


class NativeKernel:
    """One generated kernel's compiled form.

    :meth:`get` gives what is ready: a library from the disk cache (the optimized build, else the
    quick one) or one built in this process. ``wait``: build the quick one now if there is nothing
    (and the optimized one in a thread meanwhile); ``start``: build in a thread, the quick one first
    if there is nothing, then the optimized one. No compiler, or a compiler that fails: None for
    good, and the Python kernel serves.
    """

    def __init__(self, python_source: str, name: str) -> None:
        self._python_source = python_source
        self._name = name
        self._lock = threading.Lock()
        self._function: NativeFunction | None = None
        self._optimized = False
        self._failed = False
        self._looked = False
        self._thread: threading.Thread | None = None
        self._translated: tuple[str, tuple[str, ...], int] | None = None

    def get(self, wait: bool = False, start: bool = False) -> NativeFunction | None:
        if self._failed or (self._optimized and self._function is not None):
            return self._function
        with self._lock:
            if self._translated is None:  # here, not in a thread: ast is not safe in two threads at once
                self._translated = c_source(self._python_source, self._name)
            if not self._looked:
                self._looked = True
                self._load()
            if self._failed:
                return None
            if wait and self._function is None:
                self._function = self._build(QUICK)
            if (wait or start) and not self._optimized and self._thread is None and not self._failed:
                self._thread = threading.Thread(target=self._build_optimized, name="neforward-compile", daemon=True)
                self._thread.start()
        return self._function

    def _path(self, source: str, cc: str, flags: tuple[str, ...]) -> Path | None:
        return cache_path(self._name, source, cc, [*flags, *COMMON])

    def _load(self) -> None:
        """Take a library built before, the optimized one first."""
        cc = compiler()
        if cc is None:
            self._failed = True
            return
        assert self._translated is not None
        source, inputs, outputs = self._translated
        for flags in (OPTIMIZED, QUICK):
            path = self._path(source, cc, flags)
            library = load_cached(path)
            if library is None:
                continue
            try:
                self._function = NativeFunction(getattr(library, self._name), inputs, outputs)
            except AttributeError:
                if path is not None:
                    path.unlink(missing_ok=True)  # a library that does not load: built anew
                continue
            self._optimized = flags == OPTIMIZED
            return

    def _build_optimized(self) -> None:
        if self._function is None:
            self._function = self._build(QUICK)
        function = self._build(OPTIMIZED)
        if function is not None:
            self._function, self._optimized = function, True

    def _build(self, flags: tuple[str, ...]) -> NativeFunction | None:
        """Compile, keep in the disk cache, load; None (and None for good) when it fails."""
        cc = compiler()
        assert self._translated is not None
        source, inputs, outputs = self._translated
        path = self._path(source, cc, flags) if cc else None
        try:
            if cc is None:
                raise OSError("no C compiler")
            library = build_library(cc, source, [*flags, *COMMON], path)
            return NativeFunction(getattr(library, self._name), inputs, outputs)
        except (OSError, subprocess.SubprocessError, ValueError, AttributeError):
            if self._function is None:
                self._failed = True
            return None


_BUILDS: set[subprocess.Popen] = set()
"""Compilers running now: stopped when the process exits (a thread's build is not waited for)."""


def cache_path(name: str, source: str, cc: str, flags: Sequence[str]) -> Path | None:
    """Where the library of ``source`` built by ``cc`` with ``flags`` is kept in the disk cache
    (``kernels/<name>-<hash>.so``); None when the cache is off."""
    folder = disk_cache.directory()
    if folder is None:
        return None
    digest = hashlib.sha256("\n".join([source, cc, *flags, sys.platform]).encode()).hexdigest()
    return folder / "kernels" / f"{name}-{digest[:32]}.so"


def load_cached(path: Path | None) -> ctypes.CDLL | None:
    """The library kept at ``path``, or None (none there; one that does not load is removed, to be
    built anew)."""
    if path is None or not path.exists():
        return None
    try:
        return ctypes.CDLL(str(path))
    except OSError:
        path.unlink(missing_ok=True)
        return None


def build_library(cc: str, source: str, flags: Sequence[str], path: Path | None) -> ctypes.CDLL:
    """Compile ``source``, load it, and keep it at ``path`` (the disk cache's, or None).

    Raises:
        OSError, subprocess.SubprocessError: the compiler did not run or failed, or the library does
            not load.
    """
    library = compile_library(cc, source, list(flags))
    try:
        loaded = ctypes.CDLL(str(library))
        if path is not None:
            keep(library, path)  # loaded already: the copy is for other processes
        return loaded
    finally:
        shutil.rmtree(library.parent, ignore_errors=True)


def keep(library: Path, path: Path) -> None:
    """Put a built library in the disk cache at ``path``: copied beside it, then renamed into place
    (the cache is often on another file system than the temporary folder, where a rename fails; a
    reader never sees half a file). No cache (unwritable): built again in another process."""
    staging = path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident()}.part")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(library, staging)
        os.replace(staging, path)
    except OSError:
        staging.unlink(missing_ok=True)


def compile_library(cc: str, source: str, flags: list[str]) -> Path:
    """Compile C ``source`` into a shared library in a fresh temporary folder (the caller moves it
    and removes the folder); stopped with the process.

    Raises:
        OSError, subprocess.SubprocessError: the compiler did not run or failed.
    """
    folder = Path(tempfile.mkdtemp(prefix="neforward-kernel-"))
    c_file, library = folder / "kernel.c", folder / "kernel.so"
    c_file.write_text(source)
    process = subprocess.Popen(
        [cc, *flags, "-o", str(library), str(c_file), "-lm"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    _BUILDS.add(process)
    try:
        _, errors = process.communicate(timeout=600)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
        raise
    finally:
        _BUILDS.discard(process)
    if process.returncode != 0:
        shutil.rmtree(folder, ignore_errors=True)
        raise subprocess.CalledProcessError(process.returncode, cc, stderr=errors)
    return library


@atexit.register
def _stop_builds() -> None:
    for process in list(_BUILDS):
        process.kill()
        process.wait()
