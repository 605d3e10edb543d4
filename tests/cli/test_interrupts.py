"""Ctrl-C while a command starts up is latched, never lost (``tumblebot.interrupts``).

The failure these guard against: a SIGINT that lands while a library is being imported
can be raised inside a third-party ``try``/``except`` (or a C extension's initialisation)
and swallowed; the command then runs on as if nobody had pressed Ctrl-C.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
from pathlib import Path

from tests.helpers import interruptible

SWALLOWING_MODULE = textwrap.dedent("""
    import os, signal, time
    try:  # a library that guards its import with a catch-all, as some do
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)  # the signal is handled in here
    except BaseException:
        pass
""")


def _run(tmp_path: Path, body: str) -> subprocess.CompletedProcess[str]:
    (tmp_path / "swallower.py").write_text(SWALLOWING_MODULE)
    script = f"import sys\nsys.path.insert(0, {str(tmp_path)!r})\n" + textwrap.dedent(body)
    # Ctrl-C at its default in the child: a background job of a non-interactive shell (as CI
    # may run the suite) would hand it down ignored, and then nothing here could fail.
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                          stdin=subprocess.DEVNULL, preexec_fn=interruptible)


def test_that_a_ctrl_c_swallowed_by_an_import_is_lost_without_the_latch(tmp_path: Path) -> None:
    """The premise: with Python's own handler the interrupt vanishes inside the import."""
    run = _run(tmp_path, """
        import swallower
        print("ran on")
    """)
    assert run.returncode == 0 and "ran on" in run.stdout, run.stderr


def test_that_a_ctrl_c_during_a_swallowing_import_is_raised_at_release(tmp_path: Path) -> None:
    run = _run(tmp_path, """
        from tumblebot import interrupts
        interrupts.hold()
        import swallower
        print("imported")
        try:
            interrupts.release()
        except KeyboardInterrupt:
            print("interrupted at release")
    """)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["imported", "interrupted", "at", "release"]


def test_that_a_stop_flag_takes_over_a_latched_ctrl_c(tmp_path: Path) -> None:
    run = _run(tmp_path, """
        from tumblebot import interrupts
        interrupts.hold()
        import swallower
        from tumblebot.sim.optimize import StopFlag
        stop = StopFlag()
        with stop.installed():
            print("stop requested:", stop())
        interrupts.release()  # taken over: nothing left to raise
        print("released")
    """)
    assert run.returncode == 0, run.stderr
    assert run.stdout.splitlines() == ["stop requested: True", "released"]


def test_that_the_cli_gives_ctrl_c_back_to_python_when_a_command_ends() -> None:
    from tumblebot.cli import main

    before = signal.signal(signal.SIGINT, signal.default_int_handler)  # as in an interactive session
    try:
        assert main(["power", "0.292", "0.129", "0.098", "0.136"]) == 0
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        assert main(["optimize", "--tasks", "nav-flat", "--xi", "nonsense"]) == 2  # a holding command's error
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, before)


def test_that_a_process_started_with_ctrl_c_ignored_keeps_ignoring_it() -> None:
    """``nohup`` and background jobs start with SIGINT ignored; the latch leaves that alone."""
    script = textwrap.dedent("""
        import signal
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        from tumblebot import interrupts
        interrupts.hold()
        print(signal.getsignal(signal.SIGINT) is signal.SIG_IGN, interrupts.held())
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                         stdin=subprocess.DEVNULL)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["True", "False"]
