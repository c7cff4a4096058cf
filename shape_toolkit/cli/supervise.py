"""Run a command in a supervised child process: a hard ``--time-limit``, and one line for what
Python cannot catch.

A cooperative limit (checked between geodesic sources, say) cannot stop one long native call,
and a process killed for memory or crashed in native code leaves no message. So the commands
that compute run in a forked child, in its own process group (with its Dask workers, if any),
while the parent waits: past the limit the parent kills the group and prints one line, exit 2 (a
command with a cooperative limit of its own, ``geodesics`` and ``evaluate-map``, gets :data:`GRACE`
seconds more, so that its limit fires first and says how far it got); a
child killed by the system (SIGKILL: the out-of-memory killer) or crashed (SIGSEGV, SIGABRT,
SIGBUS) becomes one line too. Ctrl-C reaches the child as SIGINT; SIGTERM or SIGHUP to the parent (``timeout``,
a job scheduler, a closed terminal) kills the child's group before the parent exits, so no orphan runs on; a
parent killed outright (SIGKILL, which it cannot see) is noticed by the child, which kills its own group within
:data:`ORPHAN_POLL` seconds (not while one native call holds Python's lock, e.g. a single libigl solve).

The child is used only where it can be: POSIX ``fork``, and stdout/stderr that are real file
descriptors (not a test's in-memory capture); ``SHAPE_TOOLKIT_IN_PROCESS=1`` turns it off.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from collections.abc import Callable

__all__ = ["GRACE", "ORPHAN_POLL", "can_supervise", "run_supervised", "MEMORY_HINTS"]

#: seconds past ``--time-limit`` (counted from the command's start) before the child of a command with a
#: cooperative limit of its own is killed (the others are killed at the limit)
GRACE = 2.0
#: seconds between the supervised child's checks that its parent still runs
ORPHAN_POLL = 0.25
#: per command, what reduces its memory (named in the out-of-memory line)
MEMORY_HINTS = {
    "bench run": "fewer --workers, or a smaller dataset --limit",
    "match": "decimate or remesh the shapes first (shape-toolkit clean --remesh)",
    "track": "fewer --workers, or remeshed frames (shape-toolkit clean --remesh)",
    "spectrum": "a smaller -k, or a remeshed shape (shape-toolkit clean --remesh)",
    "geodesics": "fewer --sources, the dijkstra method, or a remeshed shape (shape-toolkit clean --remesh)",
    "transfer-labels": "a proxy (--proxy, not 0), or remeshed shapes (shape-toolkit clean --remesh)",
    "demo": "--no-bench, or a smaller -k",
}
_DEFAULT_HINT = "a remeshed, smaller shape (shape-toolkit clean --remesh)"
_CRASH = {signal.SIGSEGV: "SIGSEGV", signal.SIGABRT: "SIGABRT", signal.SIGBUS: "SIGBUS", signal.SIGILL: "SIGILL"}


def can_supervise() -> bool:
    """True when commands can run in a supervised child here (see the module docstring)."""
    if not hasattr(os, "fork") or os.environ.get("SHAPE_TOOLKIT_IN_PROCESS", "").strip() == "1":
        return False
    try:
        sys.stdout.fileno()
        sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation is an OSError
        return False
    return True


def memory_hint(command: str) -> str:
    """The option that reduces the memory ``command`` needs."""
    return MEMORY_HINTS.get(command, _DEFAULT_HINT)


def run_supervised(
    command: str, work: Callable[[], int], time_limit: float | None, started: float | None = None,
    cooperative: bool = False,
) -> int:
    """Run ``work()`` (returning an exit code) in a forked child; returns its exit code, or 2 past
    ``time_limit`` seconds from ``started`` (a ``time.monotonic()`` value; default now; ``cooperative``:
    ``work`` stops itself at the limit, and is killed :data:`GRACE` seconds later), 3 when the system
    killed it, 1 when it crashed, 130 on Ctrl-C, ``128 + signal`` when this process gets SIGTERM or SIGHUP
    (the child's group is killed with it). Each of those prints one line on stderr."""
    started = time.monotonic() if started is None else started
    sys.stdout.flush()
    sys.stderr.flush()
    # the parent stopped by a signal (`timeout`, a scheduler, a closed terminal) stops the child's group with it:
    # otherwise the child, in a group of its own, would run on as an orphan (installed before the fork: no gap)
    previous = _install(dict.fromkeys(_TERMINATING, _raise_terminated))
    parent = os.getpid()
    try:
        pid = os.fork()
    except OSError:
        _install(previous)
        raise
    if pid == 0:  # the child: its own group, so that the parent can stop it with its workers
        code = 1
        try:
            _install(previous)  # the child ends on SIGTERM as any process does
            os.setpgid(0, 0)
            _die_with(parent)
            if not os.environ.get("TOOLKIT_DEBUG"):  # a crash is the parent's one line, not a dump
                import faulthandler

                faulthandler.disable()
            code = int(work())
        except BaseException:  # work() reports its own errors; this is a last resort
            if os.environ.get("TOOLKIT_DEBUG"):
                import traceback

                traceback.print_exc()
        finally:
            try:
                sys.stdout.flush()
                sys.stderr.flush()
            finally:
                os._exit(code)
    deadline = None if not time_limit else started + time_limit + (GRACE if cooperative else 0.0)
    try:
        try:
            os.setpgid(pid, pid)  # also here: whichever runs first, the group exists before a kill
        except OSError:
            pass
        status = _wait(pid, deadline)
    except KeyboardInterrupt:
        _signal_group(pid, signal.SIGINT)  # the child prints its own 'interrupted'
        status = _wait(pid, time.monotonic() + 10.0)
        if status is None:
            _stop(pid)
        return 130
    except _Terminated as stop:
        _stop(pid)
        print(f"shape-toolkit {command}: stopped by {signal.Signals(stop.signum).name}", file=sys.stderr)
        return 128 + stop.signum
    finally:
        _install(previous)
    if status is None:
        _stop(pid)
        print(
            f"shape-toolkit {command}: error: stopped at the time limit of {time_limit:g} s (--time-limit): "
            "raise the limit, or reduce the work",
            file=sys.stderr,
        )
        return 2
    code = os.waitstatus_to_exitcode(status)
    if code >= 0:
        return code
    sig = -code
    if sig == signal.SIGKILL:
        print(
            f"shape-toolkit {command}: error: killed by the system (SIGKILL), most likely out of memory; "
            f"reduce the memory needed: {memory_hint(command)}",
            file=sys.stderr,
        )
        return 3
    if sig == signal.SIGINT:
        return 130
    name = _CRASH.get(sig, f"signal {sig}")
    print(
        f"shape-toolkit {command}: internal error: the computation crashed in native code ({name}) "
        "(please report it, with the input)",
        file=sys.stderr,
    )
    return 1


def _die_with(parent: int) -> None:
    """In the child: a daemon thread that kills the child's process group (itself and its workers) once its parent
    ``parent`` is gone, checked every :data:`ORPHAN_POLL` seconds."""
    import threading

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(ORPHAN_POLL)
        os.killpg(0, signal.SIGKILL)

    threading.Thread(target=watch, name="shape-toolkit-orphan-watch", daemon=True).start()


class _Terminated(Exception):
    """The parent received SIGTERM or SIGHUP while it waited for the child."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _raise_terminated(signum: int, frame: object) -> None:  # noqa: ARG001
    raise _Terminated(signum)


_TERMINATING = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))


def _install(handlers: dict[int, object]) -> dict[int, object]:
    """Install signal ``handlers`` (signal number -> handler); returns the ones they replace. Nothing is changed
    outside the main thread, where Python cannot set handlers."""
    try:
        return {sig: signal.signal(sig, h) for sig, h in handlers.items()}
    except ValueError:  # not the main thread
        return {}


def _wait(pid: int, deadline: float | None) -> int | None:
    """The child's wait status, or None when ``deadline`` passes first."""
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            return status
        if deadline is not None and time.monotonic() >= deadline:
            return None
        time.sleep(0.02)


def _signal_group(pid: int, sig: int) -> None:
    try:
        os.killpg(pid, sig)
    except OSError:  # already gone, or not yet a group: the child itself
        try:
            os.kill(pid, sig)
        except OSError:
            pass


def _stop(pid: int) -> None:
    """Kill the child's process group (the child and its workers) and reap the child."""
    _signal_group(pid, signal.SIGKILL)
    try:
        os.waitpid(pid, 0)
    except ChildProcessError:
        pass
