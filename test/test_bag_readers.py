"""A recorded bag opens everywhere (issue 18, items 1 and 5).

One short ``roger run --record`` (the four node processes, the recorder in the
orchestrator) is read by readers that share no code with Roger, and EVERY message must
decode:

- rosbags, given the bag folder (metadata.yaml) and given the .mcap file alone; it also
  checks each type's RIHS01 hash against the definitions in the file;
- mcap-ros2-support, the decoder of the mcap project;
- Foxglove's own JavaScript readers (@mcap/core, @foxglove/rosmsg in ROS 2 mode,
  @foxglove/rosmsg2-serialization, @foxglove/wasm-zstd), run with node on
  test/js/decode_bag.mjs; a message that leaves bytes beyond CDR's alignment padding
  counts as a mismatch.

Each reader's decoded messages are compared field by field with rclpy's (fingerprints:
every scalar, every short array, length and 8 sampled elements of long ones), so a reader
that decodes into the wrong fields fails too. A killed recording is read by Foxglove's
streaming reader up to the cut.

The npm packages are those of test/js/package-lock.json, installed by `make bootstrap`
(npm ci); a missing or stale test/js/node_modules is installed here the same way, and a
failing npm fails the test (never a skip).
"""

from __future__ import annotations

import array
import dataclasses
import io
import json
import math
import random
import subprocess
from collections import defaultdict

import numpy as np
import pytest
from conftest import REPO, WORLDS
from js_packages import ensure_js_packages
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from test_record import killed_recording

from roger_bringup.record import message_counts, read_messages
from roger_bringup.run import RunOptions, run_graph
from roger_bringup.topics import TOPICS

JS = REPO / "test" / "js"
CYCLES = 5
#: As in decode_bag.mjs: arrays longer than this are fingerprinted by length and samples.
FULL_ARRAY = 64
SAMPLES = 8


def fingerprint(value):
    """decode_bag.mjs's fingerprint of a decoded message, for rclpy, rosbags and mcap_ros2
    objects alike."""
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        value = int(value)
        return value if abs(value) <= 2**53 - 1 else str(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return value
    if isinstance(value, str):
        return value
    if isinstance(value, bytes) and len(value) == 1:
        # A ``byte`` field (DiagnosticStatus.level): rclpy gives one byte, the readers an int.
        return value[0]
    if isinstance(value, (bytes, bytearray, array.array, list, tuple, np.ndarray)):
        items = value.tolist() if isinstance(value, np.ndarray) else list(value)
        if len(items) <= FULL_ARRAY:
            return [fingerprint(v) for v in items]
        picks = [items[i * (len(items) - 1) // (SAMPLES - 1)] for i in range(SAMPLES)]
        return {"len": len(items), "samples": [fingerprint(v) for v in picks]}
    if dataclasses.is_dataclass(value):  # rosbags (its __msgtype__ is not a field)
        names = [f.name for f in dataclasses.fields(value) if not f.name.startswith("__")]
    elif hasattr(value, "get_fields_and_field_types"):  # rclpy
        names = list(value.get_fields_and_field_types())
    elif hasattr(value, "__slots__"):  # mcap_ros2
        names = list(value.__slots__)
    else:
        raise TypeError(f"cannot fingerprint {type(value)}")
    # Field names are lower case; rosbags lists the constants (upper case) among them.
    return {name: fingerprint(getattr(value, name)) for name in sorted(names)
            if name == name.lower()}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A bag of ``roger run --record`` (the node processes and the orchestrator's recorder):
    (bag folder, messages per topic, rclpy's fingerprints per topic)."""
    tmp = tmp_path_factory.mktemp("readers")
    bag = tmp / "bag"
    run_graph(RunOptions(world=WORLDS / "table1.yaml", out=tmp / "out", cycles=CYCLES,
                         progress=False, domain_id=random.SystemRandom().randint(1, 101),
                         timeout_s=240, record=bag), log=io.StringIO())
    counts = message_counts(bag)
    assert counts["/roger/policy_state"] == CYCLES
    assert not [t.name for t in TOPICS if t.per_cycle and counts[t.name] == 0]
    reference = defaultdict(list)
    for topic, msg, _ in read_messages(bag):
        reference[topic].append(fingerprint(msg))
    assert {t: len(v) for t, v in reference.items()} == {t: n for t, n in counts.items() if n}
    return bag, counts, dict(reference)


@pytest.fixture(scope="module")
def foxglove():
    """``node decode_bag.mjs`` with test/js's locked packages (npm ci when missing)."""
    ensure_js_packages("Foxglove's readers")

    def decode(path, *flags):
        proc = subprocess.run(["node", str(JS / "decode_bag.mjs"), str(path), *flags],
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        return json.loads(proc.stdout)
    return decode


def rosbags_fingerprints(path):
    """rosbags' AnyReader: decode every message; (fingerprints per topic, its counts)."""
    out = defaultdict(list)
    with AnyReader([path]) as reader:
        declared = {c.topic: c.msgcount for c in reader.connections}
        assert reader.message_count == sum(declared.values())
        for connection, _, raw in reader.messages():
            out[connection.topic].append(
                fingerprint(reader.deserialize(raw, connection.msgtype)))
    return dict(out), declared


@pytest.mark.parametrize("form", ["folder", "file"])
def test_rosbags_decodes_every_message(recorded, form):
    bag, counts, reference = recorded
    path = bag if form == "folder" else bag / "bag_0.mcap"
    decoded, declared = rosbags_fingerprints(path)
    assert declared == counts
    assert decoded == reference


def test_mcap_ros2_support_decodes_every_message(recorded):
    bag, _, reference = recorded
    decoded = defaultdict(list)
    with open(bag / "bag_0.mcap", "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages(log_time_order=True):
            decoded[channel.topic].append(fingerprint(msg))
    assert dict(decoded) == reference


def test_foxglove_decodes_every_message(recorded, foxglove):
    bag, counts, reference = recorded
    out = foxglove(bag / "bag_0.mcap")
    assert out["profile"] == "ros2" and out["complete"]
    assert out["schema_errors"] == {}
    topics = out["topics"]
    assert {t: v["messages"] for t, v in topics.items()} == counts
    assert {t: v["decoded"] for t, v in topics.items()} == counts
    assert {t: (v["failed"], v["trailing"]) for t, v in topics.items() if
            v["failed"] or v["trailing"]} == {}
    assert {t: v["fingerprints"] for t, v in topics.items() if v["fingerprints"]} == reference


def test_the_bag_holds_the_roi_outlines_of_both_retinas(recorded):
    # One ImageMarker a retina for each ROI array (the readers above decode them too).
    _, counts, reference = recorded
    left, right = "/roger/left/roi_markers", "/roger/right/roi_markers"
    assert counts[left] == counts[right] == counts["/roger/rois"] > 0, counts
    assert any(fp["points"] for fp in reference[left]) and any(
        fp["points"] for fp in reference[right])


def test_foxglove_streams_a_killed_recording_up_to_the_cut(tmp_path, foxglove):
    bag = killed_recording(tmp_path)
    on_disk = message_counts(bag)
    out = foxglove(bag / "killed_0.mcap", "--stream")
    assert not out["complete"] and out["schema_errors"] == {}
    assert {t: v["decoded"] for t, v in out["topics"].items()} == on_disk
    assert on_disk["/roger/left/image_raw"] > 0
