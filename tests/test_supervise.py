"""Supervised commands (issue 27, 29): a hard --time-limit that stops even one long native call,
with the command's workers; a child killed for memory or crashed becomes one line."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from shape_toolkit.cli import build_parser, supervise

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="supervision needs POSIX fork")


def test_a_time_limit_stops_one_blocking_call_and_its_workers(tmp_path, capsys, monkeypatch):
    pidfile = tmp_path / "grandchild"

    def work() -> int:
        p = subprocess.Popen(["sleep", "300"])  # a worker of the command (Dask's are processes too)
        pidfile.write_text(str(p.pid))
        time.sleep(300)  # one call that never returns on its own
        return 0

    code = supervise.run_supervised("match", work, time_limit=0.5)
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "time limit of 0.5 s" in err and "--time-limit" in err
    grandchild = int(pidfile.read_text())
    for _ in range(100):  # killed with the group (reaped by init: poll until it is gone)
        try:
            os.kill(grandchild, 0)
        except ProcessLookupError:
            break
        time.sleep(0.05)
    else:
        pytest.fail("the command's worker survived the time limit")


@pytest.mark.parametrize(
    "sig, code, words",
    [(signal.SIGKILL, 3, "out of memory"), (signal.SIGSEGV, 1, "crashed in native code (SIGSEGV)")],
)
def test_a_killed_or_crashed_child_is_one_line(capsys, sig, code, words):
    def work() -> int:
        os.kill(os.getpid(), sig)
        time.sleep(10)
        return 0

    assert supervise.run_supervised("spectrum", work, time_limit=None) == code
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err
    if sig == signal.SIGKILL:
        assert "-k" in err  # names the option that reduces memory


def test_the_child_exit_code_and_output_pass_through(capfd):
    def work() -> int:
        print("hello from the child")
        return 7

    assert supervise.run_supervised("info", work, time_limit=5) == 7
    assert capfd.readouterr().out == "hello from the child\n"


def test_every_computing_command_has_a_time_limit():
    parser = build_parser()
    for path in ("match", "segment", "spectrum", "keypoints", "transfer-labels", "track", "describe", "clean",
                 "geodesics", "evaluate-map", "demo", "bench run"):
        args = parser.parse_args([*path.split(), *_required(path), "--time-limit", "7"])
        assert args.time_limit == 7 and args.supervised == path, path


def test_only_a_cooperative_limit_gets_a_grace(monkeypatch):
    """A command that cannot stop itself is killed at its --time-limit; geodesics and evaluate-map, which stop
    themselves and say how far they got, get GRACE seconds more first."""
    monkeypatch.setattr(supervise, "GRACE", 30.0)

    def work() -> int:
        time.sleep(1.5)  # past the limit, well within the grace
        return 0

    assert supervise.run_supervised("match", work, time_limit=0.3) == 2  # killed at the limit, not 30 s later
    assert supervise.run_supervised("geodesics", work, time_limit=0.3, cooperative=True) == 0


def test_the_cli_gives_the_grace_to_the_commands_with_their_own_limit(monkeypatch):
    from shape_toolkit import cli

    seen = {}

    def fake(path, work, time_limit, started=None, cooperative=False):
        seen[path] = (time_limit, cooperative)
        return 0

    monkeypatch.setattr(supervise, "run_supervised", fake)
    monkeypatch.setattr(supervise, "can_supervise", lambda: True)
    parser = build_parser()
    for path in ("match", "segment", "spectrum", "geodesics", "evaluate-map"):
        args = parser.parse_args([*path.split(), *_required(path), "--time-limit", "7"])
        assert cli._run(parser, args, time.monotonic()) == 0
    assert seen == {"match": (7, False), "segment": (7, False), "spectrum": (7, False), "geodesics": (7, True),
                    "evaluate-map": (7, True)}


def _required(path: str) -> list[str]:
    return {
        "match": ["a", "b"], "transfer-labels": ["a", "l", "b"], "track": ["a", "b"],
        "geodesics": ["a", "--sources", "0"], "evaluate-map": ["a", "b", "m"], "bench run": ["c.toml"],
        "demo": [], "segment": ["a", "--method", "ncut"], "describe": ["a", "--descriptor", "hks"],
    }.get(path, ["a"])


def test_geodesics_exact_stops_at_its_time_limit(tmp_path):
    """The auditor's case: one libigl call for exact geodesics on a large mesh ran for minutes."""
    from shape_toolkit.data.generate import icosphere
    from shape_toolkit.io.mesh import save_shape

    mesh = tmp_path / "big.ply"
    save_shape(icosphere(6), mesh)  # 40,962 vertices: exact geodesics take far longer than 1 s
    proc = subprocess.run(
        [sys.executable, "-m", "shape_toolkit", "geodesics", str(mesh), "--sources", "0", "--method", "exact",
         "--time-limit", "1", "-o", str(tmp_path / "g.npz")],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
        env={**os.environ, "SHAPE_TOOLKIT_IN_PROCESS": "0"},
    )
    assert proc.returncode == 2, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and "time limit of 1 s" in proc.stderr
    assert not (tmp_path / "g.npz").exists()
    assert not [p for p in Path(tmp_path).iterdir() if p.name.startswith(".g.npz")]


def test_an_error_message_with_newlines_is_one_line(capsys, monkeypatch):
    """Whatever a message holds (a library's multi-line text, a name with a newline), the CLI prints
    one line."""
    from shape_toolkit.cli import main
    from shape_toolkit.cli.commands import info
    from shape_toolkit.errors import ParameterError

    def boom(args):
        raise ParameterError("first line\nsecond line\n\tthird")

    monkeypatch.setenv("SHAPE_TOOLKIT_IN_PROCESS", "1")
    monkeypatch.setattr(info, "run", boom)
    import shape_toolkit.cli as cli

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    parser._subparsers._group_actions[0].choices["info"].set_defaults(func=boom)
    assert main(["info", "x.off"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "first line second line third" in err


def test_a_terminated_command_takes_its_child_and_workers_with_it(tmp_path):
    """`timeout` (SIGTERM) on the command: the supervised child and its workers stop too, no orphan runs on."""
    pidfile = tmp_path / "worker"
    script = tmp_path / "cmd.py"
    script.write_text(
        "import subprocess, sys, time\n"
        "from shape_toolkit.cli import supervise\n"
        "def work():\n"
        "    p = subprocess.Popen(['sleep', '300'])\n"
        f"    open({str(pidfile)!r}, 'w').write(str(p.pid))\n"
        "    time.sleep(300)\n"
        "    return 0\n"
        "sys.exit(supervise.run_supervised('match', work, time_limit=None))\n"
    )
    proc = subprocess.Popen([sys.executable, str(script)], stderr=subprocess.PIPE, text=True)
    for _ in range(200):  # the worker has started
        if pidfile.exists() and pidfile.read_text():
            break
        time.sleep(0.05)
    worker = int(pidfile.read_text())
    proc.send_signal(signal.SIGTERM)
    err = proc.communicate(timeout=30)[1]
    assert proc.returncode == 128 + signal.SIGTERM
    assert err.strip().splitlines() == ["shape-toolkit match: stopped by SIGTERM"]
    for _ in range(100):
        try:
            os.kill(worker, 0)
        except ProcessLookupError:
            break
        time.sleep(0.05)
    else:
        os.kill(worker, signal.SIGKILL)
        pytest.fail("the command's worker survived the SIGTERM of the command")


def test_a_killed_command_takes_its_child_and_workers_with_it(tmp_path):
    """SIGKILL to the command (which no handler sees): the supervised child notices it is orphaned and kills its own
    group, workers included, within a few polls."""
    pidfile = tmp_path / "worker"
    script = tmp_path / "cmd.py"
    script.write_text(
        "import os, subprocess, sys, time\n"
        "from shape_toolkit.cli import supervise\n"
        "def work():\n"
        "    p = subprocess.Popen(['sleep', '300'])\n"
        f"    open({str(pidfile)!r}, 'w').write(f'{{os.getpid()}} {{p.pid}}')\n"
        "    time.sleep(300)\n"
        "    return 0\n"
        "sys.exit(supervise.run_supervised('match', work, time_limit=None))\n"
    )
    proc = subprocess.Popen([sys.executable, str(script)], stderr=subprocess.PIPE, text=True)
    for _ in range(200):  # the child and its worker have started
        if pidfile.exists() and len(pidfile.read_text().split()) == 2:
            break
        time.sleep(0.05)
    child, worker = map(int, pidfile.read_text().split())
    proc.kill()
    proc.communicate(timeout=30)
    alive = {child, worker}
    for _ in range(200):
        for pid in list(alive):
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                alive.discard(pid)
        if not alive:
            break
        time.sleep(0.05)
    for pid in alive:
        os.kill(pid, signal.SIGKILL)
    assert not alive, "the supervised child or its worker survived the SIGKILL of the command"
