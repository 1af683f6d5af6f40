"""How a node ends and how it says it is alive (roger_common.liveness, spin_node).

A setup error exits 2 with one line; an exception raised later in a callback exits 70 with
its traceback; while a node spins, its heartbeat reaches /diagnostics. The orchestrator's
side (restarts, a stopped node) is in test_faults.py.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from ros_helpers import spin_until

from roger_common.liveness import CRASH_EXIT, HANG_TIMEOUT_S, SETUP_EXIT, Silence
from roger_common.ros_node import HeartbeatWatch


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_silence_counts_from_the_last_beat() -> None:
    clock = FakeClock()
    silence = Silence(clock)
    assert silence.silent_for("a") is None
    silence.heard("a", "roger_sim")
    for _ in range(5):
        clock.t += 0.5
        silence.tick()
        silence.heard("a", "roger_sim")
    clock.t += 0.5
    silence.tick()
    assert silence.silent_for("a") == pytest.approx(0.5)
    assert silence.longest == {"roger_sim": pytest.approx(0.5)}
    for _ in range(20):
        clock.t += 0.5
        silence.tick()
    assert silence.silent_for("a") == pytest.approx(10.5)
    silence.forget("a")
    assert silence.silent_for("a") is None


def test_silence_does_not_blame_nodes_for_the_watchers_own_stall() -> None:
    clock = FakeClock()
    silence = Silence(clock, own_stall_s=1.0)
    silence.heard("a")
    silence.tick()
    clock.t += 30.0  # the watcher itself was stopped or swapped out
    silence.tick()
    assert silence.silent_for("a") == pytest.approx(1.0)  # at most own_stall_s counts
    clock.t += 0.5
    silence.tick()
    assert silence.silent_for("a") == pytest.approx(1.5)


def test_silence_grows_when_every_turn_of_the_watcher_is_a_little_late() -> None:
    """A watcher on a loaded machine whose turns all come 1.5 s apart still sees a node
    that stopped beating fall silent for longer than HANG_TIMEOUT_S (when each late turn
    discounted its whole delay, the silence stayed 0 for ever)."""
    clock = FakeClock()
    silence = Silence(clock, own_stall_s=1.0)
    silence.heard("a")
    silence.tick()
    for _ in range(20):  # 30 s of turns 1.5 s apart, no beat
        clock.t += 1.5
        silence.tick()
    assert silence.silent_for("a") == pytest.approx(20.0)
    assert silence.silent_for("a") > HANG_TIMEOUT_S


def test_setup_error_exits_2_with_one_line(tmp_path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "roger_sim.sim_node", "--ros-args", "-p",
         f"world:={tmp_path / 'missing.yaml'}"],
        capture_output=True, text=True, timeout=120)
    assert proc.returncode == SETUP_EXIT, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and "pybullet build" not in ln]
    assert len(lines) == 1 and lines[0].startswith("roger-sim: ") \
        and "missing.yaml" in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr


#: A node that beats and, once ``trigger`` exists, raises in a timer callback.
RAISING_NODE = textwrap.dedent("""
    import os, sys
    from rclpy.node import Node
    from roger_common.ros_node import spin_node

    class Raising(Node):
        def __init__(self):
            super().__init__("roger_raising")
            self.create_timer(0.05, self.tick)

        def tick(self):
            if os.path.exists(sys.argv[1]):
                raise RuntimeError("injected fault")

    spin_node(Raising, "roger-raising", args=[])
""")


def test_callback_exception_exits_70_with_its_traceback_after_beating(no_leaks, tmp_path,
                                                                      ros_domain) -> None:
    trigger = tmp_path / "raise"
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    executor = SingleThreadedExecutor(context=context)
    listener = rclpy.create_node("test_watch", context=context)
    executor.add_node(listener)
    watch = HeartbeatWatch(listener)
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain))
    proc = subprocess.Popen([sys.executable, "-c", RAISING_NODE, str(trigger)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert spin_until(executor, lambda: watch.silent_for(proc.pid) is not None, 60), \
            "no heartbeat from the node on /diagnostics"
        assert proc.poll() is None
        trigger.touch()
        output, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        executor.shutdown()
        listener.destroy_node()
        rclpy.try_shutdown(context=context)
        context.destroy()  # the participant and its /dev/shm files go now, not at exit
    assert proc.returncode == CRASH_EXIT, output
    assert "roger-raising: a callback raised RuntimeError: injected fault" in output
    assert "Traceback (most recent call last)" in output and "in tick" in output



#: A node whose timer callback takes a second and then publishes: a SIGTERM almost always
#: lands inside it.
SLOW_PUBLISHER_NODE = textwrap.dedent("""
    import sys, time
    from rclpy.node import Node
    from std_msgs.msg import String
    from roger_common.ros_node import spin_node

    class Slow(Node):
        def __init__(self):
            super().__init__("roger_slow")
            self.pub = self.create_publisher(String, "roger_slow_out", 1)
            self.create_timer(0.05, self.tick)

        def tick(self):
            print("in callback", flush=True)
            time.sleep(1.0)
            self.pub.publish(String(data="x"))

    spin_node(Slow, "roger-slow", args=[])
""")


def test_sigterm_inside_a_callback_is_a_clean_shutdown(no_leaks, ros_domain) -> None:
    """rclpy's SIGTERM handler shuts the context down while the callback sleeps; its
    publish then raises. That is the shutdown asked for: status 0, no traceback (before,
    status 70 and a crash report: `roger chaos` counted 15 of 48 SIGTERMs so)."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain))
    proc = subprocess.Popen([sys.executable, "-c", SLOW_PUBLISHER_NODE], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            if "in callback" in line:
                break
        time.sleep(0.3)  # well inside the 1 s callback
        proc.send_signal(signal.SIGTERM)
        output, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, output
    assert "Traceback" not in output and "exiting with status" not in output, output
