"""A subset of the run-folder fault corpus (benchmarks/run_folder_corpus.py): one file of each
kind of a finished run, each fault; 0 mishandled (issue 27: 0 wrong rows after any swap,
truncation or planting of files in a run folder; 0 files written outside it)."""

from __future__ import annotations

from pathlib import Path

import pytest
from helpers import REPO, load_script

corpus = load_script("run_folder_corpus", REPO / "benchmarks" / "run_folder_corpus.py")
#: one file of each kind: the logs, the config, a prepared item, a spectrum, an output
KINDS = ("results.jsonl", "prepare.jsonl", "config.json", "cache/prepared", "cache/spectra", "outputs")


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    work = tmp_path_factory.mktemp("rfc")
    cfg, ref = corpus.reference(work)
    return work, cfg, ref, corpus._rows(ref)


def _pick(ref: Path, kind: str) -> str:
    p = ref / kind
    return kind if p.is_file() else str(sorted(p.glob("*.npz"))[0].relative_to(ref))


#: the fast run tries every fault once and every kind at least once; the other pairs are marked slow
FAST = {(KINDS[i % len(KINDS)], fault) for i, fault in enumerate(corpus.FAULTS)}
CASES = [pytest.param(kind, fault, id=f"{kind}-{fault}", marks=() if (kind, fault) in FAST else pytest.mark.slow)
         for kind in KINDS for fault in corpus.FAULTS]


@pytest.mark.parametrize("kind, fault", CASES)
def test_no_fault_is_mishandled(reference, kind, fault):
    work, cfg, ref, rows = reference
    case = corpus.run_case(corpus.Case(fault, _pick(ref, kind)), cfg, ref, rows, work)
    assert case.outcome in ("ok", "refused"), case.detail
    if fault in ("swap", "truncate", "empty", "garbage", "pickle", "delete", "plant"):
        assert case.outcome == "ok", case  # a damaged cache is a miss: recomputed, same rows
