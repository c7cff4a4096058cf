"""The run folder is a jail (issue 27): links in it are refused before any write, 'bench run'
writes only in folders it made, and the lock survives a deleted ``.lock``."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from helpers import bench_run, segmentation_config, write_config

from shape_toolkit.bench import read_rows
from shape_toolkit.bench.store import LOCK, MARK, run_lock

CONFIG = segmentation_config("jail", limit=1, metrics='"n_segments"')


def _run(tmp_path: Path, run: Path) -> int:
    return bench_run(write_config(tmp_path, CONFIG), run)


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("link", ["prepare.jsonl", "results.jsonl", "cache", "cache/spectra", "outputs"])
def test_a_link_in_the_run_folder_is_refused_and_nothing_outside_changes(tmp_path, capsys, link):
    run = tmp_path / "run"
    assert _run(tmp_path, run) == 0
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "keep.txt").write_text("mine\n")
    target = run / link
    if target.is_dir():
        os.rename(target, outside / "moved")
        os.symlink(outside, target)
    else:
        victim = outside / "victim.jsonl"
        victim.write_text("user data\n")
        target.unlink()
        os.symlink(victim, target)
    if link != "results.jsonl":
        (run / "results.jsonl").unlink()  # every row again: each write would go through the link
    before = _tree(outside)
    capsys.readouterr()
    assert _run(tmp_path, run) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "symbolic link" in err
    assert _tree(outside) == before


def test_a_folder_that_is_not_a_run_folder_is_refused(tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "config.json").write_text('{"my": "settings"}')
    capsys.readouterr()
    assert _run(tmp_path, mine) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not a run folder" in err
    assert sorted(p.name for p in mine.iterdir() if p.name != LOCK) == ["config.json"]
    assert (mine / "config.json").read_text() == '{"my": "settings"}'


def test_a_new_or_empty_folder_becomes_a_run_folder_and_resumes(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert _run(tmp_path, empty) == 0
    assert (empty / MARK).exists() and len(read_rows(empty)) == 1
    assert _run(tmp_path, empty) == 0  # a run folder: resumed, nothing refused
    assert len(read_rows(empty)) == 1


def test_the_lock_survives_a_deleted_lock_file(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    with run_lock(run):
        (run / LOCK).unlink()
        capsys.readouterr()
        assert _run(tmp_path, run) == 2
        assert "in use by another" in capsys.readouterr().err
        assert not (run / "results.jsonl").exists()
    assert _run(tmp_path, run) == 0
