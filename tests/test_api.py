"""The public face: ``import pcpg_dist`` is light, every listed name resolves, and the Python
functions raise pcpg's own one-line errors (never SystemExit)."""

from __future__ import annotations

import subprocess
import sys

import pytest

import pcpg_dist


def test_every_public_name_resolves_and_is_listed():
    for name in pcpg_dist.__all__:
        assert getattr(pcpg_dist, name) is not None, name
    assert set(dir(pcpg_dist)) == set(pcpg_dist.__all__)
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        pcpg_dist.nope  # noqa: B018


def test_importing_the_face_imports_nothing_heavy():
    code = (
        "import sys, pcpg_dist; pcpg_dist.load_config; pcpg_dist.Domain; "
        "print(sorted(m for m in ('torch', 'ray', 'mlflow', 'optuna') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_a_bad_override_is_pcpg_error_naming_the_key(tmp_path):
    with pytest.raises(pcpg_dist.ConfigError, match="clustering.k"):
        pcpg_dist.run({"name": "x"}, ["clustering.k=0"], workdir=tmp_path, in_process=True)
    assert not (tmp_path / "x").exists()
