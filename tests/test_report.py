"""The HTML report (condor.report) and the cost/accuracy chart (condor.costchart)."""

import base64
import html.parser
import re

import numpy as np
import pandas as pd
import pytest
from shapely.geometry import box

from condor import costchart, report, tradeoff
from condor.lattice import build_lattice
from condor.moulds import Mould
from condor.scenes import get_scene


def png(path, seed=0, size=(40, 30)):
    """A small PNG of random colours."""
    from PIL import Image

    pixels = np.random.default_rng(seed).integers(0, 255, size=(*size, 3), dtype=np.uint8)
    Image.fromarray(pixels).save(path)
    return path


class Parser(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.tags, self.images, self.anchors, self.ids = [], [], [], []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        self.tags.append(tag)
        if tag == "img":
            self.images.append(attrs["src"])
        if tag == "a":
            self.anchors.append(attrs["href"])
        if "id" in attrs:
            self.ids.append(attrs["id"])


def parse(text):
    p = Parser()
    p.feed(text)
    return p


# --- building blocks --------------------------------------------------------------------


def test_figure_embeds_the_exact_png_bytes(tmp_path):
    path = png(tmp_path / "a.png")
    block = report.figure(path, "a caption <with> markup")
    src = parse(block).images[0]
    assert src.startswith("data:image/png;base64,")
    assert base64.b64decode(src.split(",", 1)[1]) == path.read_bytes()
    assert "a caption &lt;with&gt; markup" in block  # escaped


def test_table_matches_the_csv(tmp_path):
    df = pd.DataFrame({"method": ["a", "b", "c"], "x": [1.234567, np.nan, 3e-7], "n": [1, 2, 3]})
    df.to_csv(tmp_path / "t.csv", index=False)
    block = report.table(tmp_path / "t.csv", "cap", digits=3)
    rows = re.findall(r"<tr>(.*?)</tr>", block)
    assert len(rows) == 1 + 3  # header + rows
    cells = [re.findall(r"<td>(.*?)</td>", r) for r in rows[1:]]
    assert cells[0] == ["a", "1.23", "1"] and cells[1][1] == "" and cells[2][1] == "3e-07"
    shortened = report.table(df, "cap", max_rows=2)
    assert len(re.findall(r"<tr>", shortened)) == 3 and "1 more rows" in shortened
    with pytest.raises(report.ReportError, match="nope"):
        report.table(df, "cap", columns=["method", "nope"])


def test_missing_inputs_and_empty_sections_are_errors(tmp_path):
    with pytest.raises(report.ReportError, match="missing.png"):
        report.figure(tmp_path / "missing.png", "x")
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(report.ReportError, match="empty.csv"):
        report.table(tmp_path / "empty.csv", "x")
    with pytest.raises(report.ReportError, match="Nothing here"):
        report.render("t", [report.Section("a", "A", [report.paragraph("x")]),
                            report.Section("b", "Nothing here", [])])


def test_render_links_every_section_from_the_contents():
    sections = [report.Section(f"s{k}", f"Section {k}", [report.paragraph(f"text {k}")])
                for k in range(4)]
    page = report.render("Title", sections, "meta")
    p = parse(page)
    assert p.anchors == [f"#s{k}" for k in range(4)]
    assert set(p.ids) == {f"s{k}" for k in range(4)}
    assert page.index("text 0") < page.index("text 3")


# --- the workflow's report, from synthetic inputs ----------------------------------------


def fake_inputs(tmp_path):
    d = tmp_path
    for name in ("gallery", "samples", "sa", "conv", "cost"):
        png(d / f"{name}.png", seed=len(name))
    pd.DataFrame({"sample": range(4), "split": ["train", "train", "val", "test"],
                  "status": ["ok", "ok", "ok", "folded: x"], "state": ["ok"] * 3 + ["failed"]}
                 ).to_csv(d / "summary.csv", index=False)
    pd.DataFrame({"regime": ["cyclic"], "share": [1.0], "paper_share": [0.2]}).to_csv(
        d / "regimes.csv", index=False)
    pd.DataFrame({"mould": [1, 2], "method": ["hybrid"] * 2}).to_csv(d / "sa.csv", index=False)
    pd.DataFrame({c: [1] for c in ["role", "method", "runs", "n_cells", "seconds", "rel_energy",
                                   "rel_energy_ref", "field_mae", "ok"]}).to_csv(d / "sas.csv", index=False)
    pd.DataFrame({"study": ["depth"], "value": [2.0], "baseline": [False], "rel_mean": [0.1]}
                 ).to_csv(d / "conv.csv", index=False)
    pd.DataFrame({"case": ["no tethers"], "solver": ["anneal"], "status": ["ok"],
                  "as_expected": [True], "what": ["valid"]}).to_csv(d / "stab.csv", index=False)
    pd.DataFrame({"family": ["hybrid"], "method": ["hybrid"], "seconds": [1.0]}).to_csv(
        d / "cost.csv", index=False)
    pd.DataFrame({"method": ["unet_eval"], "mae_P": [0.1]}).to_csv(d / "ssum.csv", index=False)
    ev = d / "evaluation" / "unet"
    (ev / "figures").mkdir(parents=True)
    png(ev / "figures" / "unet_eval_statistics.png", seed=9)
    pd.DataFrame({"statistic": ["mean_P"], "r": [0.9], "paper_r": [0.881]}).to_csv(
        ev / "unet_eval_correlations.csv", index=False)
    return report.ReportInputs(
        gallery=d / "gallery.png", regimes=d / "regimes.csv", samples=d / "samples.png",
        dataset_summary=d / "summary.csv", speed_accuracy=d / "sa.csv",
        speed_accuracy_summary=d / "sas.csv", speed_accuracy_chart=d / "sa.png",
        convergence=d / "conv.csv", convergence_summary=d / "conv.csv",
        convergence_chart=d / "conv.png", stability=d / "stab.csv", cost_accuracy=d / "cost.csv",
        cost_accuracy_chart=d / "cost.png", surrogate_summary=d / "ssum.csv",
        evaluations={"unet": ev})


def test_condor_report_has_every_section_with_content(tmp_path):
    inputs = fake_inputs(tmp_path)
    out = report.condor_report(inputs, {"scene": "tiny", "n_moulds": 4, "seed": 1},
                               tmp_path / "out" / "report.html")
    page = out.read_text()
    p = parse(page)
    expected = ["dataset", "moulds", "samples", "simulator", "convergence", "surrogate", "cost",
                "stability"]
    assert p.anchors == [f"#{s}" for s in expected]
    assert len(p.images) == 6  # gallery, samples, 3 charts, 1 evaluation figure
    assert all(src.startswith("data:image/png;base64,") for src in p.images)
    assert "src=\"http" not in page and "href=\"http" not in page  # self-contained
    assert "3 samples finished ok" in page and "0.881" in page and "no tethers" in page
    # A missing evaluation figure is an error, not a placeholder.
    (tmp_path / "evaluation" / "unet" / "figures" / "unet_eval_statistics.png").unlink()
    with pytest.raises(report.ReportError, match="figures"):
        report.condor_report(inputs, {}, tmp_path / "again.html")


@pytest.mark.skipif(report.find_chromium() is None, reason="no Chromium on PATH")
def test_report_renders_in_headless_chromium(tmp_path):
    out = report.condor_report(fake_inputs(tmp_path), {"scene": "tiny"}, tmp_path / "r.html")
    shot = report.screenshot(out, tmp_path / "r.png", width=1000, height=2500)
    coverage = report.screenshot_coverage(shot)
    assert coverage["width"] == 1000 and coverage["height"] == 2500
    assert coverage["rows_with_ink"] > 0.3  # text and images drawn down the page
    blank = tmp_path / "blank.html"
    blank.write_text("<html><body></body></html>")
    assert report.screenshot_coverage(report.screenshot(blank, tmp_path / "b.png"))["ink_fraction"] == 0


# --- cost per mould against error --------------------------------------------------------


def test_field_errors_brute_force():
    rng = np.random.default_rng([3, 1])
    raw = rng.random((2, 8, 5, 6))
    reference = rng.random((2, 8, 5, 6))
    expected = []
    for s in range(2):
        total = sum(raw[s, 0, y, x] for y in range(5) for x in range(6))
        norm = raw[s] * 30 / total
        expected.append(np.mean([abs(norm[c, y, x] - reference[s, c, y, x])
                                 for c in range(8) for y in range(5) for x in range(6)]))
    assert np.allclose(costchart.field_errors(raw, reference), expected)
    raw[1, 0] = 0.0  # no predicted density: undefined normalisation
    assert np.isnan(costchart.field_errors(raw, reference)[1])
    with pytest.raises(ValueError, match="differ"):
        costchart.field_errors(raw[:, :4], reference)


def test_predictor_rows_score_a_perfect_and_a_shifted_predictor():
    rng = np.random.default_rng([4, 2])
    reference = rng.random((3, 8, 4, 4)) + 0.1
    n_cells = np.array([10.0, 20.0, 30.0])
    # raw fields whose normalisation gives back the reference exactly
    raw = reference * n_cells[:, None, None, None] / 16
    raw[:, 0] *= 16 * n_cells[:, None, None] / (16 * raw[:, 0].sum(axis=(1, 2))[:, None, None])
    reference[:, 0] = raw[:, 0] * 16 / n_cells[:, None, None]
    inputs = np.arange(3)[:, None, None, None] * np.ones((3, 2, 4, 4))
    lookup = lambda x: raw[int(x[0, 0, 0, 0])][None]  # noqa: E731
    rows = costchart.predictor_rows("perfect", "surrogate", lookup, inputs, reference, [7, 8, 9])
    assert [r["mould"] for r in rows] == [7, 8, 9]
    assert np.allclose([r["field_mae"] for r in rows], 0, atol=1e-12)
    assert all(r["seconds"] >= 0 and r["status"] == "ok" for r in rows)
    shifted = lambda x: lookup(x) + np.r_[0, np.full(7, 0.5)][None, :, None, None] * n_cells[int(x[0, 0, 0, 0])] / 16  # noqa: E731
    rows = costchart.predictor_rows("shifted", "surrogate", shifted, inputs, reference, [7, 8, 9])
    assert np.allclose([r["field_mae"] for r in rows], 0.5 * 7 / 8)


def test_cost_table_medians_and_ranges():
    rows = [dict(mould=m, method=meth, family=fam, seconds=s, field_mae=e, status="ok")
            for m, meth, fam, s, e in [(1, "hybrid", "hybrid", 2.0, 0.1), (2, "hybrid", "hybrid", 4.0, 0.3),
                                       (3, "hybrid", "hybrid", 9.0, 0.2), (1, "unet", "surrogate", 0.01, 0.5),
                                       (1, "anneal 1e4", "long anneal", 30.0, 0.05)]]
    table = costchart.cost_table(rows)
    assert list(table["method"]) == ["anneal 1e4", "hybrid", "unet"]  # family order
    hybrid = table.set_index("method").loc["hybrid"]
    assert (hybrid["moulds"], hybrid["seconds"], hybrid["seconds_min"], hybrid["seconds_max"]) == (3, 4.0, 2.0, 9.0)
    assert hybrid["field_mae"] == pytest.approx(0.2)


def test_reference_is_reproduced_and_chart_is_drawn(tmp_path):
    """costchart's reference is the sweep's (same energy, zero field MAE against it), and the
    simulation rows carry the sweep's costs and errors into the chart."""
    scene = get_scene("tiny", depth=1.5)
    tethers = np.array([[3.5, 5.0, 0.9], [7.5, 5.0, 0.9]])
    mould = Mould(mould_id=0, seed=0, symmetry="dihedral", order=2, removal="none",
                  box=scene.box, polygon=box(2, 2, 9, 8), tethers=tethers, origin=(5.5, 5.0),
                  unpruned_tethers=tethers)
    methods = [tradeoff.Method("anneal 10", "anneal", 10.0)]
    df, fields = costchart.sweep_with_reference(scene, mould, (10,), (1,), 200.0)
    df2 = tradeoff.sweep(scene, moulds=[mould], methods=methods, reference_budget=200.0)
    ref = df2[df2["role"] == "reference"].iloc[0]
    assert df["reference_check"].iloc[0] == pytest.approx(0, abs=1e-12)
    lattice = build_lattice(mould.polygon, mould.tethers, scene.depth)
    again = costchart.reference_result(lattice, 200.0)
    assert again.energy_per_cell == pytest.approx(ref["energy_per_cell"], rel=1e-12)
    mine = tradeoff.normalised_fields(again, scene.box, scene.pixels, scene.sigma)
    assert np.array_equal(mine, fields)
    rows = costchart.simulation_rows(df)
    assert "tight minimiser" not in {r["family"] for r in rows}
    assert {"reference", "long anneal", "anneal", "minimise", "hybrid"} <= {r["family"] for r in rows}
    assert [r["field_mae"] for r in rows if r["family"] == "reference"] == [0.0]
    table = costchart.cost_table(rows)
    costchart.chart(table, tmp_path / "cost.png")
    assert (tmp_path / "cost.png").stat().st_size > 10_000
