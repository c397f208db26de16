"""The user documentation stays a quick start and a guide: README <= 150 lines without commit hashes,
docs/bias-network.md <= 400 lines, every relative link of README.md and docs/README.md resolves, and every
decision record is listed in docs/decisions/README.md."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def test_readme_is_a_quick_start_without_commit_hashes() -> None:
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 150
    hashes = [w for w in re.findall(r"\b[0-9a-f]{7,40}\b", text) if re.search(r"[a-f]", w) and re.search(r"\d", w)]
    assert hashes == []
    for heading in ("## 1. The demo", "## 2. A board on a port", "## 3. pytest on the board", "## 4. Reading a report",
                    "## 5. Where the data comes from"):
        assert heading in text
    assert "UWB_HIL_DATA" in text and "docs/README.md" in text


def test_the_bias_network_guide_is_short() -> None:
    assert len((ROOT / "docs" / "bias-network.md").read_text().splitlines()) <= 400


def test_links_of_the_indexes_resolve() -> None:
    for index in (ROOT / "README.md", ROOT / "docs" / "README.md", ROOT / "docs" / "decisions" / "README.md"):
        targets = [t for t in LINK.findall(index.read_text()) if "://" not in t]
        assert targets, index
        missing = [t for t in targets if not (index.parent / t).exists()]
        assert missing == [], f"{index.relative_to(ROOT)}: {missing}"


def test_every_decision_record_is_listed() -> None:
    decisions = ROOT / "docs" / "decisions"
    listed = set(LINK.findall((decisions / "README.md").read_text()))
    records = {p.name for p in decisions.glob("*.md") if p.name != "README.md"}
    assert records and records <= listed
    assert all(re.fullmatch(r"\d{4}-\d{2}-\d{2}-[a-z0-9-]+\.md", name) for name in records)
