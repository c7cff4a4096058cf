"""``shape-toolkit examples list`` and ``shape-toolkit examples copy DIR``: the benchmark configs
and the tutorial notebook of the repository's ``examples/`` folder, shipped inside the wheel (as
``shape_toolkit/cli/_examples``) so pip users get them too."""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from shape_toolkit.cli.commands._common import emit
from shape_toolkit.errors import ParameterError


def examples_dir() -> Path:
    """The installed examples folder (the repository's ``examples/`` in a source checkout)."""
    here = Path(__file__).resolve().parent.parent / "_examples"
    if here.is_dir():
        return here
    repo = Path(__file__).resolve().parents[3] / "examples"
    if repo.is_dir():
        return repo
    raise ParameterError("the examples are not installed with this copy of shape-toolkit")


def _files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts
                  and not p.name.startswith(".") and ".ipynb_checkpoints" not in p.parts)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("examples", help="list the shipped examples or copy them to a folder")
    esub = p.add_subparsers(dest="examples_command", metavar="ACTION")
    lst = esub.add_parser("list", help="list the example files")
    lst.add_argument("--json", action="store_true", help="print JSON")
    lst.set_defaults(func=list_cmd)
    cp = esub.add_parser("copy", help="copy the examples (configs, tutorial notebook) into DIR")
    cp.add_argument("dir", help="destination folder (created; existing files are not overwritten without --force)")
    cp.add_argument("--force", action="store_true", help="overwrite existing files")
    cp.add_argument("--json", action="store_true", help="print JSON")
    cp.set_defaults(func=copy_cmd)
    p.set_defaults(func=list_cmd, json=False)


def list_cmd(args: argparse.Namespace) -> int:
    root = examples_dir()
    names = [str(p.relative_to(root)) for p in _files(root)]
    return emit(args, {"folder": str(root), "files": names}, f"examples in {root}:", *(f"  {n}" for n in names),
                "copy them with: shape-toolkit examples copy DIR")


def copy_cmd(args: argparse.Namespace) -> int:
    root = examples_dir()
    if not args.dir:  # Path("") is the current folder: an empty argument must not mean it
        raise ParameterError("examples copy: give a destination folder, got an empty name")
    dest = Path(args.dir)
    if dest.exists() and not dest.is_dir():
        raise ParameterError(f"{args.dir!r} is a file; give a folder")
    files = _files(root)
    clash = [f for f in files if (dest / f.relative_to(root)).exists()]
    if clash and not args.force:
        raise ParameterError(
            f"{dest / clash[0].relative_to(root)} exists ({len(clash)} file(s) would be overwritten); use --force"
        )
    written = []
    for f in files:
        to = dest / f.relative_to(root)
        to.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(f, to)
        written.append(str(to))
    return emit(args, {"folder": str(dest), "files": written},
                f"copied {len(written)} files to {dest}; see {dest / 'README.md'}")
