"""Complete message definitions for MCAP schemas, byte for byte as rosbag2 (Jazzy) writes them.

rosbag2 stores, for each type, the type's own .msg file followed by the file of every type it
depends on (recursively, each once), each dependency after a blank line, a line of 80 '=' and
a line ``MSG: <name>`` (rosbag2 docs/message_definition_encoding.md). The name is the one the
field spells, ``std_msgs/Header``, or ``<package>/<Type>`` for a field type without a
package; never ``std_msgs/msg/Header``: readers resolve field types by that name, and
Foxglove's parser finds no ``std_msgs/Header`` in a ``MSG: std_msgs/msg/Header`` section.
This module follows rosbag2_cpp's ``LocalMessageDefinitionSource::get_full_text``: the
same dependency pattern and primitive set, dependencies in sorted order, depth first, the
files' text unchanged. Foxglove, ``ros2 bag`` and mcap-ros2-support decode messages from
this text alone.

The .msg files are looked up under ``<prefix>/share/<pkg>/msg/`` for each prefix of
AMENT_PREFIX_PATH and the running interpreter's prefix (the repo's .venv), then in the
repo's ``src/<pkg>/msg`` (for roger_interfaces before it is built).
"""

from __future__ import annotations

import json
import os
import re
import sys
from functools import cache
from pathlib import Path

from roger_common.errors import RogerError

#: Field types that are not dependencies: rosbag2_cpp's PRIMITIVE_TYPES. ``wstring`` is not
#: among them there either (a wstring field would send rosbag2 looking for ``pkg/wstring``).
PRIMITIVES: frozenset[str] = frozenset({
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string"})
#: rosbag2_cpp's MSG_FIELD_TYPE_REGEX: the first word of a line, before an optional array
#: suffix and white space (comment lines, starting with '#', never match; nor do bounded
#: strings such as ``string<=8``, which are primitive anyway).
_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")
DELIMITER = "=" * 80


class MessageDefinitionError(RogerError):
    """A .msg file needed for a schema cannot be found or parsed."""


def normalize(type_name: str) -> str:
    """``pkg/Type`` or ``pkg/msg/Type`` as ``pkg/msg/Type``.

    Raises:
        MessageDefinitionError: Not a package-qualified type name.
    """
    parts = type_name.split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    if len(parts) == 3 and parts[1] == "msg":
        return type_name
    raise MessageDefinitionError(f"not a message type name: {type_name!r}")


def search_roots() -> list[Path]:
    """Install prefixes whose ``share/`` may hold .msg files, in lookup order."""
    roots = [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    roots.append(Path(sys.prefix))
    return roots


def _repo_src() -> Path:
    return Path(__file__).resolve().parents[2]


@cache
def find_file(type_name: str, suffix: str = ".msg") -> Path:
    """The installed ``<Type><suffix>`` file (".msg" or ".json") of a message type.

    Raises:
        MessageDefinitionError: No such file in any search root.
    """
    pkg, _, name = normalize(type_name).split("/")
    candidates = [root / "share" / pkg / "msg" / f"{name}{suffix}" for root in search_roots()]
    candidates.append(_repo_src() / pkg / "msg" / f"{name}{suffix}")
    for path in candidates:
        if path.is_file():
            return path
    raise MessageDefinitionError(
        f"{pkg}/msg/{name}{suffix} not found under "
        f"{', '.join(str(c.parent) for c in candidates)}; set AMENT_PREFIX_PATH")


def field_types(text: str, package: str) -> list[str]:
    """The dependencies of one .msg text, spelled as rosbag2 spells them, in sorted order.

    A field type with a package keeps its spelling (``std_msgs/Header`` stays so); one
    without gets the package of the file it is in (``RegionOfInterest`` in sensor_msgs is
    ``sensor_msgs/RegionOfInterest``).
    """
    deps: set[str] = set()
    for match in _FIELD_TYPE.finditer(text):
        name = match.group(1)
        if name in PRIMITIVES:
            continue
        deps.add(name if "/" in name else f"{package}/{name}")
    return sorted(deps)


@cache
def full_definition(type_name: str) -> str:
    """The type's .msg text with every dependency appended, as rosbag2 writes it.

    Args:
        type_name: ``pkg/msg/Type`` (the schema name; ``pkg/Type`` is accepted too).

    Raises:
        MessageDefinitionError: A .msg file is missing.
    """
    seen: set[str] = set()

    def text_with_dependencies(name: str) -> str:
        # Bytes as they are (read_text would turn "\r\n" into "\n").
        text = find_file(name).read_bytes().decode("utf-8")
        out = text
        for dep in field_types(text, name.split("/")[0]):
            if dep not in seen:
                seen.add(dep)
                out += f"\n{DELIMITER}\nMSG: {dep}\n" + text_with_dependencies(dep)
        return out

    return text_with_dependencies(normalize(type_name))


@cache
def type_hash(type_name: str) -> str:
    """The REP-2011 type hash ("RIHS01_...") from the installed .json description; "" if none."""
    root = normalize(type_name)
    try:
        data = json.loads(find_file(root, ".json").read_text())
    except (MessageDefinitionError, OSError, ValueError):
        return ""
    for entry in data.get("type_hashes", []):
        if entry.get("type_name") == root:
            return str(entry.get("hash_string", ""))
    return ""
