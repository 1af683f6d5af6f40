"""Fuzzed world files and world edits: one clear line naming the field, never a traceback.

Property-based (Hypothesis, settings in ``fuzz_settings``): random structures, types and
values where a world file or a world-edit request has fields, and random text where it has
YAML. Whatever comes in, the world loader returns a valid world or raises one
``WorldFileError`` whose message is one line that starts with the file's name and names
the field; the world-edit service answers ``ok`` or a one-line reason, and the world it
leaves can always be written out and read back (a restarted simulator resumes from it).
A few of the inputs the fuzzing found go through the real CLI (``roger run --world``) and
``roger-sim`` in a subprocess: exit status 2, one line on stderr, no traceback.
"""

from __future__ import annotations

import datetime
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import WORLDS
from fuzz_settings import fuzz
from hypothesis import example, given
from hypothesis import strategies as st
from rclpy.parameter import Parameter

from roger_common.errors import WorldFileError
from roger_sim.world import SHAPES, TEXTURES, load_world, parse_world, world_to_dict

SOURCE = "fuzz.yaml"
#: The longest message a clear line may be (a value that is a huge structure is cut short).
MAX_LINE = 600

OBJECT_FIELDS = ("name", "shape", "position", "yaw", "size", "intensity", "weight", "texture")
#: Places a valid world's objects stand on: in view, and 0.5 m apart (no overlap at size 0.3).
PLACES = ((0.8, 0.0), (0.8, 0.5), (0.8, -0.5), (1.3, 0.0), (1.3, 0.5))


def one_clear_line(exc: WorldFileError, source: str) -> str:
    """The error's message, checked: one line, the file first, not a screenful."""
    line = str(exc)
    assert len(line.splitlines()) == 1, repr(line)
    assert line.startswith(f"{source}: "), line
    assert len(line) <= MAX_LINE + len(source), f"{len(line)} characters: {line[:200]}..."
    return line


# -- strategies --------------------------------------------------------------------------
huge_ints = st.integers(min_value=10**300, max_value=10**400) | st.integers(
    min_value=-(10**400), max_value=-(10**300))
scalars = st.one_of(
    st.none(), st.booleans(), st.integers(), huge_ints,
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
    st.sampled_from([*SHAPES, *TEXTURES, "", "a\nb", "\u2028", "x" * 100]),
    st.dates(), st.binary(max_size=6))
keys = st.text(max_size=10) | st.sampled_from(OBJECT_FIELDS) | st.integers() | st.none()
values = st.recursive(scalars, lambda kids: st.lists(kids, max_size=4)
                      | st.dictionaries(keys, kids, max_size=4), max_leaves=10)


@st.composite
def valid_object(draw: st.DrawFn, place: tuple[float, float], name: str) -> dict:
    return {"name": name, "shape": draw(st.sampled_from(SHAPES)), "position": list(place),
            "yaw": draw(st.floats(-3.0, 3.0)), "size": draw(st.floats(0.05, 0.3)),
            "intensity": draw(st.integers(0, 255)), "weight": draw(st.floats(0.01, 5.0)),
            "texture": draw(st.sampled_from(TEXTURES))}


@st.composite
def valid_world(draw: st.DrawFn) -> dict:
    n = draw(st.integers(1, len(PLACES)))
    return {"name": "fuzz", "light": {"direction": [1.0, 0.5, 1.0]},
            "objects": [draw(valid_object(PLACES[i], f"obj{i}")) for i in range(n)]}


@st.composite
def near_valid_world(draw: st.DrawFn) -> dict:
    """A valid world with one to three fields replaced by anything, deleted or added."""
    world = draw(valid_world())
    for _ in range(draw(st.integers(1, 3))):
        where = draw(st.sampled_from(["top", "light", "objects", "object"]))
        if where == "objects":
            world["objects"] = draw(values)
            continue
        if where == "top":
            container, fields = world, ["name", "light", "objects"]
        elif where == "light":
            container, fields = world.get("light"), ["direction"]
        else:
            objects = world.get("objects")
            if not isinstance(objects, list) or not objects:
                continue
            container, fields = objects[draw(st.integers(0, len(objects) - 1))], \
                list(OBJECT_FIELDS)
        if not isinstance(container, dict):
            continue
        key = draw(st.sampled_from(fields) | keys)
        if draw(st.booleans()) and key in container:
            del container[key]
        else:
            container[key] = draw(values)
    return world


# -- the loader, in process --------------------------------------------------------------
def _billion_laughs() -> list:
    """10^8 strings in a few hundred bytes of references (YAML aliases build the same)."""
    x: list = ["lol"] * 10
    for _ in range(7):
        x = [x] * 10
    return x


@fuzz(examples=400)
@given(near_valid_world() | values)
@example({"objects": [{"name": "a\nb", "shape": "box"}]})
@example({"objects": [{"name": "a", "shape": "box", "position": [0.8, 0.0], "size": 10**400,
                       "intensity": 9, "weight": 1.0}]})
def test_any_world_structure_loads_or_gives_one_line_naming_the_field(data) -> None:
    try:
        world = parse_world(data, SOURCE)
    except WorldFileError as exc:
        line = one_clear_line(exc, SOURCE)
        if isinstance(data, dict):
            assert exc.where, f"names no field: {line}"
        return
    # What loads is valid through and through: written out, it reads back the same.
    assert parse_world(world_to_dict(world), SOURCE) == world


def test_a_billion_laughs_is_refused_in_one_short_line(tmp_path) -> None:
    # Not an @example: Hypothesis would pretty-print its 10^8 elements.
    for data in ({"objects": [_billion_laughs()]},
                 {"light": {"direction": _billion_laughs()}, "objects": []},
                 {"objects": _billion_laughs()}):
        with pytest.raises(WorldFileError) as info:
            parse_world(data, SOURCE)
        one_clear_line(info.value, SOURCE)
    text = "a: &a [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]\n"
    for name, prev in zip("bcdefgh", "abcdefg", strict=True):
        text += f"{name}: &{name} [{', '.join([f'*{prev}'] * 10)}]\n"
    path = tmp_path / "laughs.yaml"
    path.write_text(text.replace("h: &h", "objects: &h").replace("objects: &h [", "objects: [["))
    with pytest.raises(WorldFileError) as info:
        load_world(path)
    one_clear_line(info.value, str(path))


YAML_SNIPPETS = [
    "2001-13-01", "2001-02-30", "!!float abc", "!!int abc", "!!binary '@@'", "!!timestamp x",
    "!!python/object:os.system x", "!!set {a, b}", "&a [*a]", "*undefined", "? [a, b]",
    "{a: 1, a: 2}", "9" * 400, "-" + "9" * 400, "1.0e+400", ".nan", "-.inf", "0x_", "1_0",
    "'", '"\\x"', "[" * 1000, "{" * 1000, "\t", "%TAG", "---", "...", "@", "`", "|-",
]


@st.composite
def world_text(draw: st.DrawFn) -> str:
    """A valid world as YAML with one field's value replaced by raw text, or mere text."""
    if draw(st.integers(0, 9)) == 0:
        return draw(st.text(st.sampled_from(list("[]{}:,-&*!|>'\"#%@ \n\tab01.")),
                            max_size=80))
    world = draw(valid_world())
    raw = draw(st.sampled_from(YAML_SNIPPETS)
               | st.from_regex(r"[0-9]{4}-[0-9]{1,2}-[0-9]{1,2}", fullmatch=True)
               | st.integers(0, 1200).map(lambda n: "[" * n + "]" * (n // 2))
               | st.text(st.characters(blacklist_categories=("Cs",),
                                       blacklist_characters="\n\r"), max_size=20))
    text = yaml.safe_dump(world, default_flow_style=False, sort_keys=False)
    if draw(st.booleans()):
        key = draw(st.sampled_from(OBJECT_FIELDS))
        i = draw(st.integers(0, len(world["objects"]) - 1))
        head = f"- name: obj{i}\n"
        return text.replace(head, f"{head}  {key}: {raw}\n", 1)
    key = draw(st.sampled_from(["name", "light", "objects", "gravity"]))
    return f"{text}{key}: {raw}\n"


@fuzz(examples=200)
@given(world_text())
@example("name: 2001-13-01\nobjects: []\n")
@example("objects: " + "[" * 1000)
@example("objects:\n- name: a\n  size: " + "9" * 400 + "\n")
def test_any_world_file_loads_or_gives_one_line(tmp_path_factory, text) -> None:
    path = tmp_path_factory.getbasetemp() / "fuzz.yaml"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        load_world(path)
    except WorldFileError as exc:
        one_clear_line(exc, str(path))


# -- the command line, in a subprocess ----------------------------------------------------
#: Inputs the fuzzing found (each once gave a traceback), and one it never broke.
CLI_CASES = {
    "timestamp": "name: 2001-13-01\nobjects: []\n",
    "deep nesting": "objects: " + "[" * 1000 + "\n",
    "huge integer": ("objects:\n- {name: a, shape: box, position: [0.8, 0.0], size: 0.2,\n"
                     "   intensity: 90, weight: " + "9" * 400 + "}\n"),
    "bad tag": "objects:\n- {name: a, shape: box, size: !!float big}\n",
}


@pytest.mark.parametrize("case", sorted(CLI_CASES))
def test_roger_run_refuses_a_fuzzed_world_with_one_line(no_leaks, tmp_path, case) -> None:
    world = tmp_path / "bad.yaml"
    world.write_text(CLI_CASES[case])
    roger = Path(sys.executable).with_name("roger")
    proc = subprocess.run([str(roger), "run", "--world", str(world), "--out",
                           str(tmp_path / "out")], capture_output=True, text=True,
                          timeout=120, check=False)
    lines = [ln for ln in proc.stderr.splitlines()
             if ln.strip() and "pybullet build" not in ln]
    assert "Traceback" not in proc.stderr, proc.stderr
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and lines[0].startswith("roger: ") and "bad.yaml" in lines[0], \
        proc.stderr
    assert not (tmp_path / "out").exists()  # refused before anything started


def test_roger_sim_refuses_a_fuzzed_world_with_one_line(no_leaks, tmp_path, ros_domain):
    world = tmp_path / "bad.yaml"
    world.write_text(CLI_CASES["timestamp"])
    proc = subprocess.run(
        [sys.executable, "-m", "roger_sim.sim_node", "--ros-args", "-p", f"world:={world}"],
        capture_output=True, text=True, timeout=120, check=False,
        env={**os.environ, "ROS_DOMAIN_ID": str(ros_domain)})
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and "pybullet build" not in ln]
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert len(lines) == 1 and lines[0].startswith("roger-sim: ") and "bad.yaml" in lines[0]


# -- the world-edit service, in process --------------------------------------------------
names = st.sampled_from(["obj_new", "a\nb", "", "x" * 80, "white_cube", "cyl"]) | st.text(
    max_size=8)
floats = st.floats(allow_nan=True, allow_infinity=True) | st.floats(-1.5, 1.5)


@st.composite
def world_edits(draw: st.DrawFn):
    from roger_interfaces.msg import WorldEdit, WorldObject
    obj = WorldObject(
        name=draw(names), shape=draw(st.sampled_from(SHAPES) | st.text(max_size=6)),
        x=draw(st.floats(0.3, 1.2) | floats), y=draw(floats), yaw=draw(floats),
        size=draw(st.floats(0.04, 0.3) | floats), intensity=draw(st.floats(0, 255) | floats),
        weight=draw(st.floats(0.01, 5.0) | floats),
        texture=draw(st.sampled_from(["", *TEXTURES]) | st.text(max_size=6)))
    return WorldEdit(op=draw(st.sampled_from([0, 1, 2]) | st.integers(0, 255)), object=obj)


def test_any_world_edit_is_applied_or_refused_with_one_line(no_leaks, ros_context):
    from roger_interfaces.srv import EditWorld
    from roger_sim.sim_node import SimNode
    node = SimNode(context=ros_context, parameter_overrides=[
        Parameter("world", value=str(WORLDS / "table1.yaml")),
        Parameter("image_size", value=64)])
    known = [o.name for o in node.world.objects]
    tried = {"ok": 0, "refused": 0}

    @fuzz(examples=150)
    @given(world_edits(), st.sampled_from(known) | st.none())
    def edit(msg, existing) -> None:
        if existing is not None:  # edits of an object the world has, not only new names
            msg.object.name = existing
        response = node.on_edit_world(EditWorld.Request(edit=msg), EditWorld.Response())
        tried["ok" if response.ok else "refused"] += 1
        assert len(response.message.splitlines()) == 1, repr(response.message)
        assert len(response.message) <= MAX_LINE, response.message[:200]
        if not response.ok:
            assert response.message[:1] not in "'\"", response.message  # a KeyError's repr
        # What a restarted simulator resumes from must still be a valid world file.
        world = node.sim.world
        assert parse_world(world_to_dict(world), "sim.json").objects == world.objects
        assert all(math.isfinite(v) for o in world.objects for v in (*o.position, o.yaw))

    try:
        edit()
        assert tried["refused"], tried
        # Still serving: a valid edit is applied after all that (the object may exist).
        from roger_interfaces.msg import WorldEdit, WorldObject
        node.on_edit_world(EditWorld.Request(edit=WorldEdit(
            op=WorldEdit.REMOVE, object=WorldObject(name="fuzz_last"))), EditWorld.Response())
        free = next(p for p in ((0.45, 0.0), (0.45, 0.3), (0.45, -0.3), (1.8, 0.0))
                    if all(math.dist(p, o.position) > 0.4 for o in node.sim.world.objects))
        last = WorldEdit(op=WorldEdit.ADD, object=WorldObject(
            name="fuzz_last", shape="box", x=free[0], y=free[1], size=0.1, intensity=120.0,
            weight=0.8, texture="plain"))
        response = node.on_edit_world(EditWorld.Request(edit=last), EditWorld.Response())
        assert response.ok, (response.message, tried)
    finally:
        node.destroy_node()


def test_dates_are_not_numbers() -> None:
    # YAML reads 2001-02-03 as a date: a field that needs a number says so, naming it.
    with pytest.raises(WorldFileError, match=r"objects\[0\] \(a\)\.size: must be a number"):
        parse_world({"objects": [{"name": "a", "shape": "box", "position": [0.8, 0.0],
                                  "size": datetime.date(2001, 2, 3), "intensity": 9,
                                  "weight": 1.0}]}, SOURCE)
