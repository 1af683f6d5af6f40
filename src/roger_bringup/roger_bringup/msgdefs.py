"""Complete message definitions in rosbag2's ``ros2msg`` form, for MCAP schemas.

rosbag2 stores, for each type, the type's own .msg text followed by the text of every type
it depends on (recursively), each dependency preceded by a line of 80 '=' and a line
``MSG: pkg/msg/Type`` (rosbag2 docs/message_definition_encoding.md). Foxglove, ``ros2 bag``
and mcap-ros2-support decode messages from this text alone.

The .msg files are looked up under ``<prefix>/share/<pkg>/msg/`` for each prefix of
AMENT_PREFIX_PATH and the running interpreter's prefix (the repo's .venv), then in the
repo's ``src/<pkg>/msg`` (for roger_interfaces before it is built).
"""

from __future__ import annotations

import json
import os
import sys
from functools import cache
from pathlib import Path

from roger_common.errors import RogerError

#: Built-in field types of the .msg language.
PRIMITIVES: frozenset[str] = frozenset({
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string", "wstring"})
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
    """Non-primitive field types of one .msg text, qualified, in order of appearance."""
    out: list[str] = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        # Constants ("uint8 X=0") are always primitive, so the type alone decides.
        base = line.split()[0].split("[", 1)[0].split("<=", 1)[0]
        if base in PRIMITIVES:
            continue
        qualified = normalize(base if "/" in base else f"{package}/{base}")
        if qualified not in out:
            out.append(qualified)
    return out


@cache
def full_definition(type_name: str) -> str:
    """The type's .msg text with every dependency appended, rosbag2 ``ros2msg`` style.

    Raises:
        MessageDefinitionError: A .msg file is missing.
    """
    root = normalize(type_name)
    texts: dict[str, str] = {}
    order: list[str] = []

    def visit(name: str) -> None:
        text = find_file(name).read_text()
        texts[name] = text
        for dep in field_types(text, name.split("/")[0]):
            if dep not in texts:
                order.append(dep)
                visit(dep)

    visit(root)
    parts = [texts[root].rstrip("\n")]
    for dep in order:
        parts.append(f"{DELIMITER}\nMSG: {dep}\n{texts[dep].rstrip(chr(10))}")
    return "\n".join(parts) + "\n"


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
