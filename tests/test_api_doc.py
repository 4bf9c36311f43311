"""docs/api.md's worked example, run as a notebook would: its ``python`` blocks in order, in one
namespace, in an empty folder; each block's printed lines must be the ``# ...`` lines it shows."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "api.md"

pytestmark = pytest.mark.slow


def worked_blocks() -> list[str]:
    text = DOC.read_text().split("## A worked example", 1)[1]
    return re.findall(r"```python\n(.*?)```", text, re.S)


def test_the_worked_example_prints_what_the_doc_says(ray_session, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    blocks = worked_blocks()
    assert len(blocks) == 4
    namespace: dict = {}
    for block in blocks:
        shown = [line[2:] for line in block.splitlines() if line.startswith("# ")]
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed):
            exec(compile(block, str(DOC), "exec"), namespace)
        assert printed.getvalue().splitlines() == shown, block
    assert (tmp_path / "E1_styles.csv").is_file()
