"""The result tables in README.md and docs/ are what scripts/results_tables.py makes from results/,
and results/README.md indexes every result file."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


def _script():
    spec = importlib.util.spec_from_file_location("results_tables", ROOT / "scripts" / "results_tables.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_committed_table_is_what_the_script_makes():
    tables = _script()
    stale = []
    for path in tables.documents():
        text = path.read_text()
        if tables.render(text, tables.base_of(path)) != text:
            stale.append(str(path.relative_to(ROOT)))
    assert not stale, f"run scripts/results_tables.py: stale tables in {stale}"
    assert tables.main(["--check"]) == 0


def test_the_readme_and_the_docs_hold_every_table():
    tables = _script()
    found = {}
    for path in tables.documents():
        for name in re.findall(r"<!-- table:([\w-]+) -->", path.read_text()):
            found.setdefault(name, []).append(path.relative_to(ROOT).as_posix())
    assert set(found) == set(tables.TABLES)
    assert "README.md" in found["summary"]


def test_a_figure_edited_by_hand_is_caught(tmp_path):
    tables = _script()
    readme = (ROOT / "README.md").read_text()
    start = readme.index("<!-- table:summary -->")
    figure = re.compile(r"\d\.\d{3}").search(readme, start)
    edited = readme[: figure.start()] + "9.999" + readme[figure.end() :]
    assert tables.render(edited, "") == readme
    assert tables.render(edited, "") != edited


def test_an_unknown_table_name_is_refused():
    tables = _script()
    try:
        tables.render("<!-- table:nonsense -->\n<!-- /table:nonsense -->", "")
    except SystemExit as exc:
        assert "unknown table 'nonsense'" in str(exc)
    else:
        raise AssertionError("an unknown table was accepted")


def test_results_readme_indexes_every_result_file_and_only_existing_ones():
    index = (RESULTS / "README.md").read_text()
    linked = {(RESULTS / target).resolve() for target in LINK.findall(index) if not target.startswith(("..", "http"))}
    files = {p.resolve() for p in RESULTS.rglob("*") if p.is_file() and p.name != "README.md"}
    missing = sorted(str(p.relative_to(RESULTS)) for p in files - linked)
    dangling = sorted(str(p.relative_to(RESULTS)) for p in linked - files)
    assert not missing, f"results/README.md needs a line for each of {missing}"
    assert not dangling, f"results/README.md links to files that do not exist: {dangling}"
