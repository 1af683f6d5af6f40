"""A stand-in DDS graph for the leak-check tests (test_leak_check.py).

``python dds_graph.py N`` starts N participants on ``ROS_DOMAIN_ID`` as its children,
prints ``pid <pid>`` for each and waits for them. Each participant publishes its pid on
``/leak_check`` and prints ``ready <pid>`` once it has heard from another one: by then
every participant maps the others' shared-memory files, as the nodes of a Roger graph do.
"""

from __future__ import annotations

import os
import subprocess
import sys


def participant() -> None:
    """One participant: publish, listen, and say ``ready`` once a peer was heard."""
    from roger_common.dds import apply_dds_defaults

    apply_dds_defaults(os.environ)
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from std_msgs.msg import String

    rclpy.init()
    node = rclpy.create_node(f"leak_check_{os.getpid()}")
    me = str(os.getpid())
    heard = []

    def on_msg(msg: String) -> None:
        if msg.data != me and not heard:
            heard.append(msg.data)
            # One write: two participants share the launcher's stdout pipe, and print()'s
            # separate writes of text and newline interleaved ("ready 1ready 2\n\n"), which
            # the test read as one participant ready (the "did not discover" of issue 39).
            os.write(1, f"ready {me}\n".encode())

    pub = node.create_publisher(String, "/leak_check", 10)
    node.create_subscription(String, "/leak_check", on_msg, 10)
    node.create_timer(0.1, lambda: pub.publish(String(data=me)))
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def main() -> None:
    if sys.argv[1] == "--participant":
        participant()
        return
    procs = [subprocess.Popen([sys.executable, __file__, "--participant"])
             for _ in range(int(sys.argv[1]))]
    for p in procs:
        print(f"pid {p.pid}", flush=True)
    for p in procs:
        p.wait()


if __name__ == "__main__":
    main()
