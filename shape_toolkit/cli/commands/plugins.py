"""``shape-toolkit plugins list [--json]``: the registered plugins of every family."""

from __future__ import annotations

import argparse

from shape_toolkit.api.registry import get_registry
from shape_toolkit.cli.commands._common import print_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plugins", help="list the registered plugins")
    psub = p.add_subparsers(dest="plugins_command", metavar="ACTION")
    lst = psub.add_parser("list", help="list plugins by family")
    lst.add_argument("--json", action="store_true", help="print {family: [names...]}")
    lst.set_defaults(func=run)
    p.set_defaults(func=run, json=False)


def run(args: argparse.Namespace) -> int:
    reg = get_registry()
    fams = reg.families()
    if args.json:
        print_json(fams)
        return 0
    for fam, names in fams.items():
        print(f"{fam}: {', '.join(names) if names else '(none)'}")
    for name, err in reg.broken.items():
        print(f"broken plugin {name}: {err}")
    return 0
