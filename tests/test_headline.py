"""The figures README.md and docs/results/README.md quote are written by scripts/headline.py
from the files in docs/results: the pages must be in sync with them, and every relative link
of the results pages and the lab notebook must lead to a file."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest
from repo_paths import REPO, load_script


def load_headline():
    return load_script("scripts/headline.py")


def test_pages_quote_the_results_files() -> None:
    stale = load_headline().stale()
    assert not stale, f"{sorted(stale)}: figures out of date; run python scripts/headline.py"


def test_a_changed_result_makes_both_pages_stale(tmp_path: Path, monkeypatch) -> None:
    headline = load_headline()
    results = tmp_path / "results"
    shutil.copytree(REPO / "docs" / "results", results)
    csv = results / "heldout.csv"
    lines = csv.read_text().splitlines()
    i = next(i for i, x in enumerate(lines) if x.startswith("script,round6b_tuned,10,"))
    cells = lines[i].split(",")
    cells[4] = "0.123456"  # mean similarity
    lines[i] = ",".join(cells)
    csv.write_text("\n".join(lines) + "\n")
    monkeypatch.setattr(headline, "RESULTS", results)
    stale = headline.stale()
    assert sorted(stale) == ["README.md", "docs/results/README.md"]
    assert "scores 0.12 at N = 10" in stale["README.md"]
    assert "| script | 40 | **0.123** |" in stale["docs/results/README.md"]


def test_a_page_without_its_block_is_an_error(monkeypatch) -> None:
    headline = load_headline()
    monkeypatch.setitem(headline.PAGES, "README.md", {"no-such-block": lambda: ""})
    with pytest.raises(headline.SourceError, match="no-such-block"):
        headline.stale()


@pytest.mark.parametrize(
    "page", ["docs/results/README.md", "experiments/notes/README.md", "docs/results/demo.md"]
)
def test_relative_links_lead_to_files(page: str) -> None:
    text = (REPO / page).read_text(encoding="utf-8")
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    assert links
    for link in links:
        if not link.startswith(("http://", "https://")):
            assert ((REPO / page).parent / link).exists(), f"{page} links {link}"
