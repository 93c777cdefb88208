"""Straight-line Python generated per model: the tools the recursion kernels are written with.

:class:`Emitter` writes assignments with the model's constants folded in (a term with a zero factor
is dropped, a unit factor left out, constant terms summed at generation). :func:`finish` removes
what no output uses and inlines single-use temporaries; :func:`compile_function` and
:class:`PerModel` compile a source once per model. The generated code runs on Python floats (one
sample, no numpy call) and on numpy arrays of shape (T,) (T samples at once) alike.
"""

from __future__ import annotations

import re
import weakref
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from neforward_ros.kinematics.native import NativeFunction, NativeKernel

Value = float | str
"""A constant (folded at generation) or the name of a variable of the generated code."""


@dataclass
class Emitter:
    """Writes assignments, folding constants: a term with a zero factor is dropped, a unit factor is
    left out, constant terms are summed at generation."""

    lines: list[str]
    count: int = 0

    def temp(self, expression: str) -> str:
        self.count += 1
        name = f"t{self.count}"
        self.lines.append(f"    {name} = {expression}")
        return name

    def combine(self, terms: Sequence[tuple[Value, Value]], constant: float = 0.0) -> Value:
        """sum(a * b for a, b in terms) + constant, as a constant, an existing name or a new temporary."""
        parts: list[tuple[float, str]] = []  # (coefficient, product of names)
        for a, b in terms:
            coefficient = 1.0
            names = []
            for factor in (a, b):
                if isinstance(factor, str):
                    names.append(factor)
                else:
                    coefficient *= factor
            if coefficient == 0.0:
                continue
            if not names:
                constant += coefficient
                continue
            parts.append((coefficient, "*".join(names)))
        if not parts:
            return constant
        if len(parts) == 1 and parts[0][0] == 1.0 and constant == 0.0 and "*" not in parts[0][1]:
            return parts[0][1]
        text = ""
        for coefficient, names in parts:
            sign = "-" if coefficient < 0 else "+"
            magnitude = abs(coefficient)
            term = names if magnitude == 1.0 else f"{magnitude!r}*{names}"
            text = f"{'-' if sign == '-' else ''}{term}" if not text else f"{text} {sign} {term}"
        if constant != 0.0:
            text = f"{text} {'-' if constant < 0 else '+'} {abs(constant)!r}"
        return self.temp(text)

    def add(self, *values: Value) -> Value:
        return self.combine([(1.0, v) for v in values])

    def cross(self, a: Sequence[Value], b: Sequence[Value]) -> tuple[Value, ...]:
        return tuple(
            self.combine([(1.0, mul(a[j], b[k])), (-1.0, mul(a[k], b[j]))]) for j, k in ((1, 2), (2, 0), (0, 1))
        )


def mul(a: Value, b: Value) -> Value:
    """A factor a * b: constants folded, names joined."""
    if not isinstance(a, str) and not isinstance(b, str):
        return a * b
    if not isinstance(a, str):
        return a if a == 0.0 else (b if a == 1.0 else f"{a!r}*{b}")
    if not isinstance(b, str):
        return b if b == 0.0 else (a if b == 1.0 else f"{b!r}*{a}")
    return f"{a}*{b}"


def mat_vec(em: Emitter, m: Sequence[Value], x: Sequence[Value], transpose: bool = False):
    """m @ x (or m.T @ x) for a row-major 3x3 m."""
    out = []
    for i in range(3):
        row = [(m[3 * k + i] if transpose else m[3 * i + k], x[k]) for k in range(3)]
        out.append(em.combine([(1.0, mul(a, b)) for a, b in row]))
    return tuple(out)


def mat_mat(em: Emitter, a: Sequence[Value], b: Sequence[Value]) -> tuple[Value, ...]:
    return tuple(
        em.combine([(1.0, mul(a[3 * i + k], b[3 * k + j])) for k in range(3)]) for i in range(3) for j in range(3)
    )


_TEMP = re.compile(r"\bt\d+\b")
_MAX_INLINED = 400  # characters: keeps expressions far from the parser's nesting limits


def _inline_single_uses(lines: list[str]) -> list[str]:
    """Substitute each temporary used exactly once into its use, and drop the unused ones: fewer
    stores and loads of locals, which is most of what straight-line Python spends its time on."""
    uses: dict[str, int] = {}
    for line in lines:
        right = line.split(" = ", 1)[1] if _TEMP.match(line.strip()) else line
        for name in _TEMP.findall(right):
            uses[name] = uses.get(name, 0) + 1
    pending: dict[str, str] = {}

    def substitute(match: re.Match) -> str:
        name = match.group(0)
        return f"({pending.pop(name)})" if name in pending else name

    out = []
    for line in lines:
        stripped = line.strip()
        if _TEMP.match(stripped) and " = " in stripped:
            name, expression = stripped.split(" = ", 1)
            expression = _TEMP.sub(substitute, expression)
            count = uses.get(name, 0)
            if count == 0:
                continue
            if count == 1 and len(expression) <= _MAX_INLINED:
                pending[name] = expression
                continue
            out.append(f"    {name} = {expression}")
        else:
            out.append(_TEMP.sub(substitute, line))
    return out


def _drop_unused(lines: list[str]) -> list[str]:
    """Remove the assignments of temporaries that nothing kept uses, up the chain (liveness, backwards
    from the lines that are not temporaries' assignments)."""
    live: set[str] = set()
    kept: list[str] = []
    for line in reversed(lines):
        stripped = line.strip()
        if _TEMP.match(stripped) and " = " in stripped:
            name, expression = stripped.split(" = ", 1)
            if name not in live:
                continue
            live.update(_TEMP.findall(expression))
        else:
            live.update(_TEMP.findall(line))
        kept.append(line)
    return kept[::-1]


def finish(lines: list[str]) -> list[str]:
    """The body to write out: unused temporaries removed, single-use ones inlined."""
    return _inline_single_uses(_drop_unused(lines))


def compile_function(source: str, name: str, label: str) -> Callable[..., Any]:
    """The function ``name`` defined by ``source``."""
    namespace: dict[str, Any] = {}
    exec(compile(source, f"<neforward {label}>", "exec"), namespace)
    return namespace[name]


class Kernel:
    """A generated kernel: its Python function (on floats, or on numpy arrays) and its compiled form
    (:mod:`.native`), which gives the same numbers faster where a C compiler is at hand.

    When to compile, as one rents skis: the Python function serves until the time spent in it
    reaches what a quick build would cost (a tenth of a second for a 13-link arm, scaled by the
    source's length); then the quick build is made while that call waits, and an optimized one in a
    thread. A library built before (the disk cache) is taken on first use. A long-running caller
    (the node) asks for the optimized build at once (:meth:`NativeKernel.get` with ``start``).
    """

    QUICK_SECONDS_PER_BYTE = 3e-6
    """Seconds a quick build takes per byte of Python source (the arm's forward kernel: 30 kB, 0.09 s)."""

    def __init__(self, source: str, name: str, label: str) -> None:
        self.source = source
        self.python = compile_function(source, name, label)
        self.native = NativeKernel(source, name)
        self._slow_seconds = 0.0
        self._rent = self.QUICK_SECONDS_PER_BYTE * len(source)

    def compiled(self) -> NativeFunction | None:
        """The compiled kernel when it is ready (or, the Python function having cost as much as a
        build, once it is built); else None, and the caller runs :attr:`python`, telling the time it
        took to :meth:`spent`."""
        return self.native.get(wait=self._slow_seconds >= self._rent)

    def spent(self, seconds: float) -> None:
        """Time spent in the Python function."""
        self._slow_seconds += seconds


class PerModel:
    """Kernels generated from a model, each made on first use and kept as long as the model lives."""

    def __init__(self, make: Callable[..., Callable[..., Any]]) -> None:
        self._make = make
        self._made: dict[tuple[int, Any], Callable[..., Any]] = {}

    def __call__(self, model: Any, variant: Any = None) -> Callable[..., Any]:
        key = (id(model), variant)
        found = self._made.get(key)
        if found is None:
            found = self._make(model) if variant is None else self._make(model, variant)
            if not any(k[0] == id(model) for k in self._made):
                weakref.finalize(model, self._forget, id(model))
            self._made[key] = found
        return found

    def _forget(self, model_id: int) -> None:
        for key in [k for k in self._made if k[0] == model_id]:
            del self._made[key]
