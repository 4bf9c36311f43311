"""Every relative link and ``#anchor`` in README.md and docs/*.md leads somewhere (GitHub's rules)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
_FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)
_CODE = re.compile(r"`[^`\n]*`")
_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_HEADING = re.compile(r"^#{1,6}\s+(.*?)\s*#*\s*$", re.M)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces become hyphens."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link in a heading: its text
    text = re.sub(r"<[^>]+>", "", text).lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for heading in _HEADING.findall(_FENCE.sub("", page.read_text())):
        base = slug(heading)
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    out |= set(re.findall(r"<a\s+(?:name|id)=\"([^\"]+)\"", page.read_text()))
    return out


def links(page: Path) -> list[str]:
    text = _CODE.sub("", _FENCE.sub("", page.read_text()))
    return [
        t for t in _LINK.findall(text) if not re.match(r"^[a-z][a-z0-9+.-]*:", t)
    ]  # not http:, mailto:


def test_slugs_follow_github():
    assert (
        slug("Own logs at scale (`benchmarks/bench_trajectories.py`)")
        == "own-logs-at-scale-benchmarksbench_trajectoriespy"
    )
    assert slug("Step B: ranking — p and k") == "step-b-ranking--p-and-k"
    assert slug("Reproducing a run") == "reproducing-a-run"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_relative_links_and_anchors_resolve(page):
    broken = []
    for target in links(page):
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            broken.append(
                f"{target}: no file {dest.relative_to(ROOT) if dest.is_relative_to(ROOT) else dest}"
            )
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            broken.append(f"{target}: no heading with that anchor in {dest.name}")
    assert not broken, f"{page.name}: " + "; ".join(broken)


def test_the_user_guide_lists_every_config_section():
    from pcpg_dist.config.experiment import config_class
    from pcpg_dist.domains import registry

    sections = {key for domain in registry.BUILTIN for key in config_class(domain).model_fields}
    text = (ROOT / "docs" / "user-guide.md").read_text()
    table = text.split("| section | what it controls |", 1)[1].split("\n\n", 1)[0]
    listed = {
        k for row in table.splitlines()[2:] for k in re.findall(r"`(\w+)`", row.split("|")[1])
    }
    assert sections <= listed, sections - listed
