"""The ``shape-toolkit`` command line: subcommands are discovered in :mod:`shape_toolkit.cli.commands`.

Each module there exposes ``register(subparsers)``, adding a parser whose ``func(args) -> int``
does the work. A :class:`~shape_toolkit.errors.ToolkitError` becomes one line on stderr and a
non-zero exit code; nothing reaches the user as a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
import time
import warnings

from shape_toolkit.cli import commands
from shape_toolkit.errors import ToolkitError


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2, like every other user error
        self.exit(2, f"{self.prog}: error: {message}\n")


#: commands that run in a supervised child process (:mod:`shape_toolkit.cli.supervise`), each
#: with a hard ``--time-limit``; the others (listings, the viewer) run in process
SUPERVISED = (
    "clean", "constraints", "demo", "describe", "evaluate-map", "evaluate-segmentation", "geodesics", "info",
    "keypoints", "match", "segment", "spectrum", "track", "transfer-labels", "bench run", "bench report",
)


def _subparser(parser: argparse.ArgumentParser, path: str) -> argparse.ArgumentParser | None:
    for name in path.split():
        actions = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not actions or name not in actions[0].choices:
            return None
        parser = actions[0].choices[name]
    return parser


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every discovered subcommand; each supervised command gets
    ``--time-limit`` unless it declares its own (geodesics, evaluate-map: a cooperative limit with
    a default, which the hard one backs up :data:`~shape_toolkit.cli.supervise.GRACE` seconds later;
    the others are stopped at the limit)."""
    from shape_toolkit.cli.commands._common import time_limit_arg

    parser = _Parser(prog="shape-toolkit", description="Spectral shape analysis toolkit")
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        if hasattr(module, "register"):
            module.register(sub)
    for path in SUPERVISED:
        p = _subparser(parser, path)
        if p is not None:
            p.set_defaults(supervised=path)
            if any("--time-limit" in a.option_strings for a in p._actions):
                p.set_defaults(cooperative_limit=True)  # its own limit says how far it got: a grace before the kill
            else:
                p.add_argument("--time-limit", type=time_limit_arg, default=None, metavar="SECONDS",
                               help="stop (one line, exit 2) past this many seconds, even inside one long "
                               "native call (default: no limit)")
    return parser


def _one_line_warnings(command: str):
    """A ``warnings.showwarning`` printing each warning as one line (no source excerpt)."""

    def show(message, category, filename, lineno, file=None, line=None):  # noqa: ARG001
        text = " ".join(str(message).split())
        print(f"shape-toolkit {command}: warning: {text}", file=file or sys.stderr)

    return show


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``shape-toolkit`` console script; returns the exit code."""
    started = time.monotonic()
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, or a usage error already printed as one line
        return int(exc.code or 0) if isinstance(exc.code, int) else 2
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=DeprecationWarning)
        warnings.showwarning = _one_line_warnings(getattr(args, "command", None) or "")
        return _run(parser, args, started)


def _run(parser: argparse.ArgumentParser, args: argparse.Namespace, started: float) -> int:
    if args.version:
        from shape_toolkit import __version__

        print(__version__)
        return 0
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    path = getattr(args, "supervised", None)
    if path is not None:
        from shape_toolkit.cli import supervise

        if supervise.can_supervise():
            return supervise.run_supervised(path, lambda: _call(args), getattr(args, "time_limit", None), started,
                                            cooperative=getattr(args, "cooperative_limit", False))
    return _call(args)


def _one_line(text: object) -> str:
    """``text`` on one line: a newline in a message (from a file name, a parameter, a library) would
    make a second line."""
    return " ".join(str(text).split())


def _call(args: argparse.Namespace) -> int:
    """Run the command in this process: every error one line, with its exit code. Warnings are held until the
    command succeeds, then printed (one line each, each distinct warning once: a file read twice, as source and
    target, warns once); a command that fails prints its error line alone, not a warning about its input before it
    (a cloud file's dropped normals, then the refusal of a cloud)."""
    held: list[tuple[tuple, dict]] = []
    show = warnings.showwarning
    warnings.showwarning = lambda *w, **kw: held.append((w, kw))
    try:
        code = _command(args)
    finally:
        warnings.showwarning = show
    if code == 0:
        seen: set[tuple[str, type]] = set()
        for w, kw in held:
            key = (str(w[0]), w[1])
            if key not in seen:
                seen.add(key)
                show(*w, **kw)
    return code


def _command(args: argparse.Namespace) -> int:
    """:func:`_call`'s work: the command's exit code, each error printed as one line."""
    try:
        return int(args.func(args) or 0)
    except ToolkitError as exc:
        print(f"shape-toolkit {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"shape-toolkit {args.command}: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        from shape_toolkit.cli.supervise import memory_hint

        where = getattr(args, "supervised", None) or args.command
        print(f"shape-toolkit {args.command}: error: out of memory; reduce the memory needed: {memory_hint(where)}",
              file=sys.stderr)
        return 3
    except BrokenPipeError:
        return 0
    except OSError as exc:  # the environment (disk full, permissions), not a bug: one line
        where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
        print(f"shape-toolkit {args.command}: error: {_one_line(f'{exc.strerror or exc}{where}')}", file=sys.stderr)
        return 2
    except Exception as exc:  # a bug of ours: still one line, with a pointer for reporting
        print(
            f"shape-toolkit {args.command}: internal error: {type(exc).__name__}: {_one_line(exc)} "
            "(please report it; set TOOLKIT_DEBUG=1 for the traceback)",
            file=sys.stderr,
        )
        import os

        if os.environ.get("TOOLKIT_DEBUG"):
            raise
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
