"""The documentation stands alone: every relative link in README.md, docs/ and results/README.md
resolves inside the repository, and nothing sends a reader to a folder outside it."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LINK = re.compile(r"\]\(([^)\s]+)\)")
# Pages another change adds; a link to one is checked as soon as the page exists.
PENDING: set[Path] = set()


def _pages() -> list[Path]:
    return [ROOT / "README.md", ROOT / "results" / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _anchors(page: Path) -> set[str]:
    """GitHub's anchors of the page's headings: lower case, punctuation dropped, spaces to hyphens."""
    found = set()
    for line in page.read_text().splitlines():
        if m := re.match(r"#+ (.*)", line):
            words = re.sub(r"[^\w\- ]", "", m.group(1).strip().lower())
            found.add(words.replace(" ", "-"))
    return found


def test_every_relative_link_resolves_inside_the_repository():
    broken = []
    for page in _pages():
        for target in LINK.findall(page.read_text()):
            if target.startswith(("http://", "https://", "mailto:")):
                continue
            path, _, anchor = target.partition("#")
            resolved = (page.parent / path).resolve() if path else page
            where = f"{page.relative_to(ROOT)} -> {target}"
            if ROOT not in (resolved, *resolved.parents):
                broken.append(f"{where}: outside the repository")
            elif not resolved.exists():
                if resolved not in PENDING:
                    broken.append(f"{where}: no such file")
            elif anchor and resolved.suffix == ".md" and anchor not in _anchors(resolved):
                broken.append(f"{where}: no heading with that anchor")
    assert not broken, "\n".join(broken)


def test_nothing_in_the_repository_sends_a_reader_to_shared_docs():
    tracked = subprocess.run(
        ["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout.split("\0")
    needle = "shared/" + "docs"  # written in two parts so that this file does not match itself
    hits = []
    for name in filter(None, tracked):
        path = ROOT / name
        if path.suffix in {".png", ".safetensors", ".npy"} or not path.is_file():
            continue
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        if needle in text:
            hits.append(name)
    assert not hits, f"{hits} refer to {needle}, which is not part of the repository"
