"""The run folder: result rows, the prepare log, prepared items and outputs, and its lock.

A run folder is data, never code: everything in it is JSON lines or ``.npz`` archives read with
``allow_pickle=False`` and validated; whatever fails validation is skipped (rows, with a
warning, and recomputed) or rebuilt (cached items), never trusted.

``RUN_DIR/results.jsonl`` holds one JSON object per line. One ``bench run`` at a time writes a
run folder (an OS-level lock on ``RUN_DIR/.lock``); it appends each finished row as one whole
line followed by ``flush`` + ``fsync``, so a crash loses no finished row and at worst leaves a
torn last line, which the next run moves aside with any other invalid line.
"""

from __future__ import annotations

import errno
import json
import os
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from shape_toolkit.errors import ParameterError, ToolkitError
from shape_toolkit.validation import atomic_output, dumps_json, jsonable

__all__ = [
    "RESULTS",
    "PREPARED",
    "SPLIT",
    "PLANNED",
    "LOCK",
    "BenchWarning",
    "RunFolderError",
    "RowIdentity",
    "Row",
    "read_rows",
    "write_planned",
    "planned_keys",
    "only_planned",
    "read_prepare_log",
    "clean_results",
    "Appender",
    "run_lock",
    "RunStoppedError",
    "transient_problem",
    "claim_run_folder",
    "save_prepared",
    "load_prepared",
    "prepared_path",
    "save_output",
    "load_output",
    "safe_name",
]

RESULTS = "results.jsonl"
PREPARED = "prepare.jsonl"
SPLIT = "split.json"  # which half of which tuning/reporting split the run's rows are (absent: no split)
PLANNED = "planned.json"  # the row keys the folder's last config planned: reports show those rows only
LOCK = ".lock"
MARK = ".shape-toolkit-run"  # written in every run folder: 'bench run' writes only in folders it made
INVALID_SUFFIX = ".invalid"
_STATUSES = ("ok", "failed")


class BenchWarning(UserWarning):
    """Something in a run folder was skipped (an invalid line, an unreadable cache file)."""


class RunFolderError(ParameterError):
    """The run folder cannot be used: locked by another run, not writable, not a run folder."""


class RunStoppedError(ToolkitError):
    """The run stopped for a transient cause (the folder became unwritable, workers or the
    scheduler were lost): nothing was recorded for the rows it did not finish, and running the
    same command again resumes it. Exit code 3."""

    exit_code = 3


WRITE_ERRNOS = frozenset({errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOSPC, errno.EDQUOT})


def transient_problem(exc: BaseException, run_dir: str | os.PathLike) -> str | None:
    """What makes ``exc`` a fault of the environment rather than a result of the row (a write
    in the run folder refused: permissions, read-only, disk full), or None."""
    from shape_toolkit.errors import ShapeFileError

    if isinstance(exc, OSError) and exc.errno in WRITE_ERRNOS:
        where = f" ({exc.filename})" if exc.filename else ""
        return f"the system refused a write: {exc.strerror or exc}{where}"
    if isinstance(exc, ShapeFileError) and exc.problem.startswith("cannot "):
        run = Path(run_dir).resolve()
        path = Path(exc.path).resolve()
        if path == run or run in path.parents:
            return f"cannot write to the run folder: {exc}"
    return None


def safe_name(name: str, limit: int = 80) -> str:
    """``name`` usable as one file-name component: anything but letters, digits, ``.``, ``-``
    and ``_`` becomes ``_`` (so ``a/b`` or ``..`` never leave the folder)."""
    out = "".join(c if c.isalnum() and c.isascii() or c in "-_." else "_" for c in str(name))
    out = out.strip(".") or "_"
    return out[:limit]


# --------------------------------------------------------------------------------------------
# rows
# --------------------------------------------------------------------------------------------
@dataclass
class RowIdentity:
    """What a result row and the job that computes it share: the row's identity (run, task, dataset
    item, method, corruption, seeds) and the key hashed from it. Field names have one meaning each:
    ``task_kind`` is the adapter (spectrum, keypoints, segmentation, matching), ``task_name`` the
    config's name for the task; ``plugin`` the registry name (or pipeline name), ``method_label`` the
    display name; ``prepare_key`` the key of the (item, corruption)'s shared prepare job. The field
    order is the order of a stored row's first keys (the row format): append, never reorder."""

    key: str
    run_name: str
    task_name: str
    task_kind: str
    dataset: str
    item: str
    plugin: str
    family: str
    method_label: str
    preset: str | None
    params: dict[str, Any]
    corruption: str
    corruption_kind: str
    corruption_group: str
    corruption_params: dict[str, Any]
    strength: float | None
    random_state: int
    corruption_seed: int
    prepare_key: str

    def identity(self) -> dict[str, Any]:
        """The :class:`RowIdentity` fields of this object (a job's or a row's), by name."""
        return {f.name: getattr(self, f.name) for f in fields(RowIdentity)}


@dataclass
class Row(RowIdentity):
    """One result row: its identity (:class:`RowIdentity`) and what the method did. ``spectra``
    lists the spectra the method received (:meth:`SpectrumSpec.to_dict`), nothing else;
    ``category`` is the item's group (PSB category, animal, subject; None when the dataset has
    none) and ``item_params`` the parameters set for this item on top of ``params`` (e.g.
    ``n_segments`` from the humans)."""

    status: str = "ok"
    error: str | None = None
    seconds: float | None = None
    cpu_seconds: float | None = None
    peak_memory_mb: float | None = None
    metrics: dict[str, Any] = field(default_factory=dict)
    spectra: list[dict[str, Any]] = field(default_factory=list)
    spectrum_seconds: float | None = None
    spectrum_cache_hit: bool | None = None
    metric_seconds: float | None = None
    #: set with the task option ``metric_costs``: the metrics' CPU seconds and peak memory (MB)
    metric_cpu_seconds: float | None = None
    metric_peak_memory_mb: float | None = None
    total_seconds: float | None = None
    n_vertices: int | None = None
    output: str | None = None
    versions: dict[str, str] = field(default_factory=dict)
    worker: str = ""
    traceback: str | None = None
    category: str | None = None
    item_params: dict[str, Any] = field(default_factory=dict)
    #: the BLAS threads the worker's BLAS libraries had while the method ran (threadpoolctl; None unknown)
    blas_threads: int | None = None
    #: how often the method ran (task option ``repeats``): the timings are of the fastest run
    repeats: int = 1

    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready row (NaN and infinities become null)."""
        d = asdict(self)
        for k in ("traceback", "metric_cpu_seconds", "metric_peak_memory_mb"):  # absent unless set
            if d[k] is None:
                del d[k]
        return jsonable(d)


#: keys every stored row must have, with their types (checked on read)
_ROW_TYPES: dict[str, type | tuple[type, ...]] = {
    "key": str,
    "status": str,
    "task_name": str,
    "task_kind": str,
    "item": str,
    "method_label": str,
    "metrics": dict,
}


#: optional keys of a stored row, with the types the report can show: absent, or of this type
#: (``None`` in the tuple: null allowed); a row with another type is set aside like a torn line
_TEXT = (str,)
_NUMBER = (int, float, type(None))
_ROW_OPTIONAL: dict[str, tuple[type, ...]] = {
    **dict.fromkeys(("run_name", "dataset", "plugin", "family", "corruption", "corruption_kind",
                     "corruption_group", "prepare_key", "worker"), _TEXT),
    **dict.fromkeys(("preset", "error", "output", "traceback"), (str, type(None))),
    **dict.fromkeys(("params", "corruption_params", "versions"), (dict,)),
    **dict.fromkeys(("strength", "seconds", "cpu_seconds", "peak_memory_mb", "spectrum_seconds",
                     "metric_seconds", "metric_cpu_seconds", "metric_peak_memory_mb", "total_seconds"), _NUMBER),
    **dict.fromkeys(("random_state", "corruption_seed", "n_vertices", "blas_threads", "repeats"), (int, type(None))),
    "spectrum_cache_hit": (bool, type(None)),
    "spectra": (list,),
}


def _row_problem(obj: Any) -> str | None:
    """Why ``obj`` is not a row the report can show (None when it is): the required keys with
    their types, the optional keys of :data:`_ROW_OPTIONAL` of their types when present, numbers
    that are not booleans, and spectra that are tables."""
    if not isinstance(obj, dict):
        return f"a JSON {type(obj).__name__}, not an object"
    for k, t in _ROW_TYPES.items():
        if not isinstance(obj.get(k), t):
            return f"no valid {k!r}"
    if obj["status"] not in _STATUSES:
        return f"status {obj['status']!r}"
    for k, types in _ROW_OPTIONAL.items():
        if k not in obj:
            continue
        v = obj[k]
        if not isinstance(v, types) or (isinstance(v, bool) and bool not in types):
            return f"{k!r} is a JSON {_json_type(v)}"
    if any(not isinstance(s, dict) for s in obj.get("spectra", [])):
        return "'spectra' holds a non-table"
    return None


def _json_type(v: Any) -> str:
    return {dict: "object", list: "array", str: "string", bool: "boolean", type(None): "null"}.get(
        type(v), "number"
    )


def _prep_problem(obj: Any) -> str | None:
    if not isinstance(obj, dict):
        return f"a JSON {type(obj).__name__}, not an object"
    if not isinstance(obj.get("key"), str):
        return "no valid 'key'"
    if not isinstance(obj.get("spectra", []), list):
        return "no valid 'spectra'"
    return None


def _scan(path: Path, check) -> tuple[list[dict], list[tuple[int, str, str]]]:
    """Valid objects and ``(line number, line, problem)`` of invalid lines of a JSON-lines file."""
    good: list[dict] = []
    bad: list[tuple[int, str, str]] = []
    if not path.exists():
        return good, bad
    data = path.read_bytes()
    for i, raw in enumerate(data.split(b"\n"), 1):
        line = raw.decode("utf-8", errors="replace").strip()
        if not line:
            continue
        try:
            obj = json.loads(line)
        except ValueError:
            bad.append((i, line, "not valid JSON"))
            continue
        problem = check(obj)
        if problem:
            bad.append((i, line, problem))
        else:
            good.append(obj)
    return good, bad


def _warn_bad(path: Path, bad: list[tuple[int, str, str]], action: str) -> None:
    if not bad:
        return
    shown = ", ".join(f"line {i} ({p})" for i, _, p in bad[:3]) + (", ..." if len(bad) > 3 else "")
    warnings.warn(f"{path}: skipped {len(bad)} invalid line(s): {shown}; {action}", BenchWarning, stacklevel=3)


def read_rows(run_dir: str | os.PathLike, name: str = RESULTS, *, planned_only: bool = False) -> list[dict]:
    """Every valid row of ``RUN_DIR/results.jsonl`` as dicts (one per key, the last written);
    invalid lines (torn, not JSON, not a row object) are skipped with a :class:`BenchWarning`.
    ``planned_only``: only the rows the folder's last config planned (:func:`planned_keys`; all rows of a
    folder written before that record existed), not those a changed config left behind."""
    path = Path(run_dir) / name
    if name != RESULTS:
        return read_prepare_log(run_dir, name)
    good, bad = _scan(path, _row_problem)
    _warn_bad(path, bad, "their rows count as not done")
    by_key: dict[str, dict] = {}
    for r in good:
        by_key.pop(r["key"], None)
        by_key[r["key"]] = r
    rows = list(by_key.values())
    return only_planned(rows, run_dir) if planned_only else rows


def only_planned(rows: list[dict], run_dir: str | os.PathLike) -> list[dict]:
    """The ``rows`` whose key the folder's last config planned (:func:`planned_keys`; all of them when the
    folder has no record of its plan)."""
    keys = planned_keys(run_dir)
    return rows if keys is None else [r for r in rows if r["key"] in keys]


def write_planned(run_dir: str | os.PathLike, keys: Sequence[str]) -> None:
    """Record the row keys the run's config plans (``RUN_DIR/planned.json``, sorted JSON strings)."""
    with atomic_output(Path(run_dir) / PLANNED, "planned rows") as tmp:
        tmp.write_text(dumps_json(sorted(keys)), encoding="utf-8")


def planned_keys(run_dir: str | os.PathLike) -> set[str] | None:
    """The row keys of ``RUN_DIR/planned.json`` (read as JSON strings, nothing else), or None when the
    folder has none or it is not a list of strings (then with a :class:`BenchWarning`)."""
    path = Path(run_dir) / PLANNED
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        warnings.warn(f"{path}: unreadable ({exc}); every row of the folder is shown", BenchWarning, stacklevel=2)
        return None
    if not isinstance(data, list) or not all(isinstance(k, str) for k in data):
        warnings.warn(f"{path}: not a list of row keys; every row of the folder is shown", BenchWarning, stacklevel=2)
        return None
    return set(data)


def read_prepare_log(run_dir: str | os.PathLike, name: str = PREPARED) -> list[dict]:
    """The valid entries of ``RUN_DIR/prepare.jsonl`` (invalid lines skipped with a warning)."""
    path = Path(run_dir) / name
    good, bad = _scan(path, _prep_problem)
    _warn_bad(path, bad, "ignored")
    return good


def clean_results(path: Path, *, keep_failed: bool = True) -> None:
    """Rewrite a JSON-lines file with its valid rows only (the run holds the lock): invalid lines
    (a torn last line, garbage) move to ``NAME.invalid`` and their rows are recomputed;
    ``keep_failed=False`` also drops failed rows (``--retry-failed``)."""
    if not path.exists():
        return
    good, bad = _scan(path, _row_problem)
    _warn_bad(path, bad, f"moved to {path.name}{INVALID_SUFFIX}, their rows will be recomputed")
    keep = [r for r in good if keep_failed or r.get("status") == "ok"]
    data = path.read_bytes()
    if not bad and len(keep) == len(good) and (not data or data.endswith(b"\n")):
        return
    if bad:
        with open(path.with_name(path.name + INVALID_SUFFIX), "a", encoding="utf-8") as fh:
            fh.writelines(line + "\n" for _, line, _ in bad)
    with atomic_output(path, "results file", durable=True) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.writelines(dumps_json(r) + "\n" for r in keep)


#: where ``--rerun`` sets aside the rows it replaces (appended, never deleted)
REPLACED_SUFFIX = ".replaced"


def set_aside_rows(path: Path, keys: set[str]) -> int:
    """Move the rows of a JSON-lines results file whose ``key`` is in ``keys`` to ``NAME.replaced`` (appended) and
    rewrite the file without them (the run holds the lock); returns how many were moved (``--rerun``)."""
    if not path.exists() or not keys:
        return 0
    good, _ = _scan(path, _row_problem)
    moved = [r for r in good if r.get("key") in keys]
    if not moved:
        return 0
    with open(path.with_name(path.name + REPLACED_SUFFIX), "a", encoding="utf-8") as fh:
        fh.writelines(dumps_json(r) + "\n" for r in moved)
    with atomic_output(path, "results file", durable=True) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.writelines(dumps_json(r) + "\n" for r in good if r.get("key") not in keys)
    return len(moved)


class Appender:
    """Append JSON objects to a JSON-lines file, one whole line each, flushed and fsynced."""

    def __init__(self, path: Path):
        self.path = path
        # O_NOFOLLOW: a link planted in place of the log is refused, never appended through
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
        self.fh = os.fdopen(fd, "a", encoding="utf-8")

    def write(self, obj: Any) -> None:
        """Append ``obj`` (NaN and infinities become null)."""
        self.fh.write(dumps_json(obj) + "\n")
        self.fh.flush()
        os.fsync(self.fh.fileno())

    def close(self) -> None:
        """Close the file."""
        self.fh.close()


@contextmanager
def run_lock(run: Path) -> Iterator[None]:
    """Hold the run folder's OS-level locks for the duration: ``RUN_DIR/.lock`` (filelock) and,
    where the OS has ``flock``, a lock on the folder itself, which deleting ``.lock`` cannot
    release. A second writer gets :class:`RunFolderError` at once instead of duplicating rows."""
    from filelock import FileLock, Timeout

    busy = f"run folder {run} is in use by another 'bench run' (lock {run / LOCK}); wait for it to finish"
    lock = FileLock(str(run / LOCK), timeout=0)
    try:
        lock.acquire(timeout=0)
    except Timeout:
        raise RunFolderError(busy) from None
    except OSError as exc:
        raise RunFolderError(f"cannot lock run folder {run}: {exc.strerror or exc}") from None
    fd = None
    try:
        try:
            import fcntl
        except ImportError:  # pragma: no cover - Windows: the file lock only
            fcntl = None
        if fcntl is not None:
            fd = os.open(run, os.O_RDONLY)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise RunFolderError(busy) from None
        yield
    finally:
        if fd is not None:
            os.close(fd)
        lock.release()


def claim_run_folder(run: Path) -> None:
    """Check, under the lock, that ``run`` is a folder 'bench run' may write in, and mark it: empty
    (a new run), or already a run folder (its mark or its results); and that nothing inside it is
    a symbolic link, which could make the run write or read outside it. Else
    :class:`RunFolderError`, before anything is written."""
    entries = {p.name for p in run.iterdir()} - {LOCK}
    if entries and not entries & {MARK, RESULTS, PREPARED}:
        shown = ", ".join(sorted(entries)[:3]) + (", ..." if len(entries) > 3 else "")
        raise RunFolderError(
            f"{run} is not empty and is not a run folder (it holds {shown}); give 'bench run -o' a new or empty "
            "folder, so that no file of yours is overwritten"
        )
    for root, dirs, files in os.walk(run, followlinks=False):
        for name in dirs + files:
            p = Path(root) / name
            if p.is_symlink():
                raise RunFolderError(
                    f"{p} is a symbolic link: a run folder holds no links (the run could write outside it); "
                    "remove it or start a new run folder"
                )
    if MARK not in entries:
        (run / MARK).write_text("a shape-toolkit 'bench run' folder\n")


# --------------------------------------------------------------------------------------------
# prepared items (npz, no pickle)
# --------------------------------------------------------------------------------------------
_PREP_VERSION = 3  # 2: shapes keep their colours; 3: the header holds the item's key and input digest
_OPTIONAL = ("truth", "truth_sym", "truth_eval", "truth_eval_sym", "geodesic_rows", "geodesic_rows_sym")
_LISTS = ("source_labels", "target_labels", "target_face_labels")


def prepared_path(run_dir: str | os.PathLike, key: str) -> Path:
    """Where the prepared item ``key`` is cached."""
    return Path(run_dir) / "cache" / "prepared" / f"{safe_name(key)}.npz"


def save_prepared(path: Path, prep: Any, *, key: str = "", inputs: str = "") -> None:
    """Write a :class:`~shape_toolkit.bench.tasks.Prepared` as plain arrays plus a JSON header
    holding ``key`` (the prepare job's key) and ``inputs`` (the digest of the files it was made
    from), which :func:`load_prepared` verifies."""
    arrays: dict[str, np.ndarray] = {}
    header: dict[str, Any] = {
        "version": _PREP_VERSION,
        "key": key,
        "inputs": inputs,
        "name": prep.name,
        "corruption_seconds": float(prep.corruption_seconds),
        "geodesic_seconds": float(prep.geodesic_seconds),
        "meta": jsonable(prep.meta),
        "present": [],
        "lists": {},
        "shapes": {},
    }
    for side in ("source", "target", "clean_target"):
        shape = getattr(prep, side)
        if shape is None:  # no clean target: scored on the target itself
            continue
        arrays[f"{side}_vertices"] = np.asarray(shape.vertices, np.float64)
        if shape.faces is not None:
            arrays[f"{side}_faces"] = np.asarray(shape.faces, np.int64)
        if shape.colors is not None:
            arrays[f"{side}_colors"] = np.asarray(shape.colors, np.float64)
        if shape.normals is not None:
            arrays[f"{side}_normals"] = np.asarray(shape.normals, np.float64)
        header["shapes"][side] = {"name": shape.name, "faces": shape.faces is not None,
                                  "colors": shape.colors is not None, "normals": shape.normals is not None}
    arrays["vertex_map"] = np.asarray(prep.vertex_map)
    for k in _OPTIONAL:
        v = getattr(prep, k)
        if v is not None:
            arrays[k] = np.asarray(v)
            header["present"].append(k)
    for k in _LISTS:
        items = list(getattr(prep, k) or [])
        header["lists"][k] = len(items)
        for i, a in enumerate(items):
            arrays[f"{k}_{i}"] = np.asarray(a)
    with atomic_output(path, "prepared item", suffix=".npz", make_parents=True) as tmp:
        np.savez(tmp, header=np.array(dumps_json(header)), **arrays)


def _int_array(a: np.ndarray, what: str, shape_ok) -> np.ndarray:
    if not np.issubdtype(a.dtype, np.integer) or not shape_ok(a):
        raise ValueError(f"{what}: bad dtype {a.dtype} or shape {a.shape}")
    return a.astype(np.int64)


def load_prepared(path: Path, *, key: str | None = None, inputs: str | None = None):
    """Read and validate a prepared item written by :func:`save_prepared` (``allow_pickle=False``):
    it must hold ``key`` and ``inputs`` when they are given; ``ValueError`` when anything is off
    (the caller prepares the item again)."""
    from shape_toolkit.bench.tasks import Prepared
    from shape_toolkit.core.shape import Shape

    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:  # fh: closed on a bad zip too
            arrays = {k: z[k] for k in z.files}
    except Exception as exc:  # truncated, empty, not an npz (a pickle is refused here)
        raise ValueError(f"not a prepared-item archive: {type(exc).__name__}: {exc}") from None
    try:
        header = json.loads(str(arrays.pop("header")))
        if not isinstance(header, dict) or header.get("version") != _PREP_VERSION:
            raise ValueError("unknown header version")
        if key is not None and header.get("key") != key:
            raise ValueError("it was prepared for another item or corruption")
        if inputs is not None and header.get("inputs") != inputs:
            raise ValueError("its input files changed since it was prepared")
        shapes = {}
        for side in ("source", "target", "clean_target"):
            if side not in header["shapes"] and side == "clean_target":
                shapes[side] = None
                continue
            info = header["shapes"][side]
            faces = arrays.get(f"{side}_faces") if info["faces"] else None
            v = arrays[f"{side}_vertices"]
            bad_faces = faces is not None and not np.issubdtype(faces.dtype, np.integer)
            if not np.issubdtype(v.dtype, np.floating) or bad_faces:
                raise ValueError(f"{side}: bad dtypes")
            colors = arrays[f"{side}_colors"] if info.get("colors") else None
            normals = arrays[f"{side}_normals"] if info.get("normals") else None
            shapes[side] = Shape(v, faces, name=str(info["name"]), colors=colors, normals=normals)
        n_s, n_t = shapes["source"].n_vertices, shapes["target"].n_vertices
        vmap = _int_array(arrays["vertex_map"], "vertex_map", lambda a: a.ndim == 1 and len(a) == n_t)
        if shapes["clean_target"] is not None:  # the ground truth and rows are on the clean target
            n_t = shapes["clean_target"].n_vertices
            if len(vmap) and (vmap.min() < 0 or vmap.max() >= n_t):
                raise ValueError("vertex_map: ids out of range of the clean target")
        opt: dict[str, Any] = {k: None for k in _OPTIONAL}
        for k in header["present"]:
            if k not in _OPTIONAL:
                raise ValueError(f"unknown array {k!r}")
            a = arrays[k]
            if k.startswith("truth"):
                a = _int_array(a, k, lambda a: a.ndim == 2 and a.shape[1] == 2)
                if len(a) and (a[:, 0].max() >= n_s or a[:, 1].max() >= n_t or a.min() < -1):
                    raise ValueError(f"{k}: vertex ids out of range")
            else:
                if not np.issubdtype(a.dtype, np.floating) or a.ndim != 2 or a.shape[1] != n_t:
                    raise ValueError(f"{k}: bad dtype or shape")
            opt[k] = a
        for k, t in (("geodesic_rows", "truth_eval"), ("geodesic_rows_sym", "truth_eval_sym")):
            if opt[k] is not None and (opt[t] is None or len(opt[k]) != len(opt[t])):
                raise ValueError(f"{k} does not match {t}")
        lists: dict[str, list[np.ndarray]] = {}
        for k in _LISTS:
            n = int(header["lists"].get(k, 0))
            items = [arrays[f"{k}_{i}"] for i in range(n)]
            for a in items:
                if not np.issubdtype(a.dtype, np.integer) or a.ndim != 1:
                    raise ValueError(f"{k}: bad labels")
            lists[k] = [a.astype(np.int64) for a in items]
        if any(len(a) != n_s for a in lists["source_labels"]) or any(len(a) != n_t for a in lists["target_labels"]):
            raise ValueError("labels do not match the vertex counts")
        meta = header.get("meta") or {}
        if not isinstance(meta, dict):
            raise ValueError("meta is not a table")
        return Prepared(
            str(header["name"]),
            shapes["source"],
            shapes["target"],
            opt["truth"],
            opt["truth_sym"],
            lists["source_labels"],
            lists["target_labels"],
            vmap,
            float(header["corruption_seconds"]),
            truth_eval=opt["truth_eval"],
            truth_eval_sym=opt["truth_eval_sym"],
            geodesic_rows=opt["geodesic_rows"],
            geodesic_rows_sym=opt["geodesic_rows_sym"],
            geodesic_seconds=float(header["geodesic_seconds"]),
            meta=meta,
            target_face_labels=lists["target_face_labels"],
            clean_target=shapes["clean_target"],
        )
    except Exception as exc:  # anything off in a planted or damaged file: not this item
        raise ValueError(f"invalid prepared item {path.name}: {exc}") from None


# --------------------------------------------------------------------------------------------
# method outputs
# --------------------------------------------------------------------------------------------
def save_output(run_dir: str | os.PathLike, key: str, output: dict) -> str | None:
    """Save the array outputs of a row to ``RUN_DIR/outputs/KEY.npz``, with the row key (verified
    by :func:`load_output`); returns the relative path."""
    arrays = {}
    for k, v in output.items():
        if isinstance(v, (np.ndarray, list)):
            a = np.asarray(v)
            if a.dtype.kind in "biuf":
                arrays[k] = a
    if not arrays:
        return None
    name = safe_name(key)
    with atomic_output(Path(run_dir) / "outputs" / f"{name}.npz", "output file", suffix=".npz",
                       make_parents=True) as tmp:
        np.savez_compressed(tmp, **arrays, **{_OUTPUT_KEY: np.array(key)})
    return f"outputs/{name}.npz"


_OUTPUT_KEY = "__row_key__"


def load_output(run_dir: str | os.PathLike, rel: Any, key: str | None = None) -> dict[str, np.ndarray]:
    """The arrays of a row's output file (``allow_pickle=False``); ``ValueError`` when the path
    leaves the run folder, the file is not a plain npz archive, or (``key`` given) it was written
    for another row."""
    run = Path(run_dir).resolve()
    if not isinstance(rel, str):
        raise ValueError("output path is not a string")
    path = (run / rel).resolve()
    if run not in path.parents:
        raise ValueError(f"output path {rel!r} leaves the run folder")
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:  # fh: closed on a bad zip too
            arrays = {k: z[k] for k in z.files}
    except Exception as exc:  # truncated, empty, not an npz (a pickle is refused here)
        raise ValueError(f"unreadable output {rel}: {type(exc).__name__}: {exc}") from None
    stored = arrays.pop(_OUTPUT_KEY, None)
    if key is not None and (stored is None or str(stored) != key):
        raise ValueError(f"output {rel} was written for another row")
    return arrays
