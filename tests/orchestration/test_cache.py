"""The content-keyed cache: finished units are reused, damaged ones never (issue 18, item 8)."""

from __future__ import annotations

import json

import pytest

from pcpg_dist.common.errors import DataError
from pcpg_dist.common.file_bytes import write_files
from pcpg_dist.common.keys import content_key
from pcpg_dist.orchestration.cache import Cache


def finished(tmp_path) -> Cache:
    cache = Cache(tmp_path / "cache")
    cache.store(
        "train",
        "k1",
        {"cells.pt": b"x" * 1000, "cells.json": b"{}", "sub/t.csv": b"a,b\n"},
        {"stage": "train"},
    )
    return cache


def test_a_finished_unit_is_reused(tmp_path):
    cache = finished(tmp_path)
    info = cache.done("train", "k1")
    assert info["stage"] == "train" and set(info["files"]) == {
        "cells.pt",
        "cells.json",
        "sub/t.csv",
    }
    assert cache.rejected == []


@pytest.mark.parametrize(
    "damage",
    [
        lambda p: p.write_bytes(p.read_bytes()[:500]),  # truncated cells.pt
        lambda p: p.write_bytes(b"y" * 1000),  # same size, other bytes
        lambda p: p.unlink(),  # removed
    ],
)
def test_a_damaged_unit_is_recomputed_never_used(tmp_path, damage):
    cache = finished(tmp_path)
    damage(cache.path("train", "k1") / "cells.pt")
    assert cache.done("train", "k1") is None
    assert cache.rejected == ["train/k1"]


def test_garbage_marker_or_an_old_marker_means_not_done(tmp_path):
    cache = finished(tmp_path)
    marker = cache.path("train", "k1") / "done.json"
    marker.write_text("{not json")
    assert cache.done("train", "k1") is None
    marker.write_text(json.dumps({"stage": "train"}))  # written before checksums existed
    assert cache.done("train", "k1") is None


def test_result_files_cannot_leave_their_folder(tmp_path):
    for bad in ("../evil", "sub/../../evil", "/etc/passwd"):
        with pytest.raises(DataError):
            write_files(tmp_path / "unit", {bad: b"x"})
    assert not (tmp_path / "evil").exists()


def test_content_key_is_stable_and_sensitive():
    assert content_key("a", {"x": 1, "y": [1, 2]}) == content_key("a", {"y": [1, 2], "x": 1})
    assert content_key("a", {"x": 1}) != content_key("a", {"x": 2})
