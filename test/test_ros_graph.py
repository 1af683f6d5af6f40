"""Integration: the four nodes in one process, one executor, a per-test Context.

Bounded spin_once loops that wait on a flag, never bare sleeps.
"""

from __future__ import annotations

import pytest
from conftest import WORLDS
from ros_helpers import TopicListener, ros_graph, spin_until

from roger_attention.attention_node import AttentionNode
from roger_bringup.topics import TOPICS
from roger_interfaces.msg import Metrics, PolicyState, WorldEdit, WorldObject
from roger_interfaces.srv import EditWorld
from roger_memory.memory_node import MemoryNode
from roger_perception.perception_node import PerceptionNode
from roger_sim.sim_node import SimNode


class Listener(TopicListener):
    """Counts messages on every documented topic and keeps the policy states."""

    def __init__(self, **kwargs) -> None:
        super().__init__("test_listener", **kwargs)
        self.states: list[PolicyState] = []
        self.metrics: list[Metrics] = []

    def on_message(self, topic, msg) -> None:
        if isinstance(msg, PolicyState):
            self.states.append(msg)
        elif isinstance(msg, Metrics):
            self.metrics.append(msg)


@pytest.fixture
def graph(ros_domain, tmp_path):
    with ros_graph(ros_domain) as g:
        yield (lambda cls, **params: g.add(cls, params=params)), g.executor, tmp_path


@pytest.mark.parametrize("policy", ["straightforward", "qlearning"])
def test_four_nodes_run_cycles_and_every_topic_carries_messages(no_leaks, graph, policy):
    add, executor, tmp = graph
    listener = add(Listener)
    add(SimNode, world=str(WORLDS / "table1.yaml"), seed=1)
    add(PerceptionNode)
    add(MemoryNode, memory_file=str(tmp / "ltm.pt"))
    add(AttentionNode, policy=policy, max_cycles=12, qtable_file=str(tmp / "q.json"))
    assert spin_until(executor, lambda: any(m.done for m in listener.metrics), 120), \
        f"no completed run; topic counts {listener.counts}"
    spin_until(executor, lambda: len(listener.states) >= 12, 5)
    silent = [t.name for t in TOPICS if t.per_cycle and listener.counts[t.name] == 0]
    assert not silent, f"documented topics that carried nothing: {silent}"
    cycles = [s.cycle for s in listener.states]
    assert cycles == list(range(1, 13))
    final = listener.metrics[-1]
    assert final.cycles == 12
    assert final.attention_shifts + final.improvements + final.map_updates == final.cycles
    assert final.map_updates == (final.positive_identifications + final.new_objects
                                 + final.remaps)
    assert final.attention_shifts >= 1
    if policy == "qlearning":
        assert (tmp / "q.json").exists()


def test_world_edit_service_adds_and_refuses(no_leaks, graph):
    add, executor, _ = graph
    sim = add(SimNode, world=str(WORLDS / "table1.yaml"))
    client_node = add(Listener)
    client = client_node.create_client(EditWorld, "/roger/edit_world")
    assert spin_until(executor, client.service_is_ready, 10)

    def call(op, **obj):
        req = EditWorld.Request(edit=WorldEdit(op=op, object=WorldObject(**obj)))
        future = client.call_async(req)
        assert spin_until(executor, future.done, 10)
        return future.result()

    ok = call(WorldEdit.ADD, name="newbox", shape="box", x=0.45, y=0.0, size=0.1,
              intensity=120.0, weight=0.8, texture="plain")
    assert ok.ok, ok.message
    assert "newbox" in [o.name for o in sim.sim.world.objects]
    dup = call(WorldEdit.ADD, name="newbox", shape="box", x=0.5, y=-0.3, size=0.1,
               intensity=120.0, weight=0.8, texture="plain")
    assert not dup.ok and "newbox" in dup.message
    gone = call(WorldEdit.REMOVE, name="newbox")
    assert gone.ok
    assert "newbox" not in [o.name for o in sim.sim.world.objects]
    missing = call(WorldEdit.REMOVE, name="nothing")
    assert not missing.ok
