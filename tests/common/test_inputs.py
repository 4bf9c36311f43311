"""The input policy (pcpg_dist/common/inputs.py), on its own and in the readers that had none:
regular files and folders only; a link followed only where it resolves inside its folder; a
special file refused in one line, never skipped in silence."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from pcpg_dist.common.errors import DataError, PcpgError
from pcpg_dist.common.inputs import entries, input_file, input_folder, writable_folder

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def tree(tmp_path):
    """folder/ with a file, a link within, a link out, a FIFO; outside/ with the link's target."""
    folder, outside = tmp_path / "folder", tmp_path / "outside"
    folder.mkdir()
    outside.mkdir()
    (folder / "a.txt").write_text("a")
    (outside / "secret.txt").write_text("secret")
    (folder / "within.txt").symlink_to(folder / "a.txt")
    return folder, outside


def test_regular_files_and_links_within_are_read(tree):
    folder, _ = tree
    assert input_file(folder / "a.txt", "file", folder=folder) == folder / "a.txt"
    assert input_file(folder / "within.txt", "file", folder=folder) == folder / "within.txt"
    assert entries(folder, "file", suffixes=[".txt"]) == [folder / "a.txt", folder / "within.txt"]
    assert input_folder(folder, "folder") == folder


def test_a_link_out_and_special_files_are_one_line(tree):
    folder, outside = tree
    (folder / "out.txt").symlink_to(outside / "secret.txt")
    with pytest.raises(DataError) as e:
        input_file(folder / "out.txt", "layout file", folder=folder)
    assert str(e.value).startswith(
        f"layout file {folder / 'out.txt'}: a link to {outside / 'secret.txt'}, outside {folder}"
    )
    with pytest.raises(DataError, match="out.txt: a link to"):
        entries(folder, "file", suffixes=[".txt"])
    (folder / "out.txt").unlink()
    os.mkfifo(folder / "pipe.txt")
    with pytest.raises(DataError, match=r"pipe.txt: a FIFO, not a regular file"):
        entries(folder, "file", suffixes=[".txt"])
    with pytest.raises(DataError, match=r"pipe.txt: a FIFO, not a regular file"):
        input_file(folder / "pipe.txt", "file")
    assert entries(folder, "file", suffixes=[".csv"]) == []  # not among the named entries
    (folder / "pipe.txt").unlink()
    (folder / "dangling.txt").symlink_to(folder / "gone.txt")
    with pytest.raises(DataError, match="a link to nothing"):
        entries(folder, "file")
    with pytest.raises(DataError, match=r"big: 10 bytes, over the limit of 4 bytes"):
        (folder / "big").write_bytes(b"0123456789")
        input_file(folder / "big", "file", max_bytes=4)


def test_an_output_folder_that_is_a_link_out_is_refused(tmp_path):
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "pcpg").symlink_to(tmp_path / "elsewhere")
    with pytest.raises(DataError, match="pcpg: a link to .*elsewhere, outside .*out"):
        writable_folder(tmp_path / "out" / "pcpg", "--out", folder=tmp_path / "out")
    (tmp_path / "out" / "within").symlink_to(tmp_path / "out" / "real")
    assert writable_folder(tmp_path / "out" / "within", folder=tmp_path / "out")
    assert writable_folder(tmp_path / "new", "--out") == tmp_path / "new"
    os.mkfifo(tmp_path / "pipe")
    with pytest.raises(DataError, match="pipe: a FIFO, not a folder"):
        writable_folder(tmp_path / "pipe")


def test_a_layout_file_linked_from_outside_its_folder_is_refused(tmp_path):
    """gridworld.layout_dir files were read through links leaving the folder."""
    from pcpg_dist.config import parse_config

    layouts, outside = tmp_path / "layouts", tmp_path / "outside"
    layouts.mkdir()
    outside.mkdir()
    text = (ROOT / "pcpg_dist" / "data" / "gridworld" / "E1.txt").read_text()
    (outside / "E1.txt").write_text(text)
    (layouts / "E1.txt").symlink_to(outside / "E1.txt")
    raw = {"name": "x", "gridworld": {"layout_dir": str(layouts), "environments": ["E1"]}}
    with pytest.raises(PcpgError, match=rf"layout file {layouts / 'E1.txt'}: a link to"):
        parse_config(raw, source="x")
    (layouts / "E1.txt").unlink()
    (layouts / "E1.txt").write_text(text)
    assert parse_config(raw, source="x").gridworld.environments == ["E1"]


def test_a_cluster_model_file_linked_from_outside_is_refused_before_reading(tmp_path):
    """`pcpg classify`'s model folder: its JSON was read through a link leaving the folder."""
    from pcpg_dist.stages.clustering import load_model

    model, outside = tmp_path / "model", tmp_path / "outside"
    model.mkdir()
    outside.mkdir()
    (outside / "cluster_model.json").write_text("{}")
    (model / "cluster_model.json").symlink_to(outside / "cluster_model.json")
    (model / "cluster_model.pt").write_bytes(b"")
    with pytest.raises(DataError, match=r"cluster model file .*cluster_model.json: a link to"):
        load_model(model)
    (model / "cluster_model.json").unlink()
    os.mkfifo(model / "cluster_model.json")
    with pytest.raises(DataError, match=r"cluster_model.json: a FIFO, not a regular file"):
        load_model(model)


def test_an_agents_model_file_linked_from_outside_is_refused(tmp_path):
    """`pcpg export onnx` of an agents folder: files were read through links leaving it."""
    from pcpg_dist.api.export import load_agents_folder

    agents, outside = tmp_path / "agents", tmp_path / "outside"
    agents.mkdir()
    outside.mkdir()
    (outside / "E1.npz").write_bytes(b"")
    (agents / "E1.npz").symlink_to(outside / "E1.npz")
    with pytest.raises(DataError, match=r"agents folder .*E1.npz: a link to"):
        load_agents_folder(agents)
