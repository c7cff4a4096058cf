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
import warnings

from shape_toolkit.cli import commands
from shape_toolkit.errors import ToolkitError


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2, like every other user error
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every discovered subcommand."""
    parser = _Parser(prog="shape-toolkit", description="Spectral shape analysis toolkit")
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        if hasattr(module, "register"):
            module.register(sub)
    return parser


def _one_line_warnings(command: str):
    """A ``warnings.showwarning`` printing each warning as one line (no source excerpt)."""

    def show(message, category, filename, lineno, file=None, line=None):  # noqa: ARG001
        text = " ".join(str(message).split())
        print(f"shape-toolkit {command}: warning: {text}", file=file or sys.stderr)

    return show


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``shape-toolkit`` console script; returns the exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, or a usage error already printed as one line
        return int(exc.code or 0) if isinstance(exc.code, int) else 2
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=DeprecationWarning)
        warnings.showwarning = _one_line_warnings(getattr(args, "command", None) or "")
        return _run(parser, args)


def _run(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    if args.version:
        from shape_toolkit import __version__

        print(__version__)
        return 0
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except ToolkitError as exc:
        print(f"shape-toolkit {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"shape-toolkit {args.command}: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        print(f"shape-toolkit {args.command}: error: out of memory", file=sys.stderr)
        return 3
    except BrokenPipeError:
        return 0
    except OSError as exc:  # the environment (disk full, permissions), not a bug: one line
        where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
        print(f"shape-toolkit {args.command}: error: {exc.strerror or exc}{where}", file=sys.stderr)
        return 2
    except Exception as exc:  # a bug of ours: still one line, with a pointer for reporting
        print(
            f"shape-toolkit {args.command}: internal error: {type(exc).__name__}: {exc} "
            "(please report it; set TOOLKIT_DEBUG=1 for the traceback)",
            file=sys.stderr,
        )
        import os

        if os.environ.get("TOOLKIT_DEBUG"):
            raise
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
