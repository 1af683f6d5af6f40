"""roger_common.atomic: atomic replacement, with and without fsync."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from roger_common.atomic import atomic_write_bytes, sync_file


def _count_fsyncs(monkeypatch) -> list[int]:
    calls: list[int] = []
    real = os.fsync

    def counting(fd: int) -> None:
        calls.append(fd)
        real(fd)
    monkeypatch.setattr(os, "fsync", counting)
    return calls


@pytest.mark.parametrize("durable, fsyncs", [(True, 2), (False, 0)])
def test_write_replaces_content_and_fsyncs_only_when_durable(tmp_path: Path, monkeypatch,
                                                             durable: bool,
                                                             fsyncs: int) -> None:
    path = tmp_path / "sub" / "state.json"
    atomic_write_bytes(path, b"old")
    calls = _count_fsyncs(monkeypatch)
    atomic_write_bytes(path, b"new content", durable=durable)
    assert path.read_bytes() == b"new content"
    assert len(calls) == fsyncs  # the file and its folder
    assert [p.name for p in path.parent.iterdir()] == ["state.json"]  # no temporary left


def test_non_durable_write_is_still_atomic(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "state.json"
    atomic_write_bytes(path, b"old", durable=False)

    def crash(*args, **kwargs):
        raise OSError("killed before the rename")
    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(OSError, match="killed"):
        atomic_write_bytes(path, b"half", durable=False)
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["state.json"]


def test_sync_file_fsyncs_file_and_folder_and_skips_missing(tmp_path: Path,
                                                            monkeypatch) -> None:
    path = tmp_path / "state.json"
    atomic_write_bytes(path, b"x", durable=False)
    calls = _count_fsyncs(monkeypatch)
    sync_file(path)
    assert len(calls) == 2
    sync_file(tmp_path / "missing.json")
    sync_file(None)
    assert len(calls) == 2
