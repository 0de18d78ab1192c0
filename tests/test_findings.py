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
    assert {"more_moulds", "paper_ladder"} <= set(loaded)
    for finding in loaded.values():
        assert (REPO / finding.experiment / "README.md").is_file(), finding.experiment
        assert re.fullmatch(r"[0-9a-f]{7,40}", finding.commit), finding.commit
        source = finding.source.split(" ")[0].rstrip(",")
        assert (REPO / source).is_file(), source


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
    source = (REPO / "src" / "condor" / "report.py").read_text()
    assert "PAPER_LADDER" not in source and "MORE_MOULDS" not in source
    assert "docs/data" not in source
