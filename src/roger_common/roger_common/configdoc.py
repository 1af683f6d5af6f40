"""What the config dataclasses say about their fields, read once for every consumer.

A field's one-line description comes from its ``doc`` metadata or, more often, from the
Google-style ``Attributes:`` section of its dataclass's docstring; ROS parameter
descriptors (``conversions.declare_config``) and docs/parameters.md both take it from here,
so no description is written twice. A field whose metadata says ``live=True`` may change
while a node runs; every other one is read at start only. No ROS here.
"""

from __future__ import annotations

import inspect
import re
from dataclasses import MISSING, fields, is_dataclass
from functools import cache
from typing import Any, NamedTuple


@cache
def docstring_attributes(cls: type) -> dict[str, str]:
    """Field descriptions of a Google-style ``Attributes:`` section, joined to one line.

    An entry naming several fields ("a, b, c: ...") describes each of them.
    """
    doc = inspect.getdoc(cls) or ""
    out: dict[str, str] = {}
    in_section, names, text = False, [], []  # type: ignore[var-annotated]

    def flush() -> None:
        for n in names:
            out[n] = " ".join(text).strip()

    for line in doc.splitlines():
        if line.strip() == "Attributes:":
            in_section = True
            continue
        if not in_section:
            continue
        if line and not line.startswith(" "):
            break  # the next section
        m = re.match(r"^ {4}([A-Za-z_][\w, ]*):\s*(.*)$", line)
        if m:
            flush()
            names, text = [n.strip() for n in m.group(1).split(",")], [m.group(2)]
        elif line.startswith("     ") and names:
            text.append(line.strip())
    flush()
    return out


def field_description(cls: type, name: str) -> str:
    """The one-line description of field ``name`` of dataclass ``cls``.

    Raises:
        KeyError: The field has no description (every config field must have one).
    """
    for f in fields(cls):
        if f.name == name:
            doc = dict(f.metadata).get("doc") or docstring_attributes(cls).get(name)
            if doc:
                return str(doc)
            break
    raise KeyError(f"{cls.__name__}.{name} has no description (add it to the docstring's "
                   "Attributes: section)")


def live_fields(cls: type) -> frozenset[str]:
    """Fields of ``cls`` that may change while a node runs (metadata ``live=True``)."""
    return frozenset(f.name for f in fields(cls)
                     if dict(f.metadata).get("live"))


def field_default(f: Any) -> Any:
    """A dataclass field's default (its factory called), or None without one."""
    if f.default is not MISSING:
        return f.default
    if f.default_factory is not MISSING:
        return f.default_factory()
    return None


class ConfigField(NamedTuple):
    """One parameter of a config dataclass (see :func:`config_fields`)."""

    path: tuple[str, ...]
    owner: type
    default: Any


def config_fields(config_cls: type, prefix: str = "") -> dict[str, ConfigField]:
    """Every parameter a config dataclass makes, by name.

    A field whose default is itself a config dataclass is a group: its fields become
    parameters named ``prefix + field + "." + name`` (``qlearning.alpha``). Fields whose
    default is None are not parameters.
    """
    out: dict[str, ConfigField] = {}
    for f in fields(config_cls):
        default = field_default(f)
        if is_dataclass(default):
            for name, sub in config_fields(type(default), f"{prefix}{f.name}.").items():
                out[name] = sub._replace(path=(f.name, *sub.path))
        elif default is not None:
            out[prefix + f.name] = ConfigField((f.name,), config_cls, default)
    return out
