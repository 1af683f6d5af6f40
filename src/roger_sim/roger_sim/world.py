"""World files: YAML descriptions of the objects around Roger (schema: docs/world-files.md).

Every field is validated; any problem raises one
:class:`roger_common.errors.WorldFileError` whose message names the file, the object and
the field, e.g. ``worlds/x.yaml: objects[2] (obj03).size: must be > 0, got -0.3``.
"""

from __future__ import annotations

import math
import os
import re
import reprlib
from pathlib import Path
from typing import Any

import yaml

from roger_common.errors import WorldFileError
from roger_common.geometry import as_point
from roger_common.types import ObjectSpec, WorldSpec
from roger_sim.robot import CONTROLLERS, REACH, shoulder_xy

#: Shapes a world may use.
SHAPES: tuple[str, ...] = ("box", "cylinder", "sphere", "prism")
#: Surface textures a world may use.
TEXTURES: tuple[str, ...] = ("plain", "stripes", "checker")
#: Allowed range of ``size``, metres.
SIZE_RANGE: tuple[float, float] = (0.05, 0.5)
#: Allowed range of ``weight``, kg (the arms lift at most this much).
WEIGHT_RANGE: tuple[float, float] = (0.01, 5.0)
#: Objects must stand this far in front of Roger (x, metres) to be seen and worked on.
MIN_X: float = 0.3
#: Largest bearing of an object's centre from straight ahead, radians.
MAX_BEARING: float = math.radians(75.0)
#: Horizontal distance from the robot's origin beyond which objects are too far, metres.
MAX_DISTANCE: float = 3.0

_NAME = re.compile(r"^[A-Za-z0-9_.\-]{1,64}$")
_OBJECT_FIELDS = ("name", "shape", "position", "yaw", "size", "intensity", "weight",
                  "texture")
_REQUIRED = ("name", "shape", "position", "size", "intensity", "weight")
_WORLD_FIELDS = ("name", "light", "objects")

# A value quoted in an error is cut short: a file may hold a structure of any size (YAML
# aliases build 10^8 elements from a few hundred bytes) and the message stays one line.
_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxstring, _REPR.maxother, _REPR.maxlong = 2, 40, 40, 40
_REPR.maxlist = _REPR.maxtuple = _REPR.maxdict = _REPR.maxset = _REPR.maxfrozenset = 4


class _Loader(yaml.SafeLoader):
    """yaml.SafeLoader whose values that parse but cannot be built (a date such as
    2001-13-01, ``!!float abc``, ``!!timestamp x``, an integer of more than 4300 digits)
    are YAML errors at their line and column, not a ValueError or AttributeError from deep
    inside PyYAML."""

    def construct_object(self, node: yaml.Node, deep: bool = False) -> Any:
        try:
            return super().construct_object(node, deep=deep)
        except (ValueError, OverflowError, TypeError, AttributeError, KeyError,
                IndexError) as exc:
            value = node.value if isinstance(node, yaml.ScalarNode) else node.tag
            raise yaml.constructor.ConstructorError(
                None, None, f"cannot read {_show(value)} ({exc})", node.start_mark) from None


def _show(value: Any) -> str:
    """``value`` for an error message: repr, cut short, on one line."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 128:
        return f"an integer of {value.bit_length()} bits"  # repr fails beyond 4300 digits
    return _REPR.repr(value)


def _key(key: Any) -> str:
    """A field name for ``where``: as written when it is a plain one, else quoted."""
    if isinstance(key, str) and key and key.isprintable() and len(key) <= 40:
        return key
    return _show(key)


def shape_height(shape: str, size: float) -> float:
    """Height of an object of ``shape`` and ``size`` standing on the ground, metres."""
    if shape == "prism":
        return size * math.sqrt(3.0) / 2.0
    return size


def footprint_radius(shape: str, size: float) -> float:
    """Radius of a circle around the object's footprint, whatever its yaw, metres."""
    if shape in ("sphere", "cylinder"):
        return size / 2.0
    if shape == "prism":
        return math.hypot(size / 2.0, size / 4.0)  # triangle side ``size``, depth size / 2
    return size * math.sqrt(2.0) / 2.0


def _number(source: str, where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise WorldFileError(source, where, f"must be a number, got {_show(value)}")
    try:
        x = float(value)
    except OverflowError:  # an int beyond the floats
        x = math.inf
    if not math.isfinite(x):
        raise WorldFileError(source, where, f"must be finite, got {_show(value)}")
    return x


def _in_range(source: str, where: str, value: Any, lo: float, hi: float,
              unit: str = "") -> float:
    x = _number(source, where, value)
    if not lo <= x <= hi:
        raise WorldFileError(source, where, f"must be in [{lo:g}, {hi:g}]{unit}, got {x:g}")
    return x


def _vector(source: str, where: str, value: Any, n: int) -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise WorldFileError(source, where, f"must be a list of {n} numbers, got {_show(value)}")
    return tuple(_number(source, f"{where}[{i}]", v) for i, v in enumerate(value))


def object_from_dict(d: dict, source: str, where: str) -> ObjectSpec:
    """Validate one object entry and build its :class:`ObjectSpec`.

    Checks each field on its own (type, allowed values, ranges) and that the object can
    be seen; it may stand beyond the arms' reach (``in_reach``), where a haptic improvement
    fails. Overlaps with other objects are checked by ``parse_world``.

    Args:
        d: The entry as loaded from YAML.
        source: File name (or other origin) for error messages.
        where: Where the entry is, e.g. ``"objects[2]"``.

    Raises:
        WorldFileError: Naming ``source``, ``where`` (with the object's name) and the field.
    """
    if not isinstance(d, dict):
        raise WorldFileError(source, where, f"must be a mapping of fields, got {_show(d)}")
    name = d.get("name")
    label = f"{where} ({_key(name)})" if isinstance(name, str) and name else where
    for key in d:
        if key not in _OBJECT_FIELDS:
            raise WorldFileError(source, f"{label}.{_key(key)}",
                                 f"unknown field; allowed: {', '.join(_OBJECT_FIELDS)}")
    for key in _REQUIRED:
        if key not in d:
            raise WorldFileError(source, f"{label}.{key}", "missing required field")
    if not isinstance(name, str) or not _NAME.match(name):
        raise WorldFileError(source, f"{label}.name", "must be 1-64 letters, digits or _.- "
                             f"without spaces, got {_show(name)}")
    shape = d["shape"]
    if shape not in SHAPES:
        raise WorldFileError(source, f"{label}.shape",
                             f"unknown shape {_show(shape)}; use one of {', '.join(SHAPES)}")
    texture = d.get("texture", "plain")
    if texture not in TEXTURES:
        raise WorldFileError(source, f"{label}.texture",
                             f"unknown texture {_show(texture)}; use one of {', '.join(TEXTURES)}")
    x, y = _vector(source, f"{label}.position", d["position"], 2)
    yaw = _in_range(source, f"{label}.yaw", d.get("yaw", 0.0), -2 * math.pi, 2 * math.pi,
                    " rad")
    size = _number(source, f"{label}.size", d["size"])
    if size <= 0:
        raise WorldFileError(source, f"{label}.size", f"must be > 0, got {size:g}")
    size = _in_range(source, f"{label}.size", size, *SIZE_RANGE, " m")
    intensity = _in_range(source, f"{label}.intensity", d["intensity"], 0, 255)
    weight = _number(source, f"{label}.weight", d["weight"])
    if weight <= 0:
        raise WorldFileError(source, f"{label}.weight", f"must be > 0, got {weight:g}")
    weight = _in_range(source, f"{label}.weight", weight, *WEIGHT_RANGE, " kg")
    distance = math.hypot(x, y)
    if x < MIN_X or abs(math.atan2(y, x)) > MAX_BEARING or distance > MAX_DISTANCE:
        raise WorldFileError(source, f"{label}.position",
                             f"({x:g}, {y:g}) is out of view: need x >= {MIN_X:g} m, a "
                             f"bearing within {math.degrees(MAX_BEARING):g} deg and a "
                             f"distance <= {MAX_DISTANCE:g} m")
    return ObjectSpec(name=name, shape=shape, position=(x, y), size=size,
                      intensity=intensity, weight=weight, yaw=yaw, texture=texture)


def reach_distance(x: float, y: float) -> float:
    """Horizontal distance (m) from the nearest shoulder to the point (x, y)."""
    return min(math.hypot(x - sx, y - sy)
               for sx, sy in (shoulder_xy(arm) for arm in CONTROLLERS[3:]))


def in_reach(x: float, y: float) -> bool:
    """True when a hand can work over (x, y): within ``REACH`` of a shoulder. An object in
    view beyond it can be seen, identified and stored, but not touched or weighed."""
    return reach_distance(x, y) <= REACH


def check_overlap(objects: tuple[ObjectSpec, ...] | list[ObjectSpec], new: ObjectSpec,
                  source: str, where: str) -> None:
    """Raise when ``new`` has the name of, or overlaps, one of ``objects``."""
    for other in objects:
        if other.name == new.name:
            raise WorldFileError(source, f"{where}.name", f"duplicate name {new.name!r}")
        gap = math.dist(other.position, new.position)
        need = footprint_radius(other.shape, other.size) + footprint_radius(new.shape, new.size)
        if gap < need:
            raise WorldFileError(source, f"{where}.position",
                                 f"overlaps {other.name!r}: centres {gap:.3f} m apart, "
                                 f"need >= {need:.3f} m")


def parse_world(data: dict, source: str) -> WorldSpec:
    """Validate a loaded world file and build its :class:`WorldSpec`.

    Raises:
        WorldFileError: On the first problem found (one line, naming the field).
    """
    if not isinstance(data, dict):
        raise WorldFileError(source, "", "the file must be a YAML mapping with an 'objects' "
                             f"list, got {type(data).__name__}")
    for key in data:
        if key not in _WORLD_FIELDS:
            raise WorldFileError(source, _key(key),
                                 f"unknown field; allowed: {', '.join(_WORLD_FIELDS)}")
    name = data.get("name", Path(source).stem or "world")
    if not isinstance(name, str) or not name:
        raise WorldFileError(source, "name", f"must be a non-empty string, got {_show(name)}")
    light = data.get("light", {"direction": [1.0, 0.5, 1.0]})
    if not isinstance(light, dict):
        raise WorldFileError(source, "light", f"must be a mapping, got {_show(light)}")
    for key in light:
        if key != "direction":
            raise WorldFileError(source, f"light.{_key(key)}",
                                 "unknown field; allowed: direction")
    direction = _vector(source, "light.direction", light.get("direction", [1.0, 0.5, 1.0]), 3)
    if math.hypot(*direction) < 1e-6:
        raise WorldFileError(source, "light.direction", "must not be the zero vector")
    if "objects" not in data:
        raise WorldFileError(source, "objects", "missing required field")
    raw = data["objects"]
    if not isinstance(raw, list):
        raise WorldFileError(source, "objects", f"must be a list, got {_show(raw)}")
    if not raw:
        raise WorldFileError(source, "objects", "the world is empty; list at least one object")
    objects: list[ObjectSpec] = []
    for i, entry in enumerate(raw):
        spec = object_from_dict(entry, source, f"objects[{i}]")
        check_overlap(objects, spec, source, f"objects[{i}] ({spec.name})")
        objects.append(spec)
    return WorldSpec(objects=tuple(objects), name=name, light_direction=as_point(direction),
                     source=source)


def load_world(path: str | Path) -> WorldSpec:
    """Read and validate a world file.

    Raises:
        WorldFileError: The file is missing, unreadable, not YAML or not a valid world.
    """
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise WorldFileError(source, "", f"cannot read the file: {exc.strerror or exc}")
    except UnicodeDecodeError as exc:
        raise WorldFileError(source, "", f"cannot read the file: {exc}")
    try:
        data = yaml.load(text, Loader=_Loader)  # noqa: S506 (a SafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        kind = "value" if isinstance(exc, yaml.constructor.ConstructorError) else "syntax"
        raise WorldFileError(source, where, f"YAML {kind} error: {problem}") from None
    except RecursionError:  # PyYAML composes recursively: some thousand [ or { deep
        raise WorldFileError(source, "", "YAML nested too deep") from None
    return parse_world(data, source)


def world_to_dict(world: WorldSpec) -> dict:
    """The world as a plain dict in the file schema (``parse_world`` reads it back)."""
    return {
        "name": world.name,
        "light": {"direction": [float(c) for c in world.light_direction]},
        "objects": [
            {"name": o.name, "shape": o.shape,
             "position": [float(o.position[0]), float(o.position[1])],
             "yaw": float(o.yaw), "size": float(o.size), "intensity": float(o.intensity),
             "weight": float(o.weight), "texture": o.texture}
            for o in world.objects
        ],
    }


#: The package whose share directory holds the shipped worlds in an install space.
PACKAGE = "roger_sim"


def world_search_path() -> list[Path]:
    """Where a relative world path is looked up, in order: the working directory; the
    package's share directory under each prefix of ``AMENT_PREFIX_PATH`` (a colcon install
    space installs the repository's ``worlds/`` as ``share/roger_sim/worlds``: setup.py;
    this is the lookup ament_index_python's ``get_package_share_directory`` makes); the
    source checkout (an editable install, as ``make bootstrap``'s, installs no data files).
    """
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    return [Path.cwd(), *(Path(p) / "share" / PACKAGE for p in prefixes),
            Path(__file__).resolve().parents[3]]


def resolve_world(world: str) -> Path:
    """The world file the ``world`` parameter names: an absolute path as it is, a relative
    one in the first folder of ``world_search_path`` that has it (as it is when none has:
    loading it then says the file cannot be read)."""
    path = Path(world).expanduser()
    if path.is_absolute():
        return path
    return next((base / path for base in world_search_path() if (base / path).is_file()),
                path)
