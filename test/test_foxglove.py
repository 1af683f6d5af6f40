"""Foxglove live (issue 36, item 4): ``roger run --foxglove`` serves the run to Foxglove.

An independent client, Foxglove's own (@foxglove/ws-protocol's FoxgloveClient run with node
on test/js/foxglove_client.mjs), connects to a running ``roger run --foxglove 0`` (the
real command, node processes and all), subscribes to /tf, /tf_static, /robot_description,
the spatial map's markers, the left retina and its ROI outlines, and decodes what arrives
with the ros2msg schemas the server advertised (@foxglove/rosmsg +
@foxglove/rosmsg2-serialization, as Foxglove does). The latched topics were published
before the client came: they reach it through the bridge's resend. Then Ctrl-C stops the
run, server and all.

Also: a taken port, a bad port and a host without --foxglove stop ``roger run`` with one
line; docs/foxglove-layout.json names only topics of the graph and fields of their types.
The npm packages are those of test/js/package-lock.json (``make bootstrap``'s npm ci); a
failing npm fails the test, never a skip.
"""

from __future__ import annotations

import json
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
import xml.etree.ElementTree as ET

import pytest
from conftest import REPO, WORLDS, alive
from js_packages import ensure_js_packages
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from test_e2e_run import descendants
from visualization_msgs.msg import ImageMarker

from roger_bringup.cli import main as roger_main
from roger_bringup.foxglove_node import subscription_qos
from roger_bringup.msgdefs import normalize
from roger_bringup.topics import TOPICS
from roger_sim.config import SimConfig

JS = REPO / "test" / "js"
LAYOUT = REPO / "docs" / "foxglove-layout.json"
ROGER = [sys.executable, "-m", "roger_bringup.cli"]
LEFT = "/roger/left/image_raw"
MARKERS = "/roger/spatial_map/markers"
LEFT_ROIS = "/roger/left/roi_markers"
WATCHED = ("/tf", "/tf_static", "/robot_description", MARKERS, LEFT, LEFT_ROIS)
TYPES = {t.name: normalize(t.type) for t in TOPICS}
#: Wall seconds for the run to print its server's address, and for the client.
START_S, CLIENT_S = 90, 90


@pytest.fixture(scope="module")
def node_client():
    """``node foxglove_client.mjs`` with test/js's locked packages (npm ci when missing or
    older than the lock, as test_bag_readers does)."""
    ensure_js_packages("Foxglove's WebSocket client")

    def connect(url: str, *topics: str) -> dict:
        proc = subprocess.run(["node", str(JS / "foxglove_client.mjs"), url, str(CLIENT_S),
                               *topics], capture_output=True, text=True,
                              timeout=CLIENT_S + 30)
        assert proc.stdout.strip(), f"the client printed nothing:\n{proc.stderr}"
        out = json.loads(proc.stdout)
        assert proc.returncode == 0, f"client exit {proc.returncode}: {out}\n{proc.stderr}"
        return out
    return connect


def _lines(proc: subprocess.Popen) -> queue.Queue:
    """The process's output, line by line, read by a thread (a read never blocks the test)."""
    lines: queue.Queue = queue.Queue()

    def pump() -> None:
        for line in proc.stdout:  # type: ignore[union-attr]
            lines.put(line)
        lines.put(None)
    threading.Thread(target=pump, daemon=True).start()
    return lines


def test_a_foxglove_client_decodes_the_live_run(no_leaks, tmp_path, ros_domain, node_client):
    out_dir = tmp_path / "run"
    proc = subprocess.Popen(
        [*ROGER, "run", "--world", str(WORLDS / "table1.yaml"), "--cycles", "100000",
         "--out", str(out_dir), "--quiet", "--domain-id", str(ros_domain), "--foxglove", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=REPO)
    lines, output = _lines(proc), []
    try:
        url = None
        deadline = time.monotonic() + START_S
        while url is None and time.monotonic() < deadline:
            try:
                line = lines.get(timeout=1)
            except queue.Empty:
                continue
            assert line is not None, "roger run ended:\n" + "".join(output)
            output.append(line)
            if line.strip().startswith("foxglove: ws://"):
                url = line.split()[1]
        assert url is not None, "no foxglove line:\n" + "".join(output)
        assert url.startswith("ws://127.0.0.1:") and "picked by the system" in line
        seen = node_client(url, *WATCHED)
        nodes = descendants(proc.pid)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    while (line := lines.get(timeout=10)) is not None:
        output.append(line)
    text = "".join(output)
    assert proc.returncode == 130 and "stopped by SIGINT" in text, text
    assert "Traceback" not in text, text
    left = [p for p in nodes if alive(p)]
    assert not left, f"processes still alive after SIGINT: {left}"
    port = int(url.rsplit(":", 1)[1])
    with pytest.raises(ConnectionRefusedError):  # the server went with the run
        socket.create_connection(("127.0.0.1", port), timeout=5).close()

    # Every topic of the graph, in its ROS 2 encoding, and each watched one decoded.
    assert seen["connected"] and seen["status"] == []
    assert {t.name for t in TOPICS if t.per_cycle} <= set(seen["advertised"])
    topics = seen["topics"]
    for name in WATCHED:
        entry = topics[name]
        assert (entry["schema_name"], entry["encoding"], entry["schema_encoding"]) == (
            TYPES[name], "cdr", "ros2msg"), entry
        assert entry["error"] is None and entry["decoded"] == entry["received"] > 0, entry

    links = {e.get("name") for e in ET.parse(REPO / "src/roger_sim/urdf/roger.urdf").iter("link")}
    tf, tf_static = topics["/tf"]["summary"], topics["/tf_static"]["summary"]
    assert {"roger_neck", "roger_head", "roger_left_eye", "roger_right_eye"} <= set(
        tf["child_frames"])
    assert set(tf["frames"]) | set(tf["child_frames"]) <= links
    assert "world" in tf_static["frames"] and "roger_base" in tf_static["child_frames"]
    assert set(tf_static["child_frames"]) <= links

    urdf = topics["/robot_description"]["summary"]
    assert urdf["length"] == len((REPO / "src/roger_sim/urdf/roger.urdf").read_text())
    assert '<robot name="roger">' in urdf["head"]

    markers = topics[MARKERS]["summary"]
    assert markers["markers"] > 1 and markers["actions"][0] == 3  # DELETEALL, then the map
    assert set(markers["actions"][1:]) == {0} and markers["frames"] == ["world"]

    size = SimConfig().image_size
    image = topics[LEFT]["summary"]
    assert (image["width"], image["height"], image["encoding"]) == (size, size, "32FC1")
    assert image["data_bytes"] == size * size * 4 == image["step"] * size
    assert image["frame_id"] == "roger_left_eye_optical"

    # The ROIs' outlines over that retina: four segments an ROI, one colour a segment.
    outlines = topics[LEFT_ROIS]["summary"]
    assert outlines["points"] > 0 and outlines["points"] % 8 == 0, outlines
    assert outlines["outline_colors"] * 2 == outlines["points"], outlines
    assert (outlines["type"], outlines["action"]) == (ImageMarker.LINE_LIST, ImageMarker.ADD)
    assert outlines["frame_id"] == image["frame_id"] and outlines["scale"] > 0
    assert 0 < outlines["max_u"] <= size and 0 < outlines["max_v"] <= size, outlines

    # The layout's topics are there (/roger/view only with --view).
    assert layout_topics() - {"/roger/view"} <= set(seen["advertised"])


@pytest.mark.parametrize("argv, expected", [
    (["--foxglove", "{busy}"], "foxglove: cannot serve on 127.0.0.1:{busy}: Failed to bind "
                               "port: Address already in use"),
    (["--foxglove", "70000"], "foxglove: port 70000 is not a TCP port"),
    (["--foxglove-host", "0.0.0.0"], "--foxglove-host needs --foxglove"),
])
def test_a_bad_server_stops_the_run_with_one_line(tmp_path, capsys, argv, expected):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        argv = [a.format(busy=port) for a in argv]
        with pytest.raises(SystemExit) as exc:
            roger_main(["run", "--world", str(WORLDS / "table1.yaml"), "--quiet", "--out",
                        str(tmp_path / "run"), "--domain-id", "0", *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("roger: " + expected.format(busy=port)), err
    assert len(err.splitlines()) == 1, err


def layout_topics() -> set[str]:
    """Every topic docs/foxglove-layout.json names."""
    names = set()
    for panel in json.loads(LAYOUT.read_text())["configById"].values():
        names |= set(panel.get("topics", {}))
        mode = panel.get("imageMode", {})
        names |= {mode[k] for k in ("imageTopic", "calibrationTopic") if k in mode}
        names |= set(mode.get("annotations", {}))
        names |= {p["value"].split(".", 1)[0] for p in panel.get("paths", [])}
    return names


def test_the_layout_shows_retinas_scene_and_table2_from_graph_topics():
    layout = json.loads(LAYOUT.read_text())
    panels = layout["configById"]

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(
            node["second"])
    assert sorted(leaves(layout["layout"])) == sorted(panels)
    assert layout_topics() <= set(TYPES)
    kinds = {pid.split("!")[0] for pid in panels}
    assert kinds == {"3D", "Image", "Plot"}
    images = {p["imageMode"]["imageTopic"]: p["imageMode"].get("calibrationTopic")
              for pid, p in panels.items() if pid.startswith("Image!")}
    assert images["/roger/left/image_raw"] == "/roger/left/camera_info"
    assert images["/roger/right/image_raw"] == "/roger/right/camera_info"
    assert all(TYPES[t] == "sensor_msgs/msg/Image" for t in images)
    # Each retina with the ROIs' outlines of that retina (ImageMarkers stamped like it).
    outlines = {p["imageMode"]["imageTopic"]: {t for t, c in p["imageMode"]["annotations"]
                                              .items() if c["visible"]}
                for pid, p in panels.items() if pid.startswith("Image!")}
    assert outlines["/roger/left/image_raw"] == {LEFT_ROIS}
    assert outlines["/roger/right/image_raw"] == {"/roger/right/roi_markers"}
    assert {TYPES[t] for o in outlines.values() for t in o} == {
        "visualization_msgs/msg/ImageMarker"}
    scene = next(p for pid, p in panels.items() if pid.startswith("3D!"))
    assert scene["followTf"] == "world"
    assert {"/robot_description", MARKERS} <= {t for t, c in scene["topics"].items()
                                               if c["visible"]}
    from roger_interfaces.msg import Metrics
    fields = set(Metrics.get_fields_and_field_types())
    plotted = [p["value"] for pid, c in panels.items() if pid.startswith("Plot!")
               for p in c["paths"]]
    assert all(v.startswith("/roger/metrics.") and v.split(".", 1)[1] in fields
               for v in plotted)
    table2 = {"attention_shifts", "visual_improvements", "haptic_improvements",
              "positive_identifications", "new_objects", "map_updates"}
    assert table2 <= {v.split(".", 1)[1] for v in plotted}


@pytest.mark.parametrize("offered, reliability, durability", [
    ([("reliable", "latched")], ReliabilityPolicy.RELIABLE, DurabilityPolicy.TRANSIENT_LOCAL),
    ([("reliable", "volatile")], ReliabilityPolicy.RELIABLE, DurabilityPolicy.VOLATILE),
    ([("reliable", "latched"), ("reliable", "volatile")], ReliabilityPolicy.RELIABLE,
     DurabilityPolicy.VOLATILE),
    ([("best_effort", "volatile"), ("reliable", "latched")], ReliabilityPolicy.BEST_EFFORT,
     DurabilityPolicy.VOLATILE),
])
def test_the_bridge_subscribes_with_what_every_publisher_offers(offered, reliability,
                                                                 durability):
    profiles = [QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT if r ==
                           "best_effort" else ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL if d == "latched"
                           else DurabilityPolicy.VOLATILE) for r, d in offered]
    qos = subscription_qos(profiles)
    assert (qos.reliability, qos.durability) == (reliability, durability)
