"""World files: the shipped worlds load, round-trip, and every bad file gives one clear line."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from roger_common.errors import WorldFileError
from roger_sim.world import (
    in_reach,
    load_world,
    object_from_dict,
    parse_world,
    reach_distance,
    world_to_dict,
)
from roger_sim.worldgen import random_world

WORLDS = Path(__file__).resolve().parents[1] / "worlds"

GOOD = {
    "name": "tiny",
    "light": {"direction": [1.0, 0.5, 1.0]},
    "objects": [
        {"name": "a", "shape": "box", "position": [0.7, 0.3], "size": 0.2, "intensity": 99,
         "weight": 1.5},
        {"name": "b", "shape": "sphere", "position": [0.7, -0.3], "size": 0.2,
         "intensity": 59, "weight": 0.5, "yaw": 0.4, "texture": "checker"},
    ],
}


def _write(tmp_path: Path, data: object) -> Path:
    path = tmp_path / "world.yaml"
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data), encoding="utf-8")
    return path


def _with(index: int, **fields: object) -> dict:
    data = yaml.safe_load(yaml.safe_dump(GOOD))
    for key, value in fields.items():
        if value is None:
            del data["objects"][index][key]
        else:
            data["objects"][index][key] = value
    return data


def test_table1_matches_the_paper() -> None:
    world = load_world(WORLDS / "table1.yaml")
    objs = {o.name: o for o in world.objects}
    assert [objs[f"obj0{i}"].intensity for i in range(1, 5)] == [99, 79, 69, 59]
    assert len({o.size for o in world.objects}) == 1
    weights = [objs[f"obj0{i}"].weight for i in range(1, 5)]
    assert weights == pytest.approx([1.5, 1.0, 1.0, 0.5])
    assert world.name == "table1" and world.light_direction == (1.0, 0.5, 1.0)


def test_other_shipped_worlds() -> None:
    rows = load_world(WORLDS / "two_rows.yaml")
    assert len(rows.objects) >= 8
    categories = [o.category() for o in rows.objects]
    assert len(set(categories)) < len(categories)  # categories repeat
    shapes = load_world(WORLDS / "shapes.yaml")
    assert {o.shape for o in shapes.objects} == {"box", "cylinder", "sphere", "prism"}
    assert {"stripes", "checker"} <= {o.texture for o in shapes.objects}


@pytest.mark.parametrize("name", ["table1", "two_rows", "shapes", "beyond_reach"])
def test_round_trip(name: str) -> None:
    world = load_world(WORLDS / f"{name}.yaml")
    again = parse_world(world_to_dict(world), world.source)
    assert again == world


def test_defaults_and_object_from_dict() -> None:
    world = parse_world({"objects": [GOOD["objects"][0]]}, "x/named.yaml")
    assert world.name == "named"
    assert world.light_direction == (1.0, 0.5, 1.0)
    spec = world.objects[0]
    assert spec.yaw == 0.0 and spec.texture == "plain" and spec.position == (0.7, 0.3)
    spec = object_from_dict(GOOD["objects"][1], "src", "objects[1]")
    assert spec.texture == "checker" and math.isclose(spec.yaw, 0.4)


BAD = [
    ("missing field", _with(1, weight=None), "objects[1] (b).weight", "missing"),
    ("wrong type", _with(0, size="big"), "objects[0] (a).size", "number"),
    ("bool is no number", _with(0, weight=True), "objects[0] (a).weight", "number"),
    ("unknown shape", _with(0, shape="cone"), "objects[0] (a).shape", "cone"),
    ("duplicate name", _with(1, name="a"), "objects[1] (a).name", "duplicate"),
    ("negative size", _with(0, size=-0.3), "objects[0] (a).size", "> 0"),
    ("unknown field", _with(0, colour=3), "objects[0] (a).colour", "unknown field"),
    ("out of range", _with(1, intensity=300), "objects[1] (b).intensity", "[0, 255]"),
    ("bad texture", _with(1, texture="dots"), "objects[1] (b).texture", "dots"),
    ("bad position", _with(0, position=[0.7]), "objects[0] (a).position", "2 numbers"),
    ("overlap", _with(1, position=[0.75, 0.35]), "objects[1] (b).position", "overlaps 'a'"),
    ("out of view", _with(0, position=[-0.4, 0.5]), "objects[0] (a).position", "view"),
    ("empty world", {"objects": []}, "objects", "empty"),
    ("no objects", {"name": "x"}, "objects", "missing"),
    ("unknown top field", {**GOOD, "gravity": 9.8}, "gravity", "unknown field"),
    ("zero light", {**GOOD, "light": {"direction": [0, 0, 0]}}, "light.direction", "zero"),
    ("not a mapping", "- just\n- a list\n", "", "mapping"),
    ("yaml syntax", "objects: [\n  {name: a, shape: box\n", "line", "YAML syntax"),
]


@pytest.mark.parametrize(("case", "data", "where", "problem"), BAD, ids=[b[0] for b in BAD])
def test_bad_world_files(tmp_path: Path, case: str, data: object, where: str,
                         problem: str) -> None:
    path = _write(tmp_path, data)
    with pytest.raises(WorldFileError) as info:
        load_world(path)
    err = info.value
    message = str(err)
    assert "\n" not in message, case
    assert message.startswith(str(path)), message
    assert err.source == str(path)
    assert err.where.startswith(where), (err.where, where)
    assert problem in err.problem, (err.problem, problem)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(WorldFileError, match="cannot read"):
        load_world(tmp_path / "nope.yaml")


def test_good_file_loads(tmp_path: Path) -> None:
    world = load_world(_write(tmp_path, GOOD))
    assert [o.name for o in world.objects] == ["a", "b"]
    assert world.name == "tiny"


def test_world_edit_errors_name_the_object_once() -> None:
    from roger_sim.simulator import Simulator

    sim = Simulator(load_world(WORLDS / "table1.yaml"))
    try:
        with pytest.raises(WorldFileError) as moved:
            sim.move_object("obj01", (0.82, 0.22), 0.0)   # onto obj02
        with pytest.raises(WorldFileError) as added:
            sim.add_object(load_world(WORLDS / "table1.yaml").objects[1])  # a duplicate
        with pytest.raises(WorldFileError) as outside:
            object_from_dict({"name": "zz", "shape": "box", "position": [5.0, 0.6],
                              "size": 0.1, "intensity": 90, "weight": 1.0},
                             "world_edit", "object")
    finally:
        sim.close()
    assert str(moved.value).startswith("move_object: object (obj01).position: overlaps")
    assert str(moved.value).count("obj01") == 1
    assert str(added.value).count("obj02") == 2  # "object (obj02).name: duplicate name 'obj02'"
    assert str(outside.value).startswith("world_edit: object (zz).position: (5, 0.6) is out")
    assert str(outside.value).count("zz") == 1


def test_objects_may_stand_in_view_beyond_reach() -> None:
    world = parse_world(_with(0, position=[1.6, 0.0]), "far.yaml")   # in view, 1.61 m away
    far = world.objects[0]
    assert not in_reach(*far.position) and reach_distance(*far.position) > 1.5
    assert in_reach(*world.objects[1].position)
    shipped = load_world(WORLDS / "beyond_reach.yaml")
    assert sorted(o.name for o in shipped.objects if not in_reach(*o.position)) == \
        ["obj05", "obj06"]
    with pytest.raises(WorldFileError, match="out of view"):
        parse_world(_with(0, position=[3.2, 0.0]), "too_far.yaml")


def test_random_worlds_in_reach_unless_asked_and_unchanged_by_far_objects() -> None:
    plain = random_world(4, 2, seed=31)
    assert all(in_reach(*o.position) for o in plain.objects)
    more = random_world(4, 2, seed=31, out_of_reach=3)
    assert more.objects[:8] == plain.objects
    far = more.objects[8:]
    assert [o.name for o in far] == ["c00_far0", "c01_far0", "c02_far0"]
    assert not any(in_reach(*o.position) for o in far)
    assert [o.category() for o in far] == [o.category() for o in plain.objects[0:6:2]]


def test_a_relative_world_is_found_from_any_directory(tmp_path, monkeypatch):
    """The default world (a relative path) loads where there is no worlds/ folder: the
    simulator node and `roger run` look it up in roger_sim's share directory or the
    source checkout (roger_sim.world.resolve_world)."""
    from roger_bringup.cli import DEFAULT_WORLD, world_arg
    from roger_sim.world import load_world, resolve_world

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("AMENT_PREFIX_PATH", "")
    found = resolve_world(DEFAULT_WORLD)
    assert found.is_file() and found.parts[-2:] == ("worlds", "table1.yaml")
    assert load_world(found).objects
    assert world_arg(DEFAULT_WORLD) == found
    # A path that exists from here is taken as given; one found nowhere stays as given.
    (tmp_path / "worlds").mkdir()
    (tmp_path / "worlds" / "table1.yaml").write_text(found.read_text())
    assert world_arg(DEFAULT_WORLD) == Path(DEFAULT_WORLD)
    assert resolve_world("worlds/none.yaml") == Path("worlds/none.yaml")
    # An install space's share directory comes before the source checkout.
    share = tmp_path / "install" / "share" / "roger_sim" / "worlds"
    share.mkdir(parents=True)
    (share / "only_here.yaml").write_text(found.read_text())
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path / "install"))
    assert resolve_world("worlds/only_here.yaml") == share / "only_here.yaml"
