"""docs/benchmarks.md's result tables come from stored runs (``benchmarks/docs_tables.py``): the generator on a
small run written here, and the page itself: short, and every table what its stored run gives."""

from __future__ import annotations

import json

import pytest

from benchmarks import docs_tables
from tests.conftest import REPO

MAX_LINES = 400


def _row(case: str, origin: str, *, placed: bool | None, valid: bool, adds: float | None, status: str = "ok",
         method: str = "geometry") -> dict:
    metrics = {"placement_success": placed, "success": None if adds is None else adds <= 0.1, "valid": valid,
               "relation_holds": True, "adds": adds}
    if placed is not None:
        metrics["placement_at_k"] = True
    return {"case": case, "init": 0, "method": method, "protocol": "rigid", "seed": 0, "ablation": None,
            "preset": "default", "guide": None, "encoder": None, "copies": None, "origin": origin,
            "has_reference": placed is not None, "status": status, "time_s": 2.0, "metrics": metrics}


def _store(folder, rows: list[dict], command: str, date: str) -> None:
    folder.mkdir(parents=True)
    (folder / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    (folder / "commands.txt").write_text(command + "\n")
    (folder / "run.json").write_text(json.dumps({"machine": "test box: 2 cores", "date": date}))


def test_the_generator_writes_counts_command_machine_and_date(tmp_path):
    rows = [_row("a-1", "alpha", placed=True, valid=True, adds=0.05),
            _row("a-2", "alpha", placed=False, valid=True, adds=0.4),
            _row("a-3", "alpha", placed=None, valid=False, adds=None),
            _row("b-1", "beta", placed=True, valid=True, adds=0.2)]
    rows.append({**rows[1], "metrics": {**rows[1]["metrics"], "placement_success": True}})  # a retried row: last wins
    _store(tmp_path / "results" / "tiny", rows, "ctp bench CASES --method geometry --out OUT", "2030-01-02")
    doc = tmp_path / "bench.md"
    doc.write_text("# Results\n\nBefore.\n\n<!-- bench-table:tiny -->\nstale\n<!-- /bench-table -->\n\nAfter.\n")

    assert docs_tables.main(["--doc", str(doc), "--results", str(tmp_path / "results"), "--check"]) == 1
    assert docs_tables.main(["--doc", str(doc), "--results", str(tmp_path / "results")]) == 0
    text = doc.read_text()
    assert text.startswith("# Results\n\nBefore.\n") and text.endswith("<!-- /bench-table -->\n\nAfter.\n")
    assert "stale" not in text
    assert "ctp bench CASES --method geometry --out OUT" in text
    assert "2030-01-02" in text and "test box: 2 cores" in text
    lines = {line.split(" | ")[1]: line for line in text.splitlines() if line.startswith("| geometry")}
    # set | ok/runs | with reference | placement | placement@k | success | relation holds | valid | ADD-S median
    assert lines["alpha"].startswith("| geometry (default) | alpha | 3/3 | 2 | 2/2 | 2/2 | 1/2 | 3/3 | 2/3 | 0.225 |")
    assert lines["beta"].startswith("| geometry (default) | beta | 1/1 | 1 | 1/1 | 1/1 | 0/1 | 1/1 | 1/1 | 0.200 |")
    assert lines["**all**"].startswith("| geometry (default) | **all** | 4/4 | 3 | 3/3 | 3/3 | 1/3 | 4/4 | 3/4 |")
    assert docs_tables.main(["--doc", str(doc), "--results", str(tmp_path / "results"), "--check"]) == 0


def test_a_region_naming_no_stored_run_is_an_error(tmp_path):
    doc = tmp_path / "bench.md"
    doc.write_text("<!-- bench-table:missing -->\n<!-- /bench-table -->\n")
    with pytest.raises(KeyError, match="missing"):
        docs_tables.main(["--doc", str(doc), "--results", str(tmp_path / "results")])


def test_the_say_table_counts_the_guides_say_and_the_placements_it_gained_and_lost(tmp_path):
    base = [_row(f"a-{i}", "alpha", placed=i < 2, valid=True, adds=0.05) for i in range(4)]
    guided = [_row(f"a-{i}", "alpha", placed=i in (0, 2), valid=True, adds=0.05, method="ctp") for i in range(4)]
    for row, say in zip(guided, [0.0, 0.4, 1.0, 0.0], strict=True):
        row.update(guide="oracle", encoder="random:tiny", extra={"guide_say": {"override": say}})
    _store(tmp_path / "results" / "geo", base, "ctp bench X --method geometry", "2026-12-05")
    _store(tmp_path / "results" / "say", guided, "ctp bench X --guide oracle", "2026-12-05")
    doc = tmp_path / "bench.md"
    doc.write_text("<!-- say-table:geo:say -->\n<!-- /say-table -->\n")
    assert docs_tables.main(["--doc", str(doc), "--results", str(tmp_path / "results")]) == 0
    text = doc.read_text()
    # 2 of 4 with a say, 1 full, placed 2 of 4: a-2 gained, a-1 lost against the run without a guide
    assert "| `say` | oracle/random:tiny | 4 | 2 | 1 | 1.00 | 2/4 | a-2 | a-1 | 4/4 |" in text
    assert "`ctp bench X --method geometry`" in text and "`ctp bench X --guide oracle`" in text
    assert docs_tables.main(["--doc", str(doc), "--results", str(tmp_path / "results"), "--check"]) == 0
    doc.write_text("<!-- say-table:geo:gone -->\n<!-- /say-table -->\n")
    with pytest.raises(KeyError, match="gone"):
        docs_tables.main(["--doc", str(doc), "--results", str(tmp_path / "results")])


def test_a_run_without_machine_or_date_is_refused(tmp_path):
    _store(tmp_path / "r", [_row("a-1", "alpha", placed=True, valid=True, adds=0.05)], "ctp bench X", "")
    with pytest.raises(ValueError, match="date"):
        docs_tables.load_run(tmp_path / "r")


def test_docs_benchmarks_is_short_and_its_tables_are_what_the_stored_runs_give():
    text = docs_tables.DOC.read_text()
    assert len(text.splitlines()) <= MAX_LINES, f"docs/benchmarks.md has {len(text.splitlines())} lines"
    regions = [m.group(2) for m in docs_tables.REGION.finditer(text)]
    assert regions, "docs/benchmarks.md has no generated table"
    assert docs_tables.rewrite(text, docs_tables.stored_runs()) == text, (
        "docs/benchmarks.md's tables are stale: run make docs-bench (python benchmarks/docs_tables.py)")
    for name in regions:  # stored results only, never a mesh of the third-party bench data
        files = [p for p in (REPO / "benchmarks" / "results" / name).rglob("*") if p.is_file()]
        assert all(p.suffix in {".jsonl", ".txt", ".json", ".md"} for p in files), files
