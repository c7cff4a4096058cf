"""Published reference numbers (the thesis's tables) shown beside a benchmark's measured rows.

The numbers live as data in ``shape_toolkit/bench/data/sharma2012.toml``: per table or figure its id
(``table-7.2``), section, line of the thesis's Markdown text, caption, what the thesis measured on and
its claim; per printed row the shape or pair (``setting``), the method, the values keyed by the runner's
metric column (``r_smooth@0.8``, ``label_recall``) and the line they are printed on.

A task of a benchmark config names the tables to show with ``published = ["table-7.2"]`` (a string or a
list; an unknown id, or a table without printed numbers, is refused before any work, naming the key).
The report then adds, under the measured rows of that task's table, one row per published method
(and corruption, Table 5.2 II): the mean (and standard deviation) over the thesis's own shapes, labelled
``thesis (published): METHOD``. These rows are not measured: they are never marked best, never enter
the summary or any aggregate, and the table's notes say what they are.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

from shape_toolkit.errors import ParameterError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = [
    "PUBLISHED_LABEL",
    "PublishedTable",
    "PublishedRow",
    "ReferenceRow",
    "published_tables",
    "published_rows",
    "check_published",
    "PublishedKeyError",
    "reference_rows",
    "task_references",
]

#: the method cell of every reference row starts with this
PUBLISHED_LABEL = "thesis (published)"
_DATA = Path(__file__).resolve().parent / "data" / "sharma2012.toml"


@dataclass(frozen=True)
class PublishedTable:
    """A table or figure of the thesis: ``id`` (``table-7.2``), ``kind`` (table or figure), ``section``,
    ``line`` of its caption in the thesis's Markdown, ``caption``, ``data`` (what the thesis measured on),
    ``columns`` (runner column -> the thesis's symbol) and ``claim`` (the thesis's sentence)."""

    id: str
    kind: str
    section: str
    line: int
    caption: str
    data: str
    columns: dict[str, str]
    claim: str


@dataclass(frozen=True)
class PublishedRow:
    """One printed row: ``table`` id, ``line`` (to ``line_end``) of the thesis's Markdown, ``setting``
    (shape or pair), ``method``, ``values`` (runner column -> number as printed), ``std`` and ``n`` where
    the thesis prints mean +- std over ``n`` shapes, ``condition`` (a corruption) and ``info`` (other
    printed numbers no runner column measures)."""

    table: str
    line: int
    setting: str
    method: str
    values: dict[str, float]
    line_end: int | None = None
    condition: str = "none"
    std: dict[str, float] = field(default_factory=dict)
    n: int = 1
    info: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class ReferenceRow:
    """A row the report shows under the measured ones: ``dataset`` (what the thesis measured on),
    ``method`` (``thesis (published): METHOD``), ``corruption`` and per column ``(mean, std, n)`` over
    the thesis's shapes."""

    dataset: str
    method: str
    corruption: str
    cells: dict[str, tuple[float, float, int]]
    table: str


@lru_cache(maxsize=1)
def _load() -> tuple[dict[str, PublishedTable], tuple[PublishedRow, ...]]:
    raw = tomllib.loads(_DATA.read_text(encoding="utf-8"))
    tables = {}
    for t in raw["tables"]:
        tables[t["id"]] = PublishedTable(
            t["id"], t["kind"], str(t["section"]), int(t["line"]), t["caption"], t["data"], dict(t["columns"]),
            t["claim"],
        )
    rows = []
    for r in raw["rows"]:
        if r["table"] not in tables:  # pragma: no cover - the shipped file is tested
            raise ParameterError(f"{_DATA.name}: row of unknown table {r['table']!r}")
        rows.append(PublishedRow(
            r["table"], int(r["line"]), r["setting"], r["method"], {k: float(v) for k, v in r["values"].items()},
            r.get("line_end"), r.get("condition", "none"), {k: float(v) for k, v in r.get("std", {}).items()},
            int(r.get("n", 1)), dict(r.get("info", {})),
        ))
    return tables, tuple(rows)


def published_tables() -> dict[str, PublishedTable]:
    """Every table and figure of the thesis the data file describes, by id."""
    return dict(_load()[0])


def published_rows(table: str | None = None) -> list[PublishedRow]:
    """The printed rows of ``table`` (every table's when None); an unknown id raises :class:`ParameterError`."""
    tables, rows = _load()
    if table is not None and table not in tables:
        raise ParameterError(f"unknown published table {table!r}; known: {', '.join(tables)}")
    return [r for r in rows if table is None or r.table == table]


class PublishedKeyError(ParameterError):
    """A config's ``published`` value is bad; ``index`` is the bad entry of a list (None: the value)."""

    def __init__(self, index: int | None, problem: str):
        self.index = index
        self.problem = problem
        super().__init__(problem)


def check_published(value: Any) -> tuple[str, ...]:
    """A config's ``published`` value (a table id or a list of ids) checked: each must be a table of the
    data file with printed numbers; returns the ids. Raises :class:`PublishedKeyError` (the config names
    the key: ``tasks[0].published[1]``)."""
    ids = [value] if isinstance(value, str) else value
    if not isinstance(ids, list) or not ids:
        raise PublishedKeyError(None, f"must be a table id or a non-empty list of them, got {value!r}")
    tables, rows = _load()
    with_numbers = [t for t in tables if any(r.table == t for r in rows)]
    for j, t in enumerate(ids):
        index = None if isinstance(value, str) else j
        if not isinstance(t, str) or t not in tables:
            raise PublishedKeyError(index, f"unknown published table {t!r}; known: {', '.join(with_numbers)}")
        if t not in with_numbers:
            raise PublishedKeyError(index, f"{t} prints no numbers (the thesis shows it as a picture); "
                                           f"tables with numbers: {', '.join(with_numbers)}")
    return tuple(dict.fromkeys(ids))


def reference_rows(table: str) -> list[ReferenceRow]:
    """The rows a report shows for ``table``: per (method, condition) the mean, standard deviation and
    count over the thesis's shapes (a row printed as mean +- std over n keeps its own)."""
    tab = published_tables()[table] if table in published_tables() else None
    if tab is None:
        raise ParameterError(f"unknown published table {table!r}")
    groups: dict[tuple[str, str], list[PublishedRow]] = {}
    for r in published_rows(table):
        groups.setdefault((r.method, r.condition), []).append(r)
    out = []
    for (method, condition), rs in groups.items():
        cells: dict[str, tuple[float, float, int]] = {}
        for col in dict.fromkeys(c for r in rs for c in r.values):
            vals = [r.values[col] for r in rs if col in r.values]
            if len(rs) == 1 and col in rs[0].std:
                cells[col] = (vals[0], rs[0].std[col], rs[0].n)
                continue
            mean = sum(vals) / len(vals)
            std = (sum((v - mean) ** 2 for v in vals) / len(vals)) ** 0.5
            cells[col] = (mean, std, len(vals))
        settings = list(dict.fromkeys(r.setting for r in rs))
        what = settings[0] if len(settings) == 1 else f"mean of {len(settings)} (see the note)"
        out.append(ReferenceRow(f"thesis {table}: {what}", f"{PUBLISHED_LABEL}: {method}", condition, cells, table))
    return out


def task_references(config_raw: dict[str, Any]) -> dict[str, tuple[str, ...]]:
    """``{task name: published table ids}`` of a run's raw config (``RUN_DIR/config.json``); tasks
    without ``published`` are left out, and so is anything unreadable (a report never fails on it)."""
    out: dict[str, tuple[str, ...]] = {}
    tables = published_tables()
    for t in config_raw.get("tasks", []) if isinstance(config_raw, dict) else []:
        if not isinstance(t, dict) or "published" not in t:
            continue
        ids = t["published"] if isinstance(t["published"], list) else [t["published"]]
        name = t.get("name", t.get("task"))
        if isinstance(name, str):
            out[name] = tuple(i for i in ids if isinstance(i, str) and i in tables)
    return out
