"""The same config gives the same numbers as before the domain-seam redesign, in all three domains.

``tests/reference/metrics.json`` was written by the code before the redesign (see
tests/reference/configs.py); every metric must match (timings excluded).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.reference.configs import run_all

HERE = Path(__file__).resolve().parent / "reference"


@pytest.mark.slow
def test_metrics_equal_the_stored_reference(ray_session, tmp_path) -> None:
    expected = json.loads((HERE / "metrics.json").read_text())
    got = run_all(tmp_path)
    for domain, ref in expected.items():
        # a metric may be added by later work (e.g. a new table); none may vanish or change
        missing = sorted(set(ref) - set(got[domain]))
        assert not missing, f"{domain}: metrics gone: {missing[:5]}"
        changed = {k: (ref[k], got[domain][k]) for k in ref if got[domain][k] != pytest.approx(ref[k], rel=1e-6, abs=1e-9)}
        assert not changed, f"{domain}: {len(changed)} metrics changed, e.g. {list(changed.items())[:3]}"
