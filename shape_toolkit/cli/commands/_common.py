"""Helpers shared by CLI subcommands: JSON output, output-path checks, typed parameter parsing,
and the readers of the small text files (labels, vertex ids, seeds) with typed errors."""

from __future__ import annotations

import argparse
import inspect
import json
import math
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from shape_toolkit.errors import ParameterError, ShapeFileError, TimeLimitError
from shape_toolkit.validation import check_random_state, dumps_json, machine_memory, shown_value


def print_json(obj: Any) -> None:
    """Print ``obj`` as JSON on stdout: numpy values converted, NaN and infinities as null
    (:func:`shape_toolkit.validation.dumps_json`), so the output is always valid JSON."""
    sys.stdout.write(dumps_json(obj, indent=2))
    sys.stdout.write("\n")


def emit(args: argparse.Namespace, result: Any, *lines: str) -> int:
    """Print ``result`` as JSON (:func:`print_json`) under ``--json``, else the text ``lines``; the exit code 0."""
    if args.json:
        print_json(result)
    else:
        for line in lines:
            print(line)
    return 0


def to_json_text(obj: Any) -> str:
    """``obj`` as a JSON string (numpy values converted, NaN and infinities as null)."""
    return dumps_json(obj, indent=2)


# --------------------------------------------------------------------------------------------
# output paths
# --------------------------------------------------------------------------------------------
def check_output_path(
    path: str | os.PathLike | None, option: str = "--output", *, suffixes: tuple[str, ...] = ()
) -> Path | None:
    """Check, before any work, that ``path`` can be written as a file: not a directory, its folder
    exists, and (with ``suffixes``) it ends with one of them. Every command with an output file
    calls this; the problems are :class:`ParameterError` naming the option."""
    if path is None:
        return None
    p = Path(path)
    if str(path) == "" or p.name in ("", ".", ".."):
        raise ParameterError(f"{option} must name a file, got {str(path)!r}")
    if suffixes and not p.name.lower().endswith(tuple(s.lower() for s in suffixes)):
        raise ParameterError(f"{option} must end with {' or '.join(suffixes)}, got {str(path)!r}")
    if p.is_dir():
        raise ParameterError(f"{option} {str(path)!r} is a directory; give a file name inside it")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.exists():
        raise ParameterError(f"{option}: the output folder {str(parent)!r} does not exist")
    if not parent.is_dir():
        raise ParameterError(f"{option}: {str(parent)!r} is not a folder")
    if p.exists() and not os.access(p, os.W_OK) or not os.access(parent, os.W_OK):
        raise ParameterError(f"{option}: {str(path)!r} is not writable")
    return p


def check_distinct(output: str | os.PathLike, *inputs: str | os.PathLike | None,
                   outputs: tuple[str | os.PathLike | None, ...] = ()) -> None:
    """Refuse an output path that is one of the input files (it would be overwritten) or one of the command's
    other ``outputs`` (one would overwrite the other)."""
    out = Path(output).resolve()
    for what, paths in (("the input file", inputs), ("the command's other output", outputs)):
        for i in paths:
            if i is not None and Path(i).resolve() == out:
                raise ParameterError(f"the output {str(output)!r} must differ from {what} {str(i)!r}")


# --------------------------------------------------------------------------------------------
# arguments and parameters
# --------------------------------------------------------------------------------------------
def check_applies(option: str, given: object, applies_to: str, present: object, hint: str = "") -> None:
    """Refuse ``option``, given (``given`` true), without what it applies to (``present`` false, e.g. the option it
    belongs to missing): the command would silently ignore it. The one rule of every command for such options,
    checked before any work: a :class:`ParameterError` (one line, exit 2) ``{option} applies to {applies_to}{hint}``,
    ``hint`` saying how to ask for it, e.g. ``"; give --remesh EDGE_LEN too"``."""
    if given and not present:
        raise ParameterError(f"{option} applies to {applies_to}{hint}")


def random_state_arg(text: str) -> int:
    """argparse ``type=`` for ``--random-state``: an integer in ``[0, 2**32 - 1]``."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer in [0, 2**32 - 1], got {text!r}") from None
    try:
        check_random_state(value)
    except ParameterError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return value


def scheduler_address(text: str) -> str:
    """argparse ``type=`` for a Dask scheduler address: ``SCHEME://HOST:PORT`` (tcp, tls, ws, wss), the port an
    integer in 1-65535, checked before any work (distributed's own parser raised internal errors)."""
    from urllib.parse import urlsplit

    problem = None
    try:
        u = urlsplit(text)
        port = u.port
    except ValueError as exc:
        u, port, problem = None, None, str(exc)
    if problem is None and (u.scheme not in ("tcp", "tls", "ws", "wss") or not u.hostname or port is None
                            or not 1 <= port <= 65535 or u.path not in ("", "/")):
        problem = "expected SCHEME://HOST:PORT with a scheme of tcp, tls, ws or wss"
    if problem:
        raise argparse.ArgumentTypeError(f"not a scheduler address like tcp://host:8786: {text!r} ({problem})")
    return text


def dask_target(text: str) -> str:
    """argparse ``type=`` for ``--dask``: ``local`` or a scheduler address (:func:`scheduler_address`)."""
    return text if text == "local" else scheduler_address(text)


def _int_at_least(text: str, lowest: int, what: str, highest: int | None = None) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be {what}, got {shown_value(text)}") from None
    if value < lowest or highest is not None and value > highest:
        raise argparse.ArgumentTypeError(f"must be {what}, got {shown_value(value)}")
    return value


def int_arg(what: str, low: int, high: int | None = None) -> Callable[[str], int]:
    """An argparse ``type=`` for an integer in ``[low, high]`` (no upper end: None); anything else is refused as
    ``must be {what}, got ...``."""

    def parse(text: str) -> int:
        return _int_at_least(text, low, what, high)

    return parse


def positive_int_arg(text: str) -> int:
    """argparse ``type=`` for counts that must be >= 1."""
    return _int_at_least(text, 1, "a positive integer")


def count_arg(text: str) -> int:
    """argparse ``type=`` for counts that may be 0."""
    return _int_at_least(text, 0, "an integer >= 0")


def proxy_arg(text: str) -> int:
    """argparse ``type=`` for ``--proxy N``: 0 (no proxy) or a vertex count of at least 100 (a proxy's least) and
    at most :data:`~shape_toolkit.io.mesh.MAX_VERTICES` (no shape has more: a larger proxy is no proxy; an integer
    past float range had raised an internal OverflowError)."""
    from shape_toolkit.io.mesh import MAX_VERTICES

    what = f"0 (no proxy) or an integer in [100, {MAX_VERTICES}]"
    value = _int_at_least(text, 0, what, MAX_VERTICES)
    if 0 < value < 100:
        raise argparse.ArgumentTypeError(f"must be {what}, got {value}")
    return value


def local_workers_arg(text: str) -> int:
    """argparse ``type=`` for a number of local worker processes: 1 to
    :func:`~shape_toolkit.bench.executors.max_local_workers` (4 per core, 8 always), the bound of ``bench run``
    (each is a process with its own memory; thousands would exhaust the machine)."""
    from shape_toolkit.bench.executors import max_local_workers

    most = max_local_workers()
    return _int_at_least(text, 1, f"an integer in [1, {most}] (local worker processes: up to 4 per core, 8 always "
                         "allowed)", most)


def number_arg(
    what: str, low: float = -math.inf, high: float = math.inf, *, open_low: bool = False, open_high: bool = False
) -> Callable[[str], float]:
    """An argparse ``type=`` for a finite number between ``low`` and ``high`` (each end included
    unless ``open_low`` / ``open_high``); anything else is refused as ``must be {what}, got ...``."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        above = value > low if open_low else value >= low
        below = value < high if open_high else value <= high
        if not (math.isfinite(value) and above and below):
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
        return value

    return parse


#: argparse ``type=`` for finite lengths > 0
positive_float_arg = number_arg("a finite positive number", 0.0, open_low=True)


def parse_params(items: list[str] | None, plugin: type | None = None, what: str = "--param") -> dict[str, Any]:
    """Parse ``KEY=VALUE`` strings; values are read as JSON when possible (numbers, true, lists),
    else kept as strings. With ``plugin`` (a class), a value is checked against the kind of the
    constructor parameter's default: a number where the default is a number, a boolean where it
    is a boolean, so ``bandwidth=abc`` is a :class:`ParameterError` naming the parameter instead of
    an error deep inside the plugin."""
    out: dict[str, Any] = {}
    for item in items or []:
        if "=" not in item:
            raise ParameterError(f"{what} expects KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        key = key.strip().replace("-", "_")
        if not key.isidentifier():  # empty, or no parameter name at all (spaces, markup, control characters)
            raise ParameterError(f"{what} expects KEY=VALUE with a parameter name as KEY, got {item!r}")
        try:
            out[key] = json.loads(value, parse_constant=_no_constant)
        except (json.JSONDecodeError, RecursionError):
            out[key] = value
        except ValueError:  # NaN / Infinity, or an integer literal too long to parse
            raise ParameterError(f"{what} {key}: {value[:40]!r} is not a usable value") from None
    if plugin is not None:
        _check_param_kinds(out, plugin, what)
    return out


def _no_constant(name: str) -> Any:
    raise ValueError(name)


def _check_param_kinds(params: dict[str, Any], plugin: type, what: str) -> None:
    try:
        sig = inspect.signature(plugin.__init__)
    except (TypeError, ValueError):  # pragma: no cover - builtins
        return
    names = getattr(plugin, "_param_names", None)
    valid = set(names()) if callable(names) else None
    for key in params:
        # a name the plugin does not take, refused here (the registry would too) so that it cannot reach
        # a caller's own keywords: 'spectrum --param weighting=...' collided with build_graph's weighting
        if valid is not None and key not in valid:
            raise ParameterError(
                f"{what} {key}: {plugin.__name__} has no parameter {key!r}; valid: {', '.join(sorted(valid)) or 'none'}"
            )
    for key, value in params.items():
        par = sig.parameters.get(key)
        if par is None or par.default is inspect.Parameter.empty or par.default is None:
            continue  # unknown names are reported by the registry; no default: no expectation
        default = par.default
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise ParameterError(f"{what} {key}={_show(value)}: {key} expects true or false")
        elif isinstance(default, (int, float)):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ParameterError(f"{what} {key}={_show(value)}: {key} expects a number (default {default!r})")
            if isinstance(default, int) and isinstance(value, float) and not value.is_integer():
                raise ParameterError(f"{what} {key}={_show(value)}: {key} expects an integer (default {default})")


def _show(value: Any) -> str:
    text = value if isinstance(value, str) and value.isprintable() else json.dumps(value)
    return text if len(text) <= 40 else text[:37] + "..."


def plugin_class(family: str, name: str) -> type:
    """The plugin class registered as ``name`` (typed :class:`PluginError` when unknown)."""
    from shape_toolkit.api.registry import get_plugin

    return get_plugin(family, name)


# --------------------------------------------------------------------------------------------
# small text files
# --------------------------------------------------------------------------------------------
def read_labels_file(path: str | os.PathLike, n_expected: int | None = None) -> np.ndarray:
    """One integer label per line as int64 ``(n,)``; every problem a :class:`ShapeFileError`."""
    from shape_toolkit.results.labels import read_int_file

    labels = read_int_file(path, "labels")
    if n_expected is not None and len(labels) != n_expected:
        raise ShapeFileError(path, f"has {len(labels)} labels, expected {n_expected}")
    return labels


def declared_spectra(plugin: Any, shape: Any) -> tuple[list | None, list[dict]]:
    """The spectra ``plugin`` declares (``spectrum_specs()``), computed once on ``shape`` through the
    content cache, to pass in as ``spectrum=``; and their JSON descriptions for the output.
    ``(None, [])`` for a plugin that needs none."""
    from shape_toolkit.spectra import compute_declared, declared_specs

    specs = declared_specs(plugin)
    if not specs:
        return None, []
    return compute_declared(shape, specs), [s.for_shape(shape).to_dict() for s in specs]


# --------------------------------------------------------------------------------------------
# one CLI policy: quiet/progress flag, default output names, progress of long steps
# --------------------------------------------------------------------------------------------
OUTPUT_POLICY = (
    "-o is optional everywhere; a command whose product is a file writes it, by default, to "
    "INPUT_STEM.<what>.<ext> in the current directory"
)


def add_quiet(p: argparse.ArgumentParser) -> None:
    """``--quiet`` (no progress on stderr); ``--no-progress`` is a hidden alias of it."""
    p.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    p.add_argument("--no-progress", dest="quiet", action="store_true", help=argparse.SUPPRESS)


def add_ply(p: argparse.ArgumentParser, what: str) -> None:
    """``--ply OUT.ply``: also write the shape with coloured vertices (MeshLab, Open3D)."""
    p.add_argument("--ply", metavar="OUT.ply", default=None,
                   help=f"also write a PLY with vertex colours showing {what} (opens in MeshLab, Open3D)")


#: default ``--time-limit`` of each geodesic computation, in seconds
DEFAULT_TIME_LIMIT = 300.0


_seconds_arg = number_arg("a finite number of seconds >= 0", 0.0)


def time_limit_arg(text: str) -> float | None:
    """``--time-limit SECONDS``: a finite number >= 0 (0: no limit, returned as None)."""
    value = _seconds_arg(text)
    return None if value == 0 else value


def add_time_limit(p: argparse.ArgumentParser, hint: str = "") -> None:
    """``--time-limit SECONDS`` of geodesic computations (default :data:`DEFAULT_TIME_LIMIT`; 0: none):
    they stop with :class:`~shape_toolkit.errors.TimeLimitError` (one line, exit 2) past it, or as soon
    as the projection says they will; ``hint`` is appended to the help (typical run times)."""
    p.add_argument("--time-limit", type=time_limit_arg, default=DEFAULT_TIME_LIMIT, metavar="SECONDS",
                   help=f"stop a geodesic computation past this many seconds, or as soon as it is clearly "
                   f"going to (default {DEFAULT_TIME_LIMIT:g}; 0: no limit){hint}")


def time_limit_hint(exc: TimeLimitError, args: argparse.Namespace) -> TimeLimitError:
    """``exc`` naming the ``--time-limit`` option that set the limit (re-raise it ``from None``)."""
    return TimeLimitError(f"{exc} (--time-limit {args.time_limit:g})")


_gigabytes_arg = number_arg("a finite number of gigabytes > 0", 0.0, open_low=True)


def memory_limit_arg(text: str) -> float:
    """``--memory-limit GB``: a finite number of gigabytes (10^9 bytes) > 0, returned in bytes."""
    return _gigabytes_arg(text) * 1e9


def add_memory_limit(p: argparse.ArgumentParser) -> None:
    """``--memory-limit GB`` (default: :func:`machine_memory`), checked by :func:`check_memory`."""
    p.add_argument("--memory-limit", type=memory_limit_arg, default=None, metavar="GB",
                   help="refuse (one line, exit 2) shapes whose declared size needs more memory than this, before "
                        "reading them (default: this machine's memory)")


def check_memory(args: argparse.Namespace, paths: list[str], model: Callable[[Any], float], work: str,
                 measured: str = "scale_1m.md", also: str = "", *, by_shape: bool = False) -> None:
    """Refuse, before reading them, the shapes ``paths`` when the vertices their files declare
    (:func:`~shape_toolkit.io.mesh.declared_vertices`; a file without a count does not take part) need more than
    ``args.memory_limit`` bytes (default :func:`machine_memory`) by ``model``, the bytes the command needs for
    that many vertices in all (``by_shape``: given each path's count, 0 for a file without one), measured (in
    ``benchmarks/results/<measured>``);
    ``work`` names what needs it. :class:`ParameterError` naming the options (``also``: another way out, named
    between the remeshing and the limit)."""
    from shape_toolkit.io.mesh import declared_vertices

    limit = args.memory_limit if args.memory_limit is not None else machine_memory()
    counts = [declared_vertices(p) for p in paths]
    if limit is None or not any(counts):
        return
    n = sum(c for c in counts if c)
    need = model([c or 0 for c in counts]) if by_shape else model(n)
    if need > limit:
        shapes = " + ".join(f"{c:,}" for c in counts if c)
        default = "" if args.memory_limit is not None else ", this machine's memory"
        one = len(paths) == 1
        raise ParameterError(
            f"{' and '.join(str(p) for p in paths)} declare{'s' if one else ''} {shapes} vertices, for which {work} "
            f"would need about {need / 1e9:.1f} GB (measured growth, benchmarks/results/{measured}), above the "
            f"memory limit of {limit / 1e9:.1f} GB (--memory-limit{default}); remesh {'it' if one else 'them'} "
            f"coarser first (shape-toolkit clean --remesh EDGE_LEN), {also + ', ' if also else ''}or raise "
            "--memory-limit")


def default_output(given: str | None, inp: str | os.PathLike, what: str) -> Path:
    """The output path: ``given``, else ``INPUT_STEM.<what>`` in the current directory (the one
    ``-o`` rule of every command that writes a file)."""
    return Path(given) if given else Path(f"{Path(inp).stem}.{what}")


#: environment variable forcing progress on (``1``) even off a terminal (logs, tests) or off (``0``)
PROGRESS_ENV = "SHAPE_TOOLKIT_PROGRESS"


def progress_enabled(args: argparse.Namespace) -> bool:
    """Progress is drawn on a terminal only, and never under ``--quiet`` or ``--json``;
    ``SHAPE_TOOLKIT_PROGRESS=1`` forces it on stderr anyway, ``=0`` turns it off."""
    if getattr(args, "quiet", False) or getattr(args, "json", False):
        return False
    forced = os.environ.get(PROGRESS_ENV, "").strip()
    if forced in ("0", "1"):
        return forced == "1"
    return bool(getattr(sys.stderr, "isatty", lambda: False)())


def _eta(seconds: float) -> str:
    s = max(0, int(round(seconds)))
    return f"{s // 60}m{s % 60:02d}s" if s >= 60 else f"{s}s"


class _Status:
    """A one-line spinner with elapsed seconds on stderr (tqdm), updated from a thread; a step
    with a known size shows ``done/total (percent), ETA`` too (:meth:`count`)."""

    def __init__(self, message: str, enabled: bool):
        self.message, self.enabled = message, enabled
        self._bar = None
        self._stop = None
        self._counts = ""
        self._t0 = 0.0

    def __enter__(self) -> _Status:
        if not self.enabled:
            return self
        import shutil
        import threading
        import time

        from tqdm import tqdm

        # the size of stderr's terminal; one that reports 0 columns and rows (some pseudo-terminals)
        # made tqdm draw nothing, so fall back to $COLUMNS / stdout's terminal / 100 x 24
        try:
            cols, rows = os.get_terminal_size(sys.stderr.fileno())
        except (OSError, ValueError, AttributeError):
            cols, rows = 0, 0
        if cols <= 0 or rows <= 0:
            cols, rows = shutil.get_terminal_size((100, 24))
        self._bar = tqdm(total=None, desc=self.message, bar_format="{desc} {elapsed}", file=sys.stderr,
                         leave=False, ncols=max(40, cols - 1), nrows=max(4, rows), dynamic_ncols=False)
        self._stop = threading.Event()
        self._t0 = time.perf_counter()

        def tick() -> None:
            while not self._stop.wait(0.25):
                self._bar.refresh()

        self._thread = threading.Thread(target=tick, daemon=True)
        self._thread.start()
        return self

    def _show(self, refresh: bool = True) -> None:
        if self._bar is not None:
            self._bar.set_description_str(self.message + self._counts, refresh=refresh)

    def update(self, message: str) -> None:
        """Change the shown step (e.g. a pipeline stage); clears the counts of the previous step."""
        self.message, self._counts = message, ""
        self._t0 = __import__("time").perf_counter()
        self._show()

    def count(self, done: int, total: int | None = None) -> None:
        """Show progress within the step: ``done`` of ``total`` units, percent and ETA (a
        ``progress(done, total)`` callback of the library, e.g. geodesic sources)."""
        if self._bar is None:
            return
        if total:
            import time

            el = time.perf_counter() - self._t0
            eta = f", ETA {_eta(el / done * (total - done))}" if 0 < done < total else ""
            self._counts = f": {done}/{total} ({100.0 * done / total:.0f}%{eta})"
        else:
            self._counts = f": {done}"
        self._show(refresh=False)  # the ticker thread redraws 4 times a second

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._stop.set()
            self._thread.join()
            self._bar.close()


def status(args: argparse.Namespace, message: str) -> _Status:
    """Context manager showing ``message`` and the elapsed time while a long step runs (terminal
    only, or forced by ``SHAPE_TOOLKIT_PROGRESS=1``; silent under ``--quiet`` / ``--json``);
    ``.update(msg)`` changes the message, ``.count(done, total)`` shows progress within it."""
    return _Status(message, progress_enabled(args))


def read_labels_as_given(
    path: str | os.PathLike, shape: Any, faces: bool, option: str = "labels"
) -> np.ndarray:
    """Labels int64 as the file holds them: ``(n_faces,)`` with ``faces`` (PSB ``.seg``), else
    ``(n_vertices,)``. A count that fits the other kind is reported with the flag to use."""
    labels = read_labels_file(path)
    n_f = shape.n_faces if shape.is_mesh else 0
    if faces:
        shape.require_faces(f"{option} with --faces")
        if len(labels) != n_f:
            hint = " (one per vertex: drop --faces)" if len(labels) == shape.n_vertices else ""
            raise ShapeFileError(path, f"has {len(labels)} labels, expected one per face ({n_f}){hint}")
    elif len(labels) != shape.n_vertices:
        hint = " (one per face, PSB .seg: add --faces)" if n_f and len(labels) == n_f else ""
        raise ShapeFileError(path, f"has {len(labels)} labels, expected one per vertex ({shape.n_vertices}){hint}")
    return labels


def read_labels_arg(
    path: str | os.PathLike, shape: Any, faces: bool, option: str = "labels"
) -> np.ndarray:
    """Per-vertex labels ``(n_vertices,)`` int64 from a file of one label per vertex, or per face
    with ``faces`` (PSB ``.seg``; converted by face-area majority), checked by
    :func:`read_labels_as_given`."""
    from shape_toolkit.results.labels import face_to_vertex_labels

    labels = read_labels_as_given(path, shape, faces, option)
    if faces:
        return face_to_vertex_labels(shape.faces, labels, shape.n_vertices, shape.face_areas)
    return labels


def write_ply(path: str | os.PathLike | None, shape: Any, colors: np.ndarray) -> str | None:
    """Write ``shape`` with vertex ``colors`` ``(n, 3)`` in [0, 1] to ``path`` (PLY); None: nothing."""
    if path is None:
        return None
    from shape_toolkit.viz import save_colored_ply

    save_colored_ply(shape, path, colors)
    return str(path)


def check_ply(path: str | None, *inputs: str | None, output: str | None = None) -> None:
    """Check a ``--ply`` output before any work: not one of the ``inputs``, nor the command's main ``output``."""
    if path is not None:
        check_output_path(path, "--ply", suffixes=(".ply",))
        check_distinct(path, *inputs, outputs=(output,))


def missing_extra(feature: str, module: str, extra: str = "viz") -> ParameterError:
    """The one-line error for an optional dependency that is not installed."""
    return ParameterError(
        f"{feature} needs the optional '{extra}' extra ({module} is not installed): "
        f"pip install 'shape-toolkit[{extra}]'"
    )
