"""condor.surrogate.answer's domain verdict: where a mould sits against the training moulds and,
outside, what the out-of-domain study measured for its counts, read from a findings table
(never from numbers in the code)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from shapely.geometry import box as shapely_box

from condor import findings
from condor.data.drawings import place_mould
from condor.data.moulds import generate_mould
from condor.model.scenes import get_scene
from condor.surrogate.answer import domain_table, domain_verdict

SCENE = get_scene("tiny")
AREA, TETHERS = "area / box area", "tethers"


def _row(kind, outside_on, description, n, k, z, coverage):
    return {"kind": kind, "outside_on": outside_on, "description": description, "n_moulds": n,
            "replicas": 4, "z": z, "z_lo": z / 2, "z_hi": z * 2, "spread_ratio": k,
            "spread_ratio_lo": k - 0.3, "spread_ratio_hi": k + 0.5, "coverage_90": coverage,
            "coverage_90_lo": coverage - 0.1, "coverage_90_hi": coverage + 0.05,
            "field_error": 0.2, "field_error_lo": 0.1, "field_error_hi": 0.3,
            "noise_ceiling": 0.15}


def _verdict(tmp_path, table, rows):
    """domain_verdict of `table` against a findings.json whose out_of_domain table holds
    `rows`, read by the findings loader as `condor predict` reads the shipped one."""
    pd.DataFrame(rows).to_csv(tmp_path / "ood.csv", index=False)
    (tmp_path / "findings.json").write_text(json.dumps({"out_of_domain": {
        "question": "q", "table": "ood.csv", "experiment": "experiments/out_of_domain",
        "source": "experiments/out_of_domain/out_of_domain_tiny.csv", "commit": "abc1234"}}))
    finding = findings.load_findings(tmp_path / "findings.json")["out_of_domain"]
    return domain_verdict(table, finding.frame(), f"{finding.experiment} at {finding.commit}")


ROWS = [_row("inside", "", "inside moulds", 8, 1.1, 0.4, 0.88),
        _row("area", AREA, "moulds of another area", 5, 1.7, 1.3, 0.71),
        _row("dogbone", f"{AREA}; {TETHERS}", "dog-bones", 3, 2.5, 3.1, 0.52)]


def _two_post_mould():
    """A small bar with two posts: outside on the area and on the tether count."""
    return place_mould(shapely_box(0, 0, 9, 3), np.array([[1.5, 1.5, 0.5], [7.5, 1.5, 0.5]]),
                       SCENE)


def test_a_mould_outside_on_two_counts_reads_each_counts_measured_row(tmp_path):
    table = domain_table(_two_post_mould(), SCENE)
    assert list(table.loc[~table["inside"], "property"]) == [AREA, TETHERS]
    verdict = _verdict(tmp_path, table, ROWS)
    assert verdict.startswith("OUTSIDE the training domain on 2 of 5 counts")
    assert "(experiments/out_of_domain at abc1234; medians over moulds, 95% intervals)" in verdict
    assert (f"{AREA}: 5 moulds of another area: the statistics are off by 1.3 [0.65, 2.6] of "
            "their predicted spreads, one simulation scatters 1.7x [1.4, 2.2] the predicted "
            "spread, the 90% intervals hold 71% [61%, 76%] of the simulated pixels") in verdict
    assert f"{TETHERS}: not measured" in verdict  # no group outside on the tether count alone
    assert f"{AREA} and {TETHERS} together: 3 dog-bones: the statistics are off by 3.1" in verdict
    assert "Inside it, on 8 inside moulds: the statistics are off by 0.4" in verdict
    assert verdict.endswith("Simulate it (condor simulate) to be sure")


def test_a_group_outside_on_one_count_answers_for_that_count(tmp_path):
    rows = ROWS + [_row("tethers", TETHERS, "moulds with 1-3 tethers", 6, 1.3, 0.9, 0.8)]
    verdict = _verdict(tmp_path, domain_table(_two_post_mould(), SCENE), rows)
    assert (f"{TETHERS}: 6 moulds with 1-3 tethers: the statistics are off by 0.9 [0.45, 1.8] "
            "of their predicted spreads, one simulation scatters 1.3x [1, 1.8]") in verdict
    assert "not measured" not in verdict


def test_per_statistic_columns_name_the_statistics_whose_spreads_err_most(tmp_path):
    rows = [dict(r) for r in ROWS]
    rows[1].update({"z_alignment": 4.5, "z_mean_tension": 0.5, "spread_ratio_alignment": 2.5,
                    "spread_ratio_mean_tension": 0.25})
    verdict = _verdict(tmp_path, domain_table(_two_post_mould(), SCENE), rows)
    assert ("5 moulds of another area: the statistics are off by 1.3 [0.65, 2.6] of their "
            "predicted spreads (the most, alignment, by 4.5), one simulation scatters 1.7x "
            "[1.4, 2.2] the predicted spread (from 0.25x for mean_tension to 2.5x for "
            "alignment)") in verdict


def test_a_mould_inside_the_domain_needs_no_measurement():
    mould = generate_mould(7, 3, box=SCENE.box, area_fraction=SCENE.area_fraction,
                           max_extent=SCENE.max_extent)
    table = domain_table(mould, SCENE)
    if not table["inside"].all():
        pytest.skip("this generated mould has a tether the tiny grid misses")
    assert domain_verdict(table).startswith("inside the training domain on all 5")


def test_without_a_measurement_the_verdict_says_so():
    verdict = domain_verdict(domain_table(_two_post_mould(), SCENE))
    assert "Not measured out of the domain. Simulate it" in verdict


def test_the_shipped_table_answers_for_each_count_of_a_two_post_mould():
    finding = findings.load_findings()["out_of_domain"]
    frame = finding.frame()
    verdict = domain_verdict(domain_table(_two_post_mould(), SCENE), frame,
                             f"{finding.experiment} at {finding.commit}")
    assert f"experiments/out_of_domain at {finding.commit}" in verdict
    inside = frame.set_index("kind").loc["inside"]
    assert f"Inside it, on {int(inside['n_moulds'])} {inside['description']}" in verdict
    for count in (AREA, TETHERS):
        assert f"{count}: not measured" not in verdict
