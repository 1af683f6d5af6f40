"""``roger table1`` and ``roger features`` end to end, as a user types them (in-process)."""

from __future__ import annotations

import csv
import json
import warnings
from pathlib import Path

import pytest
from conftest import WORLDS

from roger_bringup.cli import main
from roger_experiments import feature_report


def _roger(*argv: str) -> None:
    with pytest.raises(SystemExit) as done:
        main(list(argv))
    assert done.value.code == 0, argv


def test_table1_writes_the_papers_layout_for_the_four_boxes(tmp_path: Path, capsys) -> None:
    _roger("table1", "--world", str(WORLDS / "table1.yaml"), "--out", str(tmp_path))
    rows = json.loads((tmp_path / "table1.json").read_text())["rows"]
    assert [r["object"] for r in rows] == ["obj01", "obj02", "obj03", "obj04"]
    by_intensity = sorted(rows, key=lambda r: -r["intensity"])
    assert [r["I"] for r in by_intensity] == sorted((r["I"] for r in rows), reverse=True)
    for r in rows:  # the paper's 30 cm boxes read D 0.43-0.45
        assert r["looks"] >= 2 and 0.35 < r["D"] < 0.55, r
        assert set(r["paper"]) >= {"I", "D", "W"}
    assert rows[0]["W"] > rows[1]["W"] > rows[3]["W"]  # 1.5 kg > 1 kg > 0.5 kg
    table = (tmp_path / "table1.md").read_text()
    assert "paper" in table and "obj04" in table
    assert "obj01" in capsys.readouterr().out


def test_features_writes_its_table_looks_and_a_plot_without_warnings(tmp_path: Path) -> None:
    # W's ratio is infinite (no spread once felt): the plot once scaled its axis to 1e308
    # with an overflow warning, which hid every other bar.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _roger("features", "--world", str(WORLDS / "table1.yaml"), "--out", str(tmp_path))
    result = json.loads((tmp_path / "features.json").read_text())
    focus = result["focus_looks"]
    assert focus["features"][-1] == "W" and len(focus["ratio"]) == 11
    assert focus["objects"] == 4 and focus["looks"] >= 8
    assert result["segmentation"]["merges"] == 0
    assert (tmp_path / "features.png").stat().st_size > 10_000
    with (tmp_path / "looks.csv").open() as f:
        looks = list(csv.DictReader(f))
    assert len(looks) >= focus["looks"]
    assert "| I1 |" in (tmp_path / "features.md").read_text()


def test_the_ratio_plot_keeps_an_infinite_ratio_on_the_scale_of_the_others(tmp_path: Path
                                                                           ) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = ["I1", "D", "W"]
    result = {"world": "w.yaml", "ratio_target": 2.0, "focus_looks": {
        "features": names, "within": [0.02, 0.003, 0.0], "between": [0.1, 0.03, 0.2],
        "ratio": [5.0, 10.0, float("inf")]}}
    shown = {}
    real_savefig = plt.Figure.savefig

    def keep(fig, *args, **kwargs):
        shown["ylim"] = fig.axes[1].get_ylim()
        return real_savefig(fig, *args, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plt.Figure, "savefig", keep)
        feature_report.plot(result, tmp_path / "p.png")
    assert 10.0 < shown["ylim"][1] < 20.0, shown
