"""Ctrl-C: SIGINT sent to ``neforward bag`` and ``neforward run`` subprocesses at many points, from the
interpreter's start-up and the imports to the last stage. Each stops with one line and no traceback;
``bag`` leaves no output and no partial file behind, and running it again works.

The points are found by what the process says, not by how long it took before: ``bag`` runs with its
standard error on a terminal (a pseudo-terminal here), so that it draws its progress, and SIGINT
goes when a stage starts; ``run`` gets it when its start-up line is out. The early points (imports,
model loading) are short delays after the start: whatever each lands on, the outcome must be one of
the allowed ones. One of them is Python's own: a signal while the interpreter itself starts (its
``site`` module, before any of the package's code runs) ends it with "Fatal Python error:
init_import_site" and exit code 1; nothing of ours can run earlier. The subprocesses start with
SIGINT at its default whatever the suite inherited (a background job of a non-interactive shell
ignores it, and so would they). The only time bounds are generous timeouts; how fast Ctrl-C takes
effect is measured by ``bench/bench_interrupts.py``. Ctrl-C met in a finalizer and on a fleet of
recordings is sent by the process itself, from a script that wraps the command's functions, at the
moment each test names.
"""

from __future__ import annotations

import os
import pty
import re
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_bag import record

from conftest import CONFIG_DIR, require

STAGES = ("reading", "estimating", "computing", "plotting", "finishing")
EARLY = (0.0, 0.05, 0.15, 0.3)  # s after the start: the interpreter, the imports, the model
TIMEOUT = 120.0


def command(*arguments: str) -> list[str]:
    return [sys.executable, "-m", "neforward_ros", *arguments]


def default_sigint() -> None:
    """In the child, before it runs Python: SIGINT as a terminal's Ctrl-C would find it."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class Interrupted:
    """A subprocess whose standard error is a pseudo-terminal, read as it comes."""

    def __init__(self, arguments: list[str], cwd: Path, env: dict[str, str] | None = None) -> None:
        self.master, slave = pty.openpty()
        self.process = subprocess.Popen(
            arguments, cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=slave,
            preexec_fn=default_sigint,
        )  # fmt: skip
        os.close(slave)
        self.output = ""

    def read(self, timeout: float) -> bool:
        """Read what is there within ``timeout``; False once the pseudo-terminal is closed."""
        ready, _, _ = select.select([self.master], [], [], timeout)
        if not ready:
            return True
        try:
            data = os.read(self.master, 65536)
        except OSError:  # the child closed its side
            return False
        self.output += data.decode(errors="replace").replace("\r\n", "\n")
        return bool(data)

    def wait_for(self, text: str) -> bool:
        """Until ``text`` appears (True) or the process ends without it (False)."""
        deadline = time.monotonic() + TIMEOUT
        while text not in self.output:
            if time.monotonic() > deadline:
                self.process.kill()
                pytest.fail(f"{text!r} never came:\n{self.output}")
            if not self.read(0.05) and self.process.poll() is not None:
                return text in self.output
        return True

    def interrupt_and_wait(self) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        try:
            self.process.wait(timeout=TIMEOUT)
        except subprocess.TimeoutExpired:
            self.process.kill()
            pytest.fail(f"SIGINT swallowed: still running {TIMEOUT:g} s later:\n{self.output}")
        while self.read(0.05):
            pass
        os.close(self.master)
        return self.process.returncode

    def last_line(self) -> str:
        lines = [line.split("\r")[-1] for line in self.output.strip().split("\n")]
        return lines[-1] if lines else ""


@pytest.fixture(scope="module")
def long_recording(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("interrupts") / "rec"
    record(path, seconds=16.0)
    return path


OUTPUTS = ["out", "out.csv", "out.png"]


BEFORE_HANDLER = ("neforward_ros/__init__.py", "neforward_ros/__main__.py", "neforward_ros/command.py")
"""The package's files that run before its SIGINT handler is in (neforward_ros.command puts it in)."""


def before_handler(output: str) -> bool:
    """Whether every frame of the package in a traceback is one that runs before its handler is in."""
    frames = re.findall(r'File "([^"]*neforward_ros/[^"]*)"', output)
    return all(frame.endswith(BEFORE_HANDLER) for frame in frames) and "interrupted_early" not in output


def interpreter_start(code: int, output: str) -> bool:
    """Whether the signal ended the interpreter's own start-up, before the package's handler was in
    (silently, in site's imports, as the interpreter imports runpy itself: "Could not import runpy module",
    exit status 1, seen once in CI with every core busy, or with Python's own KeyboardInterrupt while runpy
    looks for the module or the package's first lines import what installs the handler)."""
    before_package = "neforward_ros/" not in output
    return (
        (code == -signal.SIGINT and output.strip() == "")
        or (code == 1 and "Fatal Python error: init_import_site" in output and before_package)
        or (code in (1, -signal.SIGINT) and "Could not import runpy module" in output and before_package)
        or (code in (1, -signal.SIGINT) and "KeyboardInterrupt" in output and "<frozen runpy>" in output
            and before_handler(output))
    )  # fmt: skip


def check_bag_outcome(run: Interrupted, folder: Path, arguments: list[str], where: str) -> bool:
    """The outcome of an interrupted bag run is allowed (True: it was interrupted)."""
    code = run.interrupt_and_wait()
    if code == 0:  # finished before the signal: everything is there
        assert "Traceback" not in run.output, (where, run.output)
        assert sorted(p.name for p in folder.iterdir()) == OUTPUTS, where
        return False
    if not interpreter_start(code, run.output):
        assert "Traceback" not in run.output, (where, run.output)
        assert code == 130 and run.last_line() == "neforward: interrupted", (where, code, run.output)
    assert list(folder.iterdir()) == [], (where, list(folder.iterdir()))  # no output, no partial file
    done = subprocess.run(arguments, cwd=folder, capture_output=True, text=True, timeout=300)  # a rerun works
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in folder.iterdir()) == OUTPUTS
    return True


def test_ctrl_c_in_bag_leaves_nothing_and_a_rerun_works(long_recording, tmp_path) -> None:
    arguments = command("bag", str(long_recording), "-o", "out", "--csv", "--plot", "--torques")
    for stage in STAGES:  # the start of each stage, as its progress bar shows it
        folder = tmp_path / stage
        folder.mkdir()
        run = Interrupted(arguments, folder)
        assert run.wait_for(stage), f"the run ended before {stage}:\n{run.output}"
        interrupted = check_bag_outcome(run, folder, arguments, stage)
        # the last stage is short: the run may be done before the signal (then it says so with 0)
        assert interrupted or stage == "finishing", f"{stage}: the whole run finished before the signal"
    for delay in EARLY:
        folder = tmp_path / f"early{delay}"
        folder.mkdir()
        run = Interrupted(arguments, folder)
        time.sleep(delay)
        check_bag_outcome(run, folder, arguments, f"{delay} s")


def test_ctrl_c_in_run_stops_it_at_any_moment(tmp_path) -> None:
    require("cyclonedds")
    env = {**os.environ, "ROS_DOMAIN_ID": str(100 + os.getpid() % 100)}
    arguments = command("run", "--urdf", str(CONFIG_DIR / "panda.urdf"))
    for delay in (*EARLY, None):  # None: once the node is up
        run = Interrupted(arguments, tmp_path, env)
        if delay is None:
            assert run.wait_for("on DDS domain"), run.output
        else:
            time.sleep(delay)
        code = run.interrupt_and_wait()
        # stopped while the interpreter started, before the node existed (130, one line), or the node
        # stopped cleanly (0, its last log line)
        if not interpreter_start(code, run.output):
            assert "Traceback" not in run.output, (delay, run.output)
            assert (code == 130 and run.last_line() == "neforward: interrupted") or (
                code == 0 and "stopped:" in run.last_line()
            ), (delay, code, run.output)
        if delay is None:
            assert code == 0


SEEN_AT_START = """Traceback (most recent call last):
  File "<frozen runpy>", line 198, in _run_module_as_main
  File "<frozen runpy>", line 88, in _run_code
  File "/work/main/neforward_ros/__main__.py", line 3, in <module>
    from neforward_ros.command import entry
  File "/work/main/neforward_ros/command.py", line 10, in <module>
    import signal
  File "/usr/lib/python3.11/signal.py", line 10, in <lambda>
    name.isupper()
KeyboardInterrupt
"""

SEEN_IMPORTING_RUNPY = """Could not import runpy module
Traceback (most recent call last):
  File "<frozen importlib._bootstrap>", line 1165, in _find_and_load
KeyboardInterrupt
"""


def test_only_a_traceback_before_the_handler_counts_as_the_interpreters() -> None:
    """Python's KeyboardInterrupt while the package's first lines run (seen in CI, 2026-11-26) is the
    interpreter's start; one from any later module of the package is a failure of ours."""
    assert interpreter_start(1, SEEN_AT_START)
    later = SEEN_AT_START.replace("neforward_ros/command.py", "neforward_ros/cli.py")
    assert not interpreter_start(1, later)
    handler = SEEN_AT_START.replace("line 10, in <module>", "line 16, in interrupted_early")
    assert not interpreter_start(1, handler)
    runpy = SEEN_IMPORTING_RUNPY
    assert interpreter_start(1, runpy)  # (CI, 2026-11-29: the signal as the interpreter imported runpy)
    assert not interpreter_start(1, runpy.replace("<frozen importlib._bootstrap>", "/x/neforward_ros/cli.py"))


CTRL_C_IN_A_FINALIZER = """
import os, signal, sys, weakref
from neforward_ros import cli
from neforward_ros.bag import commands


def ctrl_c_in_a_finalizer():
    # a Ctrl-C landing while a finalizer runs (seen in CI, 2026-11-27: the weakref.finalize of an
    # object freed as the run ended)
    weakref.finalize(type("Freed", (), {})(), os.kill, os.getpid(), signal.SIGINT)


class Progress(commands.Progress):
    def __call__(self, stage, fraction):
        if stage == STAGE and not getattr(self, "sent", False):
            self.sent = True
            ctrl_c_in_a_finalizer()
        return super().__call__(stage, fraction)


described = commands.describe


def describe(report):  # after every output is in place
    if STAGE == "done":
        ctrl_c_in_a_finalizer()
    return described(report)


commands.Progress, commands.describe = Progress, describe
sys.argv[1:] = ARGUMENTS
cli.entry()
"""


def run_script(script: str, cwd: Path) -> subprocess.CompletedProcess:
    """``python -c script`` in ``cwd``, SIGINT at its default, its outputs captured."""
    return subprocess.run(
        [sys.executable, "-c", script], cwd=cwd, capture_output=True, text=True, timeout=300,
        preexec_fn=default_sigint,
    )  # fmt: skip


@pytest.mark.parametrize("stage", ["computing", "done"])
def test_ctrl_c_in_a_finalizer_is_not_lost(long_recording, tmp_path, stage: str) -> None:
    """Python prints a KeyboardInterrupt met in a finalizer as "Exception ignored", with a traceback,
    and goes on: before, a run interrupted so went on to finish (exit 0, with the traceback). Now one
    while computing stops the run as any Ctrl-C does, and one once the outputs are in place is taken
    and not acted on."""
    arguments = ["bag", str(long_recording), "-o", "out", "--csv"]
    script = CTRL_C_IN_A_FINALIZER.replace("ARGUMENTS", repr(arguments)).replace("STAGE", repr(stage))
    done = run_script(script, tmp_path)
    assert "Traceback" not in done.stderr and "Exception ignored" not in done.stderr, done.stderr
    if stage == "done":
        assert done.returncode == 0, done.stderr
        assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "out.csv"]
    else:
        assert done.returncode == 130, done.stderr
        assert done.stderr.strip().split("\n")[-1].split("\r")[-1] == "neforward: interrupted", done.stderr
        assert list(tmp_path.iterdir()) == []


CTRL_C_MADE_INTO_SOMETHING_ELSE = """
import importlib.abc, os, signal, sys, time
from neforward_ros.command import entry  # as the executable starts: its first handler in


class Finder(importlib.abc.MetaPathFinder):
    # a Ctrl-C landing in matplotlib's import, where a C extension turns it into an ImportError (seen in
    # CI, 2026-11-30) or swallows it (as one in lxml's import did, 2026-11-30)
    def find_spec(self, name, path, target=None):
        if name != "matplotlib" or getattr(self, "done", False):
            return None
        self.done = True
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(60)
        except KeyboardInterrupt:  # (not the executable's first handler, which ends the process at once)
            print("KeyboardInterrupt met", file=sys.stderr, flush=True)
            if HOW == "turned":
                raise ImportError("numpy._core.multiarray failed to import") from None
        return None


sys.meta_path.insert(0, Finder())
sys.argv[1:] = ARGUMENTS
entry()
"""


@pytest.mark.parametrize("how", ["turned", "swallowed"])
@pytest.mark.parametrize("fleet", [False, True], ids=["one", "fleet"])
def test_ctrl_c_that_a_library_turns_into_an_error_or_swallows_still_stops(
    two_recordings, tmp_path, how: str, fleet: bool
) -> None:
    """A Ctrl-C that a library turns into another error or swallows still stops the run: exit status 130,
    the one line, nothing half written (in a fleet, at the first recording's outcome). Before, one turned
    into an ImportError as matplotlib was imported ended the run on "--plot needs matplotlib" (exit 1; in
    CI the interpreter then crashed at exit), and one swallowed let the run go on to finish (exit 0)."""
    if fleet:  # in one process: the first recording's failure or run, then the Ctrl-C
        arguments = ["bag", str(two_recordings), "-o", "out", "--plot", "--jobs", "1"]
    else:
        arguments = ["bag", str(two_recordings / "b"), "-o", "out", "--csv", "--plot"]
    script = CTRL_C_MADE_INTO_SOMETHING_ELSE.replace("ARGUMENTS", repr(arguments)).replace("HOW", repr(how))
    done = run_script(script, tmp_path)
    assert "KeyboardInterrupt met" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr and "Fatal Python error" not in done.stderr, done.stderr
    assert done.returncode == 130, (done.stdout, done.stderr)
    assert done.stderr.strip().split("\n")[-1].split("\r")[-1] == "neforward: interrupted", done.stderr
    left = [p.name for p in tmp_path.iterdir()]
    assert left == (["out"] if fleet else []), left
    if fleet:  # the first recording's whole outputs where its run went on to the end, and nothing of b's
        written = sorted(p.name for p in (tmp_path / "out").iterdir())
        assert written == ([] if how == "turned" else ["a", "a.png"]), written


def test_main_in_process_leaves_ctrl_c_as_it_found_it(long_recording, tmp_path) -> None:
    from neforward_ros.cli import main

    handler, hook = signal.getsignal(signal.SIGINT), sys.unraisablehook
    assert main(["bag", str(long_recording), "-o", str(tmp_path / "out")]) == 0
    assert signal.getsignal(signal.SIGINT) is handler and sys.unraisablehook is hook


CTRL_C_IN_A_FLEET = """
import os, signal, sys
from neforward_ros import cli
from neforward_ros.bag import commands

fleet, summarised = commands.process_fleet, commands.summary


def process_fleet(jobs, options, workers, on_outcome, **rest):
    def said(k, outcome):
        said.count = getattr(said, "count", 0) + 1
        if WHEN == "first" and said.count == 1:
            os.kill(os.getpid(), signal.SIGINT)
        on_outcome(k, outcome)

    return fleet(jobs, options, workers, said, **rest)


def summary(outcomes, seconds):  # every recording's outcome known, its outputs in place
    if WHEN == "done":
        os.kill(os.getpid(), signal.SIGINT)
    return summarised(outcomes, seconds)


commands.process_fleet, commands.summary = process_fleet, summary
sys.argv[1:] = ARGUMENTS
cli.entry()
"""


@pytest.fixture(scope="module")
def two_recordings(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("fleet")
    for name, seconds in (("a", 1.0), ("b", 6.0)):  # b still computing when a is done
        record(folder / name, seconds=seconds)
    return folder


@pytest.mark.parametrize("jobs", [1, 2])
@pytest.mark.parametrize("when", ["first", "done"])
def test_ctrl_c_in_a_fleet_stops_it_until_every_recording_is_done(two_recordings, tmp_path, jobs: int, when: str):
    """``neforward bag`` on several recordings: a Ctrl-C once every recording's outputs are in place is
    taken and not acted on (before, it ended the finished run with 130), and one at the first
    recording's outcome still stops the run, leaving whole outputs only and no worker's traceback
    (before, a worker terminated while computing printed one)."""
    arguments = ["bag", str(two_recordings), "-o", "out", "--jobs", str(jobs)]
    script = CTRL_C_IN_A_FLEET.replace("ARGUMENTS", repr(arguments)).replace("WHEN", repr(when))
    done = run_script(script, tmp_path)
    assert "Traceback" not in done.stderr, done.stderr
    if when == "done":
        assert done.returncode == 0, done.stderr
        assert "2 recordings in" in done.stdout and "2 done" in done.stdout, done.stdout
        assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a", "b"]
    else:
        assert done.returncode == 130, (done.stdout, done.stderr)
        assert done.stderr.strip().split("\n")[-1] == "neforward: interrupted", done.stderr
        left = sorted(p.name for p in (tmp_path / "out").iterdir())  # whole outputs only, no partial one
        assert "a" in left and set(left) <= {"a", "b"}, left
