"""``roger table1`` and ``roger features`` end to end, as a user types them (in-process)."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import WORLDS

from roger_bringup.cli import main
from roger_common.types import (
    FEATURE_NAMES,
    SHAPE_FEATURE_NAMES,
    WEIGHT_INDEX,
    FeatureMode,
    ObjectSpec,
    Roi,
    WorldSpec,
    feature_dim,
    feature_names,
)
from roger_experiments import feature_report, table1
from roger_memory.config import MemoryConfig


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
        _roger("features", "--world", str(WORLDS / "table1.yaml"), "--features", "paper",
               "--out", str(tmp_path))
    result = json.loads((tmp_path / "features.json").read_text())
    assert result["feature_mode"] == "paper"
    focus = result["focus_looks"]
    assert focus["features"] == list(FEATURE_NAMES) and len(focus["ratio"]) == 11
    assert result["all_looks"]["features"] == list(FEATURE_NAMES)
    assert focus["objects"] == 4 and focus["looks"] >= 8
    assert result["segmentation"]["merges"] == 0
    # The four 30 cm boxes placed within 3 cm of their centres (docs/perception.md).
    assert result["positions"]["looks"] >= 8 and result["positions"]["error_p95"] < 0.03
    assert (tmp_path / "features.png").stat().st_size > 10_000
    with (tmp_path / "looks.csv").open() as f:
        looks = list(csv.DictReader(f))
    assert len(looks) >= focus["looks"]
    for row in looks:  # which features were measured: W only after a haptic improvement
        assert len(row["known"]) == 11 and set(row["known"]) <= {"0", "1"}, row
        assert row["known"][-1] == row["W_known"], row
    assert {row["known"][-1] for row in looks} == {"0", "1"}
    assert list(looks[0])[9:21] == [*FEATURE_NAMES, "W_known"]
    text = (tmp_path / "features.md").read_text()
    assert "| I1 |" in text and "Feature mode: paper" in text
    assert "**Extended features**" not in text and "| H |" not in text
    assert "**Positions**" in text
    # The repeated looks at one fixation (3 by default): fresh pixel noise moves I1, not W
    # (felt once, carried at the place); they are rows of looks.csv but not in the spreads.
    noise = result["sensor_noise"]
    assert noise["visits"] >= 3 and noise["features"] == list(FEATURE_NAMES)
    assert noise["sd"][0] > 0.0 and noise["sd"][-1] == 0.0
    assert noise["ceiling"][0] == pytest.approx(focus["between"][0] / noise["sd"][0])
    rows = [row for row in looks if row["stage"] == feature_report.NOISE_STAGE]
    assert len(rows) >= 3 * noise["visits"] and all(int(row["place"]) >= 0 for row in rows)
    assert all(int(row["place"]) == -1 for row in looks if row["stage"] == "scan")
    assert "**Sensor noise**" in (tmp_path / "features.md").read_text()
    # The four boxes, each felt: every pair is one of two categories.
    sep = result["memory_separability"]
    assert sep["objects"] == 4 and sep["with_copies"] == 0 and not sep["apart_from_copies"]
    assert "**The memory's distance**" in (tmp_path / "features.md").read_text()


def test_features_refuses_a_negative_number_of_noise_looks(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit) as done:
        main(["features", "--world", str(WORLDS / "table1.yaml"), "--out", str(tmp_path),
              "--noise-looks", "-1"])
    assert done.value.code == 2
    assert "--noise-looks" in capsys.readouterr().err
    assert not (tmp_path / "features.json").exists()


def test_features_in_the_extended_mode_reports_the_shape_features_too(tmp_path: Path) -> None:
    # shapes.yaml: the four shapes, each once (the smallest world where H differs between
    # categories; table1's four equal boxes read one H).
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _roger("features", "--world", str(WORLDS / "shapes.yaml"), "--features", "extended",
               "--noise-looks", "2", "--out", str(tmp_path))
    result = json.loads((tmp_path / "features.json").read_text())
    names = list(feature_names(FeatureMode.EXTENDED))
    assert result["feature_mode"] == "extended"
    for key in ("focus_looks", "all_looks", "sensor_noise"):
        assert result[key]["features"] == names, key
    focus = result["focus_looks"]
    assert len(focus["ratio"]) == len(focus["within"]) == len(names) == feature_dim("extended")
    ratio = dict(zip(names, focus["ratio"], strict=True))
    assert math.isfinite(ratio["H"]) and ratio["H"] > 0.0, ratio["H"]
    # Felt, like W, after the haptic improvement every place gets: measured, never NaN.
    for f in ("TH", "TK", "TC"):
        assert not math.isnan(ratio[f]), (f, ratio[f])
    assert len(result["sensor_noise"]["ceiling"]) == feature_dim("extended")
    text = (tmp_path / "features.md").read_text()
    assert "Feature mode: extended" in text
    assert all(f"| {f} | " in text for f in SHAPE_FEATURE_NAMES)
    assert "**Extended features**: mean between/within ratio " in text
    assert "nan" not in text.split("**Extended features**")[1].split("\n")[0]
    with (tmp_path / "looks.csv").open() as f:
        looks = list(csv.DictReader(f))
    assert list(looks[0])[9:9 + len(names) + 1] == [*names, "W_known"]
    for row in looks:  # W_known is W's flag, not the last feature's (TC)
        assert len(row["known"]) == feature_dim("extended"), row
        assert row["known"][WEIGHT_INDEX] == row["W_known"], row


def _extended_look(obj: str, i1: float, touched: bool) -> feature_report.Look:
    """A look of the extended mode, W known; touch's shape only when ``touched``."""
    n = len(feature_names(FeatureMode.EXTENDED))
    features, known = np.full(n, 0.5), np.ones(n, bool)
    features[0] = i1
    for name in ("TH", "TK", "TC", "TR", "AP"):  # weighed without a tactile contact: unknown, 0
        k = feature_names(FeatureMode.EXTENDED).index(name)
        known[k], features[k] = touched, features[k] if touched else 0.0
    roi = Roi(0, (0, 0, 4, 4), (0.5, 0.0, 0.05), features, known)
    return feature_report.Look("shift", 0, True, obj, 1.0, (obj,), roi)


def test_a_feature_no_look_measured_is_reported_unknown_not_as_nan_or_zero_spread(
        tmp_path: Path) -> None:
    objects = tuple(ObjectSpec(n, "box", (0.5, y), 0.1, grey, 1.0)
                    for n, y, grey in (("a", -0.2, 60), ("b", 0.2, 120)))
    world = WorldSpec(objects)
    looks = [_extended_look(o, v + e, touched=False) for o, v in (("a", 0.3), ("b", 0.7))
             for e in (-0.01, 0.01)]
    log = feature_report.LookLog(world, looks, 4)
    assert log.feature_mode is FeatureMode.EXTENDED
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = feature_report.write(log, tmp_path)
    names = list(feature_names(FeatureMode.EXTENDED))
    s = result["focus_looks"]
    assert s["features"] == names and result["feature_mode"] == "extended"
    for f in ("TH", "TK", "TC", "TR", "AP"):  # NaN, not a within spread of 0 (ratio inf)
        k = names.index(f)
        assert math.isnan(s["within"][k]) and math.isnan(s["ratio"][k]), f
    # The measured features keep their spreads: I1's looks +-0.01 around 0.3 and 0.7.
    assert s["ratio"][0] == pytest.approx(np.std([0.3, 0.7], ddof=1)
                                          / np.sqrt(4 * 0.01 ** 2 / 2))
    text = (tmp_path / "features.md").read_text()
    for f in ("TH", "TK", "TC", "TR", "AP"):
        assert f"| {f} | unknown | - | - | - | - |" in text, f
    assert "| W | unknown" not in text and "| H | 0.0000 |" in text
    line = next(t for t in text.splitlines() if t.startswith("**Extended features**"))
    assert "unknown (never measured): TH, TK, TC, TR, AP" in line and "nan" not in line
    assert result["memory_separability"]["objects"] == 2  # W known: the memory's looks
    with (tmp_path / "looks.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [(r["W_known"], r["known"][WEIGHT_INDEX], r["known"][-1]) for r in rows] == \
        [("1", "1", "0")] * 4


def test_the_memory_of_another_mode_than_the_looks_is_refused() -> None:
    world = WorldSpec((ObjectSpec("a", "box", (0.5, 0.0), 0.1, 60, 1.0),))
    looks = [_extended_look("a", 0.3, touched=True)]
    with pytest.raises(feature_report.ConfigError, match="extended"):
        feature_report.memory_separability(looks, world, MemoryConfig.for_mode("paper"))
    assert feature_report.memory_separability(looks, world)["objects"] == 1


def test_the_ratio_plot_keeps_an_infinite_ratio_on_the_scale_of_the_others(tmp_path: Path
                                                                           ) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = ["I1", "D", "W"]
    result = {"world": "w.yaml", "ratio_target": 2.0, "focus_looks": {
        "features": names, "within": [0.02, 0.003, 0.0], "between": [0.1, 0.03, 0.2],
        "ratio": [5.0, 10.0, float("inf")], "copies": [0.01, float("nan"), 0.0]}}
    shown = {}
    real_savefig = plt.Figure.savefig

    def keep(fig, *args, **kwargs):
        shown["ylim"] = fig.axes[1].get_ylim()
        return real_savefig(fig, *args, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plt.Figure, "savefig", keep)
        feature_report.plot(result, tmp_path / "p.png")
    assert 10.0 < shown["ylim"][1] < 20.0, shown


def _look(obj: str, values: dict[int, float], known_d: bool = True) -> feature_report.Look:
    features = np.full(11, 0.5)
    for k, v in values.items():
        features[k] = v
    known = np.ones(11, bool)
    known[9] = known_d
    roi = Roi(0, (0, 0, 4, 4), (0.5, 0.0, 0.05), features, known)
    return feature_report.Look("shift", 0, True, obj, 1.0, (obj,), roi)


def test_copies_of_a_category_at_other_places_are_measured_apart_from_one_objects_looks(
) -> None:
    # Two categories of two copies. Looks of one object scatter by +-0.01 in I1; the
    # copies of category a read 0.40 and 0.50 (another bearing), those of b 0.80 and 0.80.
    objects = tuple(ObjectSpec(n, "box", (0.5, y), 0.1, grey, 1.0)
                    for n, y, grey in (("a0", -0.2, 60), ("a1", 0.2, 60),
                                       ("b0", -0.4, 120), ("b1", 0.4, 120)))
    world = WorldSpec(objects)
    i1 = {"a0": 0.40, "a1": 0.50, "b0": 0.80, "b1": 0.80}
    looks = [_look(o, {0: v + e}, known_d=o != "b1") for o, v in i1.items()
             for e in (-0.01, 0.01)]
    s = feature_report.feature_stats(looks, world)
    # Pooled over the categories: sqrt((2 * 0.05^2 + 0) / (1 + 1)) = 0.05.
    assert s["copies"][0] == pytest.approx(0.05, rel=1e-6)
    assert s["within"][0] == pytest.approx(np.sqrt(8 * 0.01 ** 2 / 4), rel=1e-6)
    # Category means 0.45 and 0.80: sd 0.2475; the copies are 0.05 apart.
    assert s["ratio_copies"][0] == pytest.approx(np.std([0.45, 0.8], ddof=1) / 0.05, rel=1e-6)
    # D unknown for b1: only a's two copies give its dof (no spread: equal values).
    assert s["copies"][9] == 0.0
    # W equal everywhere: no spread between copies.
    assert s["copies"][10] == 0.0
    # Copies of a are 0.1 apart in I1 (RMS over 11 features: 0.1 / sqrt(11)), of b 0.
    assert s["copy_distance_median"] == pytest.approx(0.5 * 0.1 / np.sqrt(11), rel=1e-6)
    text = feature_report.markdown({"world": "w", "frames": 1, "all_looks": s,
                                    "focus_looks": s, "ratio_target": 2.0,
                                    "segmentation": feature_report.segmentation_stats(looks)})
    assert "between-copies sd" in text and "| I1 |" in text


def test_sensor_noise_pools_one_fixations_looks_of_its_object_and_stays_out_of_the_spreads(
) -> None:
    objects = tuple(ObjectSpec(n, "box", (0.5, y), 0.1, grey, 1.0)
                    for n, y, grey in (("a", -0.2, 60), ("b", 0.0, 90), ("c", 0.2, 120)))
    world = WorldSpec(objects)

    def noisy(obj: str, i1: float, place: int, *, purity: float = 1.0,
              known_d: bool = True) -> feature_report.Look:
        lk = _look(obj, {0: i1, 9: 0.3}, known_d=known_d)
        return feature_report.Look(feature_report.NOISE_STAGE, 0, True, obj, purity,
                                   (obj,), lk.roi, place)

    # Place 0 shows a three times (I1 0.50, 0.52, 0.54: sd 0.02), b once (not the place's
    # object) and a once impurely; place 1 shows c twice alike, one look without D;
    # place 2 one look only (no spread to give).
    noise = [noisy("a", 0.50, 0), noisy("a", 0.52, 0), noisy("a", 0.54, 0),
             noisy("b", 0.90, 0), noisy("a", 0.99, 0, purity=0.5),
             noisy("c", 0.30, 1), noisy("c", 0.30, 1, known_d=False), noisy("b", 0.7, 2)]
    between = np.full(11, 0.1)
    s = feature_report.noise_stats(noise, between)
    assert s["visits"] == 2
    assert s["sd"][0] == pytest.approx(np.sqrt(2 * 0.02 ** 2 / (2 + 1)), rel=1e-9)
    assert s["ceiling"][0] == pytest.approx(0.1 / s["sd"][0], rel=1e-9)
    assert s["sd"][9] == 0.0 and math.isinf(s["ceiling"][9])
    # report(): the focus spreads are those of the other looks alone.
    shifts = [_look(o, {0: v}) for o, v in (("a", 0.5), ("a", 0.52), ("b", 0.9), ("c", 0.3))]
    with_noise = feature_report.report(feature_report.LookLog(world, shifts + noise, 9))
    without = feature_report.report(feature_report.LookLog(world, shifts, 4))
    for key in ("focus_looks", "all_looks", "segmentation", "positions"):  # NaN-aware
        assert json.dumps(with_noise[key]) == json.dumps(without[key]), key
    assert with_noise["sensor_noise"]["visits"] == 2 and without["sensor_noise"]["visits"] == 0
    text = feature_report.markdown(with_noise)
    assert "**Sensor noise**" in text and "ceiling" in text
    assert "**Sensor noise**" not in feature_report.markdown(without)


def test_memory_separability_names_objects_near_another_category_or_far_from_their_copies(
) -> None:
    objects = tuple(ObjectSpec(n, "box", (0.5, y), 0.1, grey, 1.0)
                    for n, y, grey in (("a0", -0.2, 60), ("a1", 0.2, 60), ("b0", 0.4, 90)))
    world = WorldSpec(objects)
    # a0 and b0 (two categories) differ by 0.01 in I1, a quarter of a category scale; a1,
    # a copy of a0's category, by 0.3 (I1 ~ 9 scales: beyond tau over all 11 features).
    looks = [_look("a0", {0: 0.5}), _look("a0", {0: 0.5}), _look("b0", {0: 0.51}),
             _look("a1", {0: 0.8})]
    unfelt = _look("b0", {0: 0.9})  # W unknown: not what a final trial sees
    unfelt.roi.known[10] = False
    s = feature_report.memory_separability(looks + [unfelt], world)
    assert s["objects"] == 3 and s["with_copies"] == 2
    assert sorted(r[:2] for r in s["taken_for_another"]) == [["a0", "b0"], ["b0", "a0"]]
    assert sorted(r[0] for r in s["apart_from_copies"]) == ["a0", "a1"]
    assert max(r[2] for r in s["taken_for_another"]) < s["tau"]
    assert min(r[1] for r in s["apart_from_copies"]) > s["tau"]
    c = s["closest"]
    assert c["distance"] == min(r[2] for r in s["taken_for_another"])
    assert c["repeats_beyond"] == 0.0 and c["copies_beyond"] == 1.0  # a0's looks are equal
    text = feature_report.markdown({"world": "w", "frames": 1, "ratio_target": 2.0,
                                    "all_looks": feature_report.feature_stats(looks, world),
                                    "focus_looks": feature_report.feature_stats(looks, world),
                                    "memory_separability": s,
                                    "segmentation": feature_report.segmentation_stats(looks)})
    assert "2 objects lie within tau of another category (" in text
    assert "2 of 2 lie beyond it from their own category's other copies (" in text


def test_memory_separability_keeps_a_look_with_ground_around_one_object_not_a_merge(
) -> None:
    # A round silhouette leaves a quarter of its ROI on the ground (purity 0.75 on random
    # 233's spheres): the memory is asked about such looks, so they count; a ROI that
    # shows two objects (each on >= MERGE_SHARE of it) does not.
    objects = tuple(ObjectSpec(n, "sphere", (0.5, y), 0.1, 60, 1.0)
                    for n, y in (("a0", -0.2), ("a1", 0.2), ("a2", 0.4)))
    world = WorldSpec(objects)

    def seen(obj: str, purity: float, merged: tuple[str, ...]) -> feature_report.Look:
        lk = _look(obj, {0: 0.5})
        return dataclasses.replace(lk, purity=purity, merged=merged)

    looks = [seen("a0", 0.75, ("a0",)), seen("a1", 0.72, ("a1",)),
             seen("a2", 0.6, ("a2", "a0"))]
    s = feature_report.memory_separability(looks, world)
    assert s["objects"] == 2 and s["with_copies"] == 2


def test_positions_are_scored_against_the_footprint_and_skip_cut_impure_and_merged_rois(
) -> None:
    world = WorldSpec((ObjectSpec("a", "box", (0.5, 0.0), 0.1, 60, 1.0),
                       ObjectSpec("b", "box", (0.8, 0.3), 0.1, 90, 1.0)))
    features, known = np.full(11, 0.5), np.ones(11, bool)

    def look(obj: str, x: float, y: float, *, cut: bool = False, purity: float = 1.0,
             merged: tuple[str, ...] | None = None) -> feature_report.Look:
        roi = Roi(0, (0, 0, 4, 4), (x, y, 0.05), features, known, cut=cut)
        return feature_report.Look("shift", 0, True, obj, purity,
                                   (obj,) if merged is None else merged, roi)

    looks = [look("a", 0.51, 0.0), look("a", 0.49, 0.0),      # 1 cm off, 1 cm from their mean
             look("a", 0.50, 0.0),                            # on the centre
             look("b", 0.8, 0.34),                            # 4 cm off, its only look
             look("a", 0.9, 0.9, cut=True), look("a", 0.9, 0.9, purity=0.5),
             look("b", 0.9, 0.9, merged=("a", "b"))]          # not scored
    p = feature_report.position_stats(looks, world)
    assert p["looks"] == 4
    assert p["error_median"] == pytest.approx(0.01)   # 0, 0.01, 0.01, 0.04
    assert p["error_max"] == pytest.approx(0.04)
    assert p["over_3cm"] == 1
    # a's three looks lie 0.01, 0.01 and 0 from their mean; b's one look shows no jitter.
    assert p["jitter_median"] == pytest.approx(0.01)
    assert p["jitter_p95"] == pytest.approx(0.01)
    assert feature_report.position_stats([], world)["looks"] == 0


def test_table1_means_a_feature_over_the_looks_that_measured_it() -> None:
    # obj01: two looks at the focus with I = 0.6 and D = 0.44, and one cut by the retina's
    # edge (I, T, S, D unknown and 0): the table must not average the zeros in.
    world = WorldSpec((ObjectSpec("obj01", "box", (0.6, 0.6), 0.3, 99, 1.5),))
    looks = [_look("obj01", {0: 0.6, 1: 0.6, 2: 0.6, 9: 0.44}) for _ in range(2)]
    cut = _look("obj01", {k: 0.0 for k in range(10)}, known_d=False)
    cut.roi.known[:10] = False
    log = feature_report.LookLog(world, [*looks, cut], 3)
    row = table1.table1(log)["rows"][0]
    assert row["looks"] == 3
    assert row["I"] == pytest.approx(0.6) and row["I_sd"] == pytest.approx(0.0, abs=1e-12)
    assert row["D"] == pytest.approx(0.44) and row["D_sd"] == pytest.approx(0.0, abs=1e-12)
    assert row["W"] == pytest.approx(0.5)  # felt at its position: known in all three
