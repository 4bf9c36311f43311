"""Error lines stay short when the user's input is huge: a value a message echoes is cut to its
head, ``…`` and its tail, so the line still names the key, the file and the hint."""

from __future__ import annotations

from pathlib import Path

import pytest

from pcpg_dist.cli import main
from pcpg_dist.common.errors import shorten

ROOT = Path(__file__).resolve().parent.parent
QUICK = str(ROOT / "experiments" / "quick.yaml")
LONG = "x" * 5000


def test_shorten_cuts_long_words_and_keeps_the_rest():
    assert shorten("key 'a': value 'b' is not allowed") == "key 'a': value 'b' is not allowed"
    line = shorten(f"cannot access /tmp/{LONG}/run.json: File name too long")
    assert line.startswith("cannot access /tmp/xxx") and line.endswith(
        "/run.json: File name too long"
    )
    assert "…" in line and len(line) < 300
    # a long value with spaces in it: the line is cut in the middle, its end (the hint) kept
    spaced = shorten("value '" + "ab " * 3000 + "' is not allowed; use 1..5")
    assert len(spaced) < 1100 and spaced.endswith("is not allowed; use 1..5")
    # line by line: argparse's usage lines stay as they are
    assert shorten("usage: pcpg [-h]\n" + LONG).splitlines()[0] == "usage: pcpg [-h]"


@pytest.mark.parametrize(
    ("argv", "keeps"),
    [
        (["report", LONG], "/run.json: File name too long"),  # was the 5,000 characters whole
        (["run", LONG], ": cannot read config (File name too long)"),
        (["sweep", QUICK, f"bc.lr=1,{LONG}"], "quick.yaml with bc.lr=xxx"),
        (["run", QUICK, f"name={LONG}"], "key 'name'"),
    ],
)
def test_cli_error_line_cuts_a_5000_character_value(argv, keeps, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("pcpg: error: "), err
    assert keeps in err[0] and len(err[0]) < 500, err[0][:1000]


@pytest.mark.parametrize(
    ("argv", "keeps"),
    [
        ([LONG], "argument COMMAND: invalid choice: 'xxx"),
        (["run", QUICK, "--out", LONG], "unrecognized arguments: --out xxx"),
    ],
)
def test_argparse_error_line_cuts_a_5000_character_value(
    argv, keeps, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0].startswith("usage: pcpg") and err[-1].startswith("pcpg: error: "), err
    assert keeps in err[-1] and len(err[-1]) < 500, err[-1][:1000]
