"""``shape-toolkit bench run CONFIG -o RUN_DIR`` and ``shape-toolkit bench report RUN_DIR``."""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from shape_toolkit.cli.commands._common import (
    add_quiet,
    check_applies,
    default_output,
    number_arg,
    positive_int_arg,
    print_json,
    scheduler_address,
)

RUN_EPILOG = """exit status:
  0  every row of the run folder succeeded
  1  the run finished but some rows failed (see results.jsonl or the report)
  2  usage error: invalid config (or one planning more rows than --max-rows), bad option, or a
     run folder that is locked by another 'bench run' or not writable (one line on stderr,
     nothing run)"""


@contextmanager
def _one_line_warnings() -> Iterator[None]:
    """Show benchmark warnings (skipped invalid lines, ...) as one ``warning:`` line on stderr."""
    from shape_toolkit.bench.store import BenchWarning

    def show(message, category, filename, lineno, file=None, line=None):  # noqa: ANN001
        print(f"shape-toolkit bench: warning: {message}", file=sys.stderr)

    with warnings.catch_warnings():
        warnings.simplefilter("always", BenchWarning)
        warnings.showwarning = show
        yield


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="run benchmark configs and write reports")
    bsub = p.add_subparsers(dest="bench_command", metavar="ACTION")
    r = bsub.add_parser(
        "run",
        help="run (or resume) a benchmark config into a run folder",
        description="Run (or resume) a benchmark config: one row per item, method and parameters "
        "appended to RUN_DIR/results.jsonl. One 'bench run' per run folder at a time.",
        epilog=RUN_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    r.add_argument("config", help="TOML benchmark config")
    r.add_argument(
        "-o", "--output", metavar="RUN_DIR",
        help="run folder (results.jsonl, cache; default CONFIG_STEM.run in the current directory)",
    )
    r.add_argument(
        "--workers", type=int, default=1, help="local parallel workers (Dask LocalCluster when > 1)"
    )
    r.add_argument(
        "--scheduler", metavar="ADDRESS", type=scheduler_address,
        help="address of an existing Dask scheduler (tcp://host:port)"
    )
    r.add_argument(
        "--worker-timeout", metavar="SECONDS", type=number_arg("a number of seconds > 0", 0, open_low=True),
        default=60.0, help="stop (resumable, exit 3) when Dask has had no worker this long (default 60)",
    )
    r.add_argument("--limit", type=positive_int_arg, metavar="N", help="keep the first N items of each dataset")
    r.add_argument(
        "--max-rows", type=positive_int_arg, metavar="N", default=None,
        help="refuse a config planning more than N rows, counted before anything is expanded "
        "(default 1000, bench.config.MAX_ROWS)",
    )
    r.add_argument("--retry-failed", action="store_true", help="run failed rows again")
    r.add_argument("--rerun", metavar="LABEL", action="append", default=[],
                   help="compute the rows of this method label again (repeatable): rows are reused by their config, "
                   "not by the code, so after a code change name the methods it touches; the former rows move to "
                   "RUN_DIR/results.jsonl.replaced")
    add_quiet(r)
    r.add_argument("--report", action="store_true", help="write the report when the run ends")
    r.add_argument("--markdown", metavar="FILE",
                   help="with --report: also write its tables to FILE as Markdown, headed by this command")
    r.add_argument("--json", action="store_true", help='print {"rows", "failed", "reused", ...} at the end')
    r.set_defaults(func=run_cmd)
    rep = bsub.add_parser("report", help="write RUN_DIR/report/index.html and PNG figures")
    rep.add_argument("run_dir", help="a run folder written by bench run")
    rep.add_argument("-o", "--output", help="report folder (default RUN_DIR/report)")
    rep.add_argument("--renders", type=int, default=3, help="shapes rendered per task (default 3)")
    rep.add_argument("--markdown", metavar="FILE", help="also write the tables to FILE as Markdown")
    rep.add_argument("--up", choices=("auto", "longest", "middle"), default="auto",
                     help="up direction of rendered shapes: auto (the default: the longest principal axis, or the "
                     "middle one for a shape standing on legs across its longest, such as a quadruped), or "
                     "always the longest or the middle axis (viz.upright_frame)")
    rep.add_argument("--json", action="store_true", help="print the written files as JSON")
    add_quiet(rep)
    rep.set_defaults(func=report_cmd)
    cmp_ = bsub.add_parser(
        "compare", help="what changed between two runs: paired differences per method and metric",
        description="Pair the rows of RUN_A and RUN_B by task, dataset, item, corruption and method label; "
        "for each method and metric print the mean paired difference B - A, its standard error and a verdict "
        "(better / worse beyond 2 SE in the metric's better direction), the items that moved most, and rows "
        "that failed in one run only.",
    )
    cmp_.add_argument("run_a", help="the run before (a run folder)")
    cmp_.add_argument("run_b", help="the run after")
    cmp_.add_argument("-o", "--output", metavar="DIR", help="also write DIR/compare.html and DIR/compare.csv")
    cmp_.add_argument("--json", action="store_true", help="print the comparison as JSON")
    cmp_.set_defaults(func=compare_cmd)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _say(args: argparse.Namespace):
    """Report-writing progress lines on stderr (none under --quiet / --json)."""
    if args.quiet or args.json:
        return None
    return lambda msg: print(f"report: {msg}", file=sys.stderr, flush=True)


def run_cmd(args: argparse.Namespace) -> int:
    """Exit 0 when every row succeeded, 1 when some failed; usage errors raise (exit 2)."""
    from shape_toolkit.bench.config import MAX_ROWS, load_config
    from shape_toolkit.bench.executors import run_benchmark

    args.output = str(default_output(args.output, args.config, "run"))
    check_applies("--markdown", args.markdown is not None, "the report, whose tables it writes", args.report,
                  "; give --report too")
    if args.markdown is not None:
        _check_markdown(args.markdown)
    with _one_line_warnings():
        # every check happens before any work, the row count before any grid is expanded
        cfg = load_config(args.config, max_rows=args.max_rows or MAX_ROWS, limit=args.limit)
        if args.report:  # a report folder holding someone else's index.html: refused now, not after the run
            from shape_toolkit.bench.report import check_report_output

            check_report_output(Path(args.output) / "report")
        summary = run_benchmark(
            cfg,
            args.output,
            workers=args.workers,
            scheduler=args.scheduler,
            limit=args.limit,
            progress=not (args.quiet or args.json),
            retry_failed=args.retry_failed,
            worker_timeout=args.worker_timeout,
            rerun=args.rerun,
        )
        report = None
        if args.report:
            from shape_toolkit.bench.report import write_report

            report = str(write_report(args.output, progress=_say(args), markdown=args.markdown,
                                      command=_command_line())["html"])
    if args.json:
        print_json(
            {
                "rows": summary.rows,
                "failed": summary.failed,
                "reused": summary.reused,
                "planned": summary.planned,
                "seconds": summary.seconds,
                "run_dir": summary.run_dir,
                "report": report,
            }
        )
    else:
        print(
            f"{summary.rows} rows written, {summary.reused} reused, {summary.failed} failed "
            f"({summary.planned} planned) in {summary.seconds:.1f} s -> {summary.run_dir}/results.jsonl"
        )
        if report:
            print(f"report: {report}")
    return 1 if summary.failed else 0


def _command_line() -> str:
    """This command as typed, for the head of a Markdown report (``shape-toolkit`` and its arguments)."""
    import shlex

    return " ".join(["shape-toolkit", *(shlex.quote(a) for a in sys.argv[1:])])


def _check_markdown(path: str) -> None:
    """``--markdown FILE`` usable before any work: in an existing folder, not a folder."""
    from shape_toolkit.errors import ParameterError

    p = Path(path)
    if p.is_dir() or not p.parent.is_dir():
        raise ParameterError(f"--markdown {path}: must be a file in an existing folder")


def report_cmd(args: argparse.Namespace) -> int:
    from shape_toolkit.bench.report import write_report

    if args.markdown is not None:
        _check_markdown(args.markdown)
    with _one_line_warnings():
        res = write_report(args.run_dir, output=args.output, renders=args.renders, progress=_say(args),
                           markdown=args.markdown, command=_command_line(), up=args.up)
    if args.json:
        print_json({k: (str(v) if v is not None else None) if not isinstance(v, list) else [str(x) for x in v]
                    for k, v in res.items()})
    else:
        print(f"report: {res['html']} ({len(res['figures'])} figures)", file=sys.stdout)
    return 0


def compare_cmd(args: argparse.Namespace) -> int:
    """Exit 0 with the comparison; a folder that is not a run folder is one line, exit 2."""
    from shape_toolkit.bench.compare import compare_runs, format_text, write_comparison

    with _one_line_warnings():
        comp = compare_runs(args.run_a, args.run_b)
    written = write_comparison(comp, args.output) if args.output else []
    if args.json:
        print_json({**comp.to_dict(), "written": written})
    else:
        sys.stdout.write(format_text(comp))
        for w in written:
            print(f"wrote {w}")
    return 0
