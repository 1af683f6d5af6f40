"""What the config dataclasses say about their fields, read once for every consumer.

A field's one-line description comes from its ``doc`` metadata or, more often, from the
Google-style ``Attributes:`` section of its dataclass's docstring; ROS parameter
descriptors (``conversions.declare_config``) and docs/parameters.md both take it from here,
so no description is written twice. A field whose metadata says ``live=True`` may change
while a node runs; every other one is read at start only. A numeric field's range
(``field_range``) is read off the dataclass's own validation, so it is never written a
second time either. No ROS here.
"""

from __future__ import annotations

import inspect
import math
import re
from dataclasses import MISSING, fields, is_dataclass, replace
from functools import cache
from typing import Any, NamedTuple

#: A bound at or beyond this magnitude is reported as unbounded.
UNBOUNDED = 1e9


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


def check_live_change(old: Any, new: Any) -> None:
    """Raise ValueError unless ``new`` differs from ``old`` (configs of one dataclass) only
    in fields marked ``live`` (nested config dataclasses compared field by field)."""
    for f in fields(old):
        a, b = getattr(old, f.name), getattr(new, f.name)
        if is_dataclass(a):
            check_live_change(a, b)
        elif a != b and not dict(f.metadata).get("live"):
            raise ValueError(f"{type(old).__name__}.{f.name} is read at start only")


def take_live_fields(current: Any, new: Any) -> Any:
    """``current`` with the fields marked ``live`` taken from ``new`` (nested config
    dataclasses field by field): what a running core may take from a parameter change."""
    changes = {}
    for f in fields(current):
        a, b = getattr(current, f.name), getattr(new, f.name)
        if is_dataclass(a):
            changes[f.name] = take_live_fields(a, b)
        elif dict(f.metadata).get("live"):
            changes[f.name] = b
    return replace(current, **changes)


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


def _accepts(config_cls: type, path: tuple[str, ...], value: Any) -> bool:
    """Whether the default config of ``config_cls`` with the field at ``path`` set to
    ``value`` passes the dataclasses' own validation."""
    def build(cls: type, rest: tuple[str, ...]) -> Any:
        base = cls()
        if len(rest) == 1:
            return replace(base, **{rest[0]: value})
        sub = getattr(base, rest[0])
        return replace(base, **{rest[0]: build(type(sub), rest[1:])})
    try:
        build(config_cls, path)
    except (ValueError, TypeError):
        return False
    return True


def _nice(x: float, ok: Any, outward: float) -> float:
    """``x`` (an accepted bound) as a round number: the nearest value with at most 12
    decimals within 1e-9 of it (4e-52 next to an open 0 is 0, 0.0999... is 0.1; the
    validation may refuse that point itself, an open bound), else ``x`` rounded away
    from the default (``outward`` +-1) to the fewest significant digits still accepted."""
    for k in range(13):
        r = round(x, k)
        if abs(r - x) <= 1e-9 * max(1.0, abs(x)):
            return r
    for d in range(1, 13):
        r = float(f"{x:.{d}g}")
        if (r - x) * outward >= 0 and ok(r):
            return r
    return x


@cache
def field_range(config_cls: type, path: tuple[str, ...]) -> tuple[float, float] | None:
    """The closed interval of values the numeric field at ``path`` accepts, read off the
    dataclasses' validation (``__post_init__``) around the defaults; None for a field that
    is not a number (bool, str, tuple). An unbounded side is +-inf. An open bound (> 0)
    is given as the bound itself (0): a ROS range is closed, and the validation still
    refuses that one point with its reason.

    Probed by bisection between the default (accepted) and +-``UNBOUNDED``: exact for
    integers; for floats to far below any printed digit, then rounded (``_nice``). A
    bound that depends on another field (a tolerance below another) is the one that
    holds at the other's default.
    """
    default: Any = config_cls()
    for step in path:
        default = getattr(default, step)
    if isinstance(default, bool) or not isinstance(default, (int, float)):
        return None
    is_int = isinstance(default, int)

    def ok(v: float) -> bool:
        return _accepts(config_cls, path, int(v) if is_int else float(v))

    if not ok(default):
        return None
    bounds = []
    for far in (-UNBOUNDED, UNBOUNDED):
        if ok(far):
            bounds.append(math.copysign(math.inf, far))
            continue
        good, bad = float(default), far
        for _ in range(200):
            if is_int and abs(bad - good) <= 1:
                break
            mid = (good + bad) / 2
            if is_int:
                mid = float(math.floor(mid) if far > 0 else math.ceil(mid))
                if mid in (good, bad):
                    break
            if mid in (good, bad):
                break
            if ok(mid):
                good = mid
            else:
                bad = mid
        bounds.append(good if is_int else _nice(good, ok, math.copysign(1.0, far)))
    return bounds[0], bounds[1]
