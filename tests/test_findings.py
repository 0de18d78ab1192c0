"""condor.findings: the findings measured outside the workflow, shipped as data with their
provenance (experiment folder, source table, commit), never as prose constants in the code."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import pytest

from condor import findings

REPO = Path(__file__).resolve().parents[1]


def test_every_shipped_finding_has_its_provenance_and_its_experiment_folder_exists():
    loaded = findings.load_findings()
    assert {"more_moulds", "paper_ladder", "out_of_domain"} <= set(loaded)
    for finding in loaded.values():
        assert (REPO / finding.experiment / "README.md").is_file(), finding.experiment
        assert re.fullmatch(r"[0-9a-f]{7,40}", finding.commit), finding.commit
        source = finding.source.split(" ")[0].rstrip(",")
        assert (REPO / source).is_file(), source


def test_record_finding_writes_its_table_and_entry_and_refuses_one_without_provenance(tmp_path):
    import pandas as pd

    path = tmp_path / "findings.json"
    path.write_text(json.dumps({"other": {"question": "q"}}))
    entry = {"question": "Q?", "table": "t.csv", "experiment": "experiments/x", "source": "s",
             "commit": "abc1234"}
    findings.record_finding("new", entry, pd.DataFrame({"a": [1.0 / 3]}), path=path)
    written = json.loads(path.read_text())
    assert written["new"] == entry and written["other"] == {"question": "q"}
    assert (tmp_path / "t.csv").read_text() == "a\n0.333333\n"
    for bad in ({**entry, "commit": ""}, {k: v for k, v in entry.items() if k != "table"}):
        with pytest.raises(ValueError, match="new"):
            findings.record_finding("new2", bad, pd.DataFrame({"a": [1]}), path=path)
    assert "new2" not in json.loads(path.read_text())


def test_a_findings_commit_is_in_the_history_when_the_repository_is_a_clone():
    done = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--git-dir"], capture_output=True)
    if done.returncode != 0:
        pytest.skip("not a git checkout")
    for finding in findings.load_findings().values():
        known = subprocess.run(["git", "-C", str(REPO), "cat-file", "-e",
                                f"{finding.commit}^{{commit}}"], capture_output=True)
        if known.returncode != 0:
            shallow = subprocess.run(["git", "-C", str(REPO), "rev-parse",
                                      "--is-shallow-repository"], capture_output=True, text=True)
            if shallow.stdout.strip() == "true":
                pytest.skip("shallow clone")
        assert known.returncode == 0, f"{finding.key}: no commit {finding.commit}"
        # a commit only on a side branch is in this object store but not in a clone of main
        ancestor = subprocess.run(["git", "-C", str(REPO), "merge-base", "--is-ancestor",
                                   finding.commit, "HEAD"], capture_output=True)
        assert ancestor.returncode == 0, f"{finding.key}: {finding.commit} is not in HEAD's history"


def test_the_more_moulds_sentence_is_computed_from_its_table():
    finding = findings.load_findings()["more_moulds"]
    table = finding.frame().set_index("name")
    words = findings.more_moulds_sentence(finding)
    assert f"{table.loc['d2060_e60', 'mean_Sx2:r']:.3f}" in words
    assert f"{table.loc['d774_e160', 'mean_Sx2:r']:.3f}" in words
    assert "774 -> 2,060 at 60 epochs" in words and finding.commit in words


def test_the_ladder_sentence_fills_its_values():
    finding = findings.load_findings()["paper_ladder"]
    assert "{" not in finding.sentence() and "1,000,000 moves per cell" in finding.sentence()
    assert finding.commit in finding.sentence()


def test_a_finding_without_provenance_or_numbers_is_refused(tmp_path):
    path = tmp_path / "findings.json"
    path.write_text(json.dumps({"x": {"question": "q", "experiment": "e", "source": "s",
                                      "statement": "a {v}", "values": {"v": 1}}}))
    with pytest.raises(ValueError, match="lacks \\['commit'\\]"):
        findings.load_findings(path)
    path.write_text(json.dumps({"x": {"question": "q", "experiment": "e", "source": "s",
                                      "commit": "abc1234"}}))
    with pytest.raises(ValueError, match="neither a table nor a statement"):
        findings.load_findings(path)
    path.write_text(json.dumps({"x": {"question": "q", "experiment": "e", "source": "s",
                                      "commit": "abc1234", "table": "missing.csv"}}))
    with pytest.raises(ValueError, match="no table"):
        findings.load_findings(path)


def test_the_report_states_no_measured_finding_as_a_constant():
    source = "".join(p.read_text() for p in (REPO / "src" / "condor" / "report").glob("*.py"))
    assert "condor_report" in source
    assert "PAPER_LADDER" not in source and "MORE_MOULDS" not in source
    assert "docs/data" not in source
    answer = (REPO / "src" / "condor" / "surrogate" / "answer.py").read_text()
    assert "OUT_OF_DOMAIN_MEASURED" not in answer and "dog-bone" not in answer


def test_the_out_of_domain_table_names_domain_table_counts_and_its_groups():
    from condor.moulds.paper import generate_mould
    from condor.model.scenes import get_scene
    from condor.surrogate.answer import domain_table, outside_counts

    scene = get_scene("default")
    properties = set(domain_table(generate_mould(1, 0, scene), scene)["property"])
    table = findings.load_findings()["out_of_domain"].frame()
    assert list(table.columns[:len(findings.OUT_OF_DOMAIN_COLUMNS)]) == \
        list(findings.OUT_OF_DOMAIN_COLUMNS)
    assert table["kind"].is_unique and (table["n_moulds"] >= 1).all()
    for row in table.itertuples():
        counts = outside_counts(row.outside_on)
        assert set(counts) <= properties, counts
        assert (row.kind == "inside") == (counts == ())
        for name in ("z", "spread_ratio", "coverage_90", "field_error"):
            low, value, high = (getattr(row, f"{name}_lo"), getattr(row, name),
                                getattr(row, f"{name}_hi"))
            assert low <= value <= high, (row.kind, name)
    # every count domain_table can put a mould outside on was measured on its own
    assert {c for r in table.itertuples() for c in outside_counts(r.outside_on)
            if len(outside_counts(r.outside_on)) == 1} == properties


def test_a_table_the_product_reads_is_checked_for_its_columns(tmp_path):
    columns = list(findings.OUT_OF_DOMAIN_COLUMNS)
    entry = {"question": "q", "experiment": "e", "source": "s", "commit": "abc1234",
             "table": "ood.csv"}
    path = tmp_path / "findings.json"
    path.write_text(json.dumps({"out_of_domain": entry}))
    (tmp_path / "ood.csv").write_text(",".join(columns[:-1]) + "\n")
    with pytest.raises(ValueError, match="lacks columns \\['noise_ceiling'\\]"):
        findings.load_findings(path)
    (tmp_path / "ood.csv").write_text(",".join(columns) + "\n" +
                                      ",".join(["area", "a"] + ["1"] * (len(columns) - 2)) + "\n")
    with pytest.raises(ValueError, match="no 'inside' row"):
        findings.load_findings(path)
    (tmp_path / "ood.csv").write_text(",".join(columns) + "\n" +
                                      ",".join(["inside", ""] + ["1"] * (len(columns) - 2)) + "\n")
    loaded = findings.load_findings(path)["out_of_domain"]  # read beside its findings.json
    assert loaded.frame()["kind"].tolist() == ["inside"]
