"""The parameter table (issue 10, item 4): up to date, true to the nodes, and loadable."""

from __future__ import annotations

import pytest
from conftest import REPO

from roger_attention.attention_node import AttentionNode
from roger_bringup.paramdoc import (
    BUILTIN,
    NODE_ORDER,
    parameter_table,
    parameters_markdown,
    params_yaml,
)
from roger_bringup.view_node import ViewNode
from roger_common.configdoc import docstring_attributes, field_description
from roger_memory.memory_node import MemoryNode
from roger_perception.config import PerceptionConfig
from roger_perception.perception_node import PerceptionNode
from roger_sim.sim_node import SimNode

NODE_CLASSES = {"roger_sim": SimNode, "roger_perception": PerceptionNode,
                "roger_memory": MemoryNode, "roger_attention": AttentionNode,
                "roger_view": ViewNode}


def test_docs_are_up_to_date():
    hint = "regenerate with: .venv/bin/python -m roger_bringup.paramdoc"
    assert (REPO / "docs" / "parameters.md").read_text() == parameters_markdown(), hint
    assert (REPO / "docs" / "params_example.yaml").read_text() == params_yaml(), hint


def test_every_row_has_a_meaning_and_nodes_are_covered():
    rows = parameter_table()
    assert {r.node for r in rows} == {n for n, _ in NODE_ORDER}
    assert all(r.meaning and not r.meaning.endswith(f"Config.{r.name}") for r in rows)
    names = [(r.node, r.name) for r in rows]
    assert len(names) == len(set(names))
    assert ("roger_attention", "qlearning.alpha") in names


def test_docstring_attributes_split_shared_entries():
    attrs = docstring_attributes(PerceptionConfig)
    assert attrs["weight_size"] == attrs["weight_unmapped"]
    assert "activation" in attrs["weight_size"]
    assert attrs["log_sigmas"].endswith("strictly increasing.")


def test_a_field_without_a_description_is_refused():
    from dataclasses import dataclass

    @dataclass(frozen=True)
    class Undocumented:
        """No attributes section."""

        x: int = 0

    with pytest.raises(KeyError, match="Undocumented.x"):
        field_description(Undocumented, "x")


def _value(v):
    return list(v) if not isinstance(v, (str, bool, int, float)) else v


@pytest.fixture
def context(ros_context):
    return ros_context  # in the repository folder: the sim's default world is relative


def _build(name, ctx, cli_args=None):
    return NODE_CLASSES[name](context=ctx, cli_args=cli_args) if cli_args else \
        NODE_CLASSES[name](context=ctx)


def test_table_matches_the_live_nodes(no_leaks, context):
    rows = parameter_table()
    for name, _ in NODE_ORDER:
        node = _build(name, context)
        try:
            live = {p: node.get_parameter(p).value
                    for p in node.list_parameters([], 0).names if p not in BUILTIN}
            documented = {r.name: r for r in rows if r.node == name}
            assert set(live) == set(documented), name
            for pname, row in documented.items():
                value = _value(live[pname])
                assert value == row.default, f"{name}.{pname}: {value!r} != {row.default!r}"
                # One description, written once: the node says what the table says.
                assert node.describe_parameter(pname).description == row.meaning
        finally:
            node.destroy_node()


def test_params_file_sets_every_node(no_leaks, context, tmp_path):
    text = params_yaml()
    changed = (text.replace("    policy: \"straightforward\"", "    policy: \"qlearning\"")
               .replace("      alpha: 0.5", "      alpha: 0.25")
               .replace("    scale: 2", "    scale: 3")
               .replace("    image_size: 128", "    image_size: 96")
               .replace("    samples_m: 32", "    samples_m: 16")
               .replace('    maskable_features: ["W", "TH", "TK", "TC", "TR", "AP", "O"]',
                        '    maskable_features: ["W", "D"]'))
    path = tmp_path / "params.yaml"
    path.write_text(changed)
    expected = {"roger_attention": {"policy": "qlearning", "qlearning.alpha": 0.25},
                "roger_view": {"scale": 3}, "roger_sim": {"image_size": 96},
                "roger_perception": {"samples_m": 16},
                "roger_memory": {"maskable_features": ["W", "D"]}}
    for name, values in expected.items():
        node = _build(name, context, ["--ros-args", "--params-file", str(path)])
        try:
            for pname, want in values.items():
                assert _value(node.get_parameter(pname).value) == want, f"{name}.{pname}"
        finally:
            node.destroy_node()
    assert changed != text
