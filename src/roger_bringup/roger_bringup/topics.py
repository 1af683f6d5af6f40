"""The documented topics of the Roger graph (kept for callers of this module): the table and
the names live in ``roger_common.topics``, where the nodes can import them."""

from roger_common.topics import QOS_PROFILES, TOPICS, Topic

__all__ = ["QOS_PROFILES", "TOPICS", "Topic"]
