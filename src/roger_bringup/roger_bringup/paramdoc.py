"""One table of every node parameter, generated from the config dataclasses (issue 10, item 4).

Most parameters of the nodes are the fields of their packages' frozen config dataclasses
(``roger_common.conversions.declare_config``): their defaults are read from the dataclass
and their meaning from its ``doc`` field metadata or the ``Attributes:`` section of its
docstring. The few parameters a node declares itself (world file, seeds, file names...)
are listed in NODE_PARAMETERS with the same description as in the node;
test/test_paramdoc.py checks both against live nodes and keeps docs/parameters.md and
docs/params_example.yaml equal to what this module writes.

Regenerate the docs: ``python -m roger_bringup.paramdoc``.
"""

from __future__ import annotations

import inspect
import json
import re
from dataclasses import MISSING, dataclass, fields, is_dataclass
from pathlib import Path
from typing import Any

from roger_attention.config import AttentionConfig, QLearningConfig, RewardConfig, SpatialMapConfig
from roger_memory.config import MemoryConfig
from roger_perception.config import PerceptionConfig
from roger_sim.config import SimConfig

REPO = Path(__file__).resolve().parents[3]
#: Parameters rclpy gives every node (documented in the text above the table).
BUILTIN: frozenset[str] = frozenset({"use_sim_time", "start_type_description_service"})
#: (node name, parameter, default, meaning) of the parameters nodes declare themselves.
NODE_PARAMETERS: tuple[tuple[str, str, Any, str], ...] = (
    ("roger_sim", "world", "worlds/table1.yaml", "World file (YAML, docs/world-files.md)"),
    ("roger_sim", "seed", 0,
     "Seed of pixel and sensor noise; same seed and world -> same images"),
    ("roger_memory", "memory_file", "",
     ("Long-term memory file; loaded at start if it exists, written atomically after each "
      "store. Empty: memory lives in RAM only.")),
    ("roger_memory", "seed", 0, "Seed of the network's initial weights and training order"),
    ("roger_attention", "seed", 0, "Seed of the policy's exploration"),
    ("roger_attention", "qtable_file", "",
     ("Q-table file: loaded at start if it exists, saved atomically after every cycle "
      "while learning. Empty: kept in RAM only.")),
    ("roger_attention", "learn", True,
     "Q-learning: update the table (training) or only run it"),
    ("roger_attention", "max_cycles", 0,
     "Stop after this many control cycles; 0 runs until shut down"),
    ("roger_attention", "home_targets",
     [0.45, 0.7, 0.0, 0.75, 0.4, 0.0, 0.9, 0.0, 0.0, 0.75, -0.4, 0.0, 0.45, -0.7, 0.0],
     ("Points (x, y, z triples, robot frame, m) fixated in turn by the initial scan that "
      "settles the map before the first cycle")),
    ("roger_attention", "wait_for_observers", 0,
     ("Start only once this many subscriptions listen on /roger/policy_state (the "
      "orchestrator's monitor sets 1), so that no cycle goes unrecorded")),
    ("roger_attention", "retry_after_s", 10.0,
     "Wall seconds without an answer before a goal or request is re-sent"),
    ("roger_view", "out_dir", "",
     "Folder for PNG frames and view.gif; empty: publish /roger/view only"),
    ("roger_view", "scale", 2, "Integer magnification of the retinas in the view"),
    ("roger_view", "fps", 4.0, "Frames per second of view.gif"),
    ("roger_view", "association_radius", 0.15,
     ("A ROI takes the interest of the spatial-map entry within this distance (m); as "
      "spatial_map.association_radius of the attention node")),
)
#: (node name, parameter prefix, config dataclass) of the generated parameters.
NODE_CONFIGS: tuple[tuple[str, str, type], ...] = (
    ("roger_sim", "", SimConfig),
    ("roger_perception", "", PerceptionConfig),
    ("roger_memory", "", MemoryConfig),
    ("roger_attention", "", AttentionConfig),
    ("roger_attention", "rewards.", RewardConfig),
    ("roger_attention", "qlearning.", QLearningConfig),
    ("roger_attention", "spatial_map.", SpatialMapConfig),
)
#: Node names in table order, with what runs them.
NODE_ORDER: tuple[tuple[str, str], ...] = (
    ("roger_sim", "roger-sim"), ("roger_perception", "roger-perception"),
    ("roger_memory", "roger-memory"), ("roger_attention", "roger-attention"),
    ("roger_view", "python -m roger_bringup.view_node"))


@dataclass(frozen=True)
class ParamRow:
    """One parameter of one node."""

    node: str
    name: str
    default: Any
    meaning: str
    source: str


def docstring_attributes(cls: type) -> dict[str, str]:
    """Field descriptions of a Google-style ``Attributes:`` section, joined to one line.

    An entry naming several fields ("a, b, c: ...") describes each of them.
    """
    doc = inspect.getdoc(cls) or ""
    out: dict[str, str] = {}
    in_section, names, text = False, [], []

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


def _default(f: Any) -> Any:
    if f.default is not MISSING:
        return f.default
    if f.default_factory is not MISSING:
        return f.default_factory()
    return None


def config_rows(node: str, prefix: str, cls: type) -> list[ParamRow]:
    """The parameters ``declare_config`` makes of a config dataclass (nested ones skipped)."""
    attrs = docstring_attributes(cls)
    rows = []
    for f in fields(cls):
        default = _default(f)
        if default is None or is_dataclass(default):
            continue
        if isinstance(default, tuple):
            default = list(default)
        meaning = (f.metadata or {}).get("doc") or attrs.get(f.name) or \
            f"{cls.__name__}.{f.name}"
        rows.append(ParamRow(node, prefix + f.name, default, meaning, cls.__name__))
    return rows


def parameter_table() -> list[ParamRow]:
    """Every parameter of the five nodes, node by node (own parameters first)."""
    rows: list[ParamRow] = []
    for node, _ in NODE_ORDER:
        rows += [ParamRow(n, name, default, meaning, "node")
                 for n, name, default, meaning in NODE_PARAMETERS if n == node]
        for n, prefix, cls in NODE_CONFIGS:
            if n == node:
                rows += config_rows(node, prefix, cls)
    return rows


def format_value(value: Any) -> str:
    """A default as YAML/ROS writes it (true, 0.5, "text", [1, 2])."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(format_value(v) for v in value) + "]"
    raise TypeError(f"no parameter format for {value!r}")


def parameters_markdown(rows: list[ParamRow] | None = None) -> str:
    """docs/parameters.md: one table of every node parameter."""
    rows = parameter_table() if rows is None else rows
    lines = [
        "# Node parameters",
        "",
        ("Every parameter of the Roger nodes, generated by `python -m roger_bringup.paramdoc` "
         "from the config dataclasses (`config.py` of each package) and the parameters the "
         "nodes declare themselves; `test/test_paramdoc.py` keeps it up to date. Set them "
         "with `-p name:=value` or a parameter file "
         "(`--ros-args --params-file docs/params_example.yaml`, which lists every default). "
         "Every node also has rclpy's `use_sim_time` (default false; `roger run` sets it "
         "true) and `start_type_description_service` (default true). "
         "Nested names such as `qlearning.alpha` are nested keys in a parameter file."),
        "",
        "| node | parameter | default | meaning | from |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        meaning = r.meaning.replace("|", "\\|")
        lines.append(f"| `{r.node}` | `{r.name}` | `{format_value(r.default)}` | {meaning} "
                     f"| {r.source} |")
    lines += ["", "How each node is started: " + ", ".join(
        f"`{node}`: `{cmd}`" for node, cmd in NODE_ORDER) + ".", ""]
    return "\n".join(lines)


def params_yaml(rows: list[ParamRow] | None = None) -> str:
    """docs/params_example.yaml: every parameter at its default, usable with --params-file."""
    rows = parameter_table() if rows is None else rows
    lines = ["# Every parameter of the Roger nodes at its default (generated by",
             "# python -m roger_bringup.paramdoc; meanings in docs/parameters.md).",
             "# Use: roger-attention --ros-args --params-file docs/params_example.yaml",
             "# (each node reads its own section). Edit a copy and keep what you change."]
    for node, _ in NODE_ORDER:
        lines += [f"{node}:", "  ros__parameters:"]
        groups: dict[str, list[ParamRow]] = {}
        for r in rows:
            if r.node != node:
                continue
            if "." in r.name:
                groups.setdefault(r.name.split(".", 1)[0], []).append(r)
            else:
                lines.append(f"    {r.name}: {format_value(r.default)}")
        for group, members in groups.items():
            lines.append(f"    {group}:")
            lines += [f"      {m.name.split('.', 1)[1]}: {format_value(m.default)}"
                      for m in members]
    return "\n".join(lines) + "\n"


def write_docs(docs: Path = REPO / "docs") -> tuple[Path, Path]:
    """Write docs/parameters.md and docs/params_example.yaml; returns their paths."""
    md, yml = docs / "parameters.md", docs / "params_example.yaml"
    md.write_text(parameters_markdown())
    yml.write_text(params_yaml())
    return md, yml


if __name__ == "__main__":
    for path in write_docs():
        print(f"wrote {path}")
