"""Topic names live in one place (roger_common.topics): the nodes, the launcher and the
tools take them from there, and the table documents every one of them."""

from __future__ import annotations

import ast
from pathlib import Path

from roger_common import topics

SRC = Path(__file__).resolve().parents[1] / "src"
HOME = SRC / "roger_common" / "roger_common" / "topics.py"


def topic_names() -> dict[str, str]:
    """Value -> constant name of every name constant in roger_common.topics."""
    return {value: name for name, value in vars(topics).items()
            if name.isupper() and isinstance(value, str) and value.startswith("/")}


def test_every_topic_of_the_table_has_a_name_constant_and_every_constant_a_row() -> None:
    names = topic_names()
    rows = [t.name for t in topics.TOPICS]
    assert len(rows) == len(set(rows))
    assert set(rows) == set(names) - {topics.EDIT_WORLD_SERVICE}


def test_no_topic_name_is_written_as_a_string_outside_its_home() -> None:
    names = topic_names()
    found = []
    for path in sorted(SRC.rglob("*.py")):
        if path == HOME:
            continue
        tree = ast.parse(path.read_text(), str(path))
        docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                      if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef,
                                           ast.AsyncFunctionDef))
                      and node.body and isinstance(node.body[0], ast.Expr)
                      and isinstance(node.body[0].value, ast.Constant)}
        for node in ast.walk(tree):
            if (isinstance(node, ast.Constant) and isinstance(node.value, str)
                    and node.value in names and id(node) not in docstrings):
                found.append(f"{path.relative_to(SRC)}:{node.lineno}: {node.value!r} "
                             f"(use topics.{names[node.value]})")
    assert found == [], "\n".join(found)


def test_the_launcher_module_still_offers_the_table() -> None:
    from roger_bringup import topics as bringup_topics

    assert bringup_topics.TOPICS is topics.TOPICS


def test_the_readme_lists_every_topic_as_the_table_has_it() -> None:
    """README.md's node-graph table shows topics.TOPICS: every topic, with its type, QoS
    and publisher, and nothing else."""
    readme = (SRC.parent / "README.md").read_text(encoding="utf-8")
    rows = {}
    for line in readme.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 6 and cells[0].startswith("`/"):
            rows[cells[0].strip("`")] = (cells[1].strip("`"), cells[2], cells[3].replace("`", ""))
    table = {t.name: (t.type, t.qos, t.publisher) for t in topics.TOPICS}
    assert rows == table
