"""The recording's Foxglove topics, decoded with Foxglove's own published schemas.

Nothing of ptinertia decodes here: the messages are parsed with the classes of
``foxglove-schemas-protobuf`` and, independently, with the ``FileDescriptorSet``
embedded in the file (``mcap-protobuf-support``, as Foxglove does). The scene
must hold the bench, the sensors, the estimated body and the cog; the body's box
must have the estimated principal moments (uniform box: ``I1 = m (b^2 + c^2) / 12``).
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from support.report_logs import realistic_log

from ptinertia.config import load_bench
from ptinertia.paths import DEFAULT_BENCH

CLASSES = {"/foxglove/scene": SceneUpdate, "/foxglove/tf": FrameTransform, "/foxglove/log": Log}


@pytest.fixture(scope="module")
def foxglove_messages(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[dict[str, list[tuple[int, Any]]], dict[str, Any]]:
    log, doc = realistic_log(tmp_path_factory)
    found: dict[str, list[tuple[int, Any]]] = defaultdict(list)
    with open(log, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None
        for channel in summary.channels.values():
            if channel.topic in CLASSES:
                schema = summary.schemas[channel.schema_id]
                assert schema.name == CLASSES[channel.topic].DESCRIPTOR.full_name
                assert (schema.encoding, channel.message_encoding) == ("protobuf", "protobuf")
        for _, channel, message, decoded in reader.iter_decoded_messages(topics=list(CLASSES)):
            ours = CLASSES[channel.topic].FromString(message.data)
            # the embedded schema and the published class read the same message
            assert ours.SerializeToString() == decoded.SerializeToString()
            found[channel.topic].append((message.log_time, ours))
    return found, json.loads(Path(doc).read_text())


def test_the_scene_holds_the_bench_the_sensors_and_the_estimated_body(
    foxglove_messages: tuple[dict[str, list[tuple[int, Any]]], dict[str, Any]],
) -> None:
    found, _ = foxglove_messages
    entities = {e.id: e for _, update in found["/foxglove/scene"] for e in update.entities}
    bench_file = load_bench(DEFAULT_BENCH)
    sensors = [s.name for s in bench_file.sensors]
    mounts = {m.name for m in bench_file.mounts}
    assert set(entities) == {"bench", "powertrain", "cog", *(f"sensor/{s}" for s in sensors)}
    bench = entities["bench"]
    assert len(bench.cubes) == len(mounts)
    assert {t.text for t in bench.texts} == {*mounts, "nominal cog"}
    for s in sensors:
        sensor = entities[f"sensor/{s}"]
        assert sensor.frame_id == "moving" and len(sensor.arrows) == 3  # a triaxial sensor
    assert len(entities["powertrain"].cubes) == 1 and len(entities["powertrain"].arrows) == 3
    assert entities["cog"].frame_id == "cog" and len(entities["cog"].spheres) == 1


def test_the_box_has_the_estimated_principal_moments(
    foxglove_messages: tuple[dict[str, list[tuple[int, Any]]], dict[str, Any]],
) -> None:
    found, doc = foxglove_messages
    last = [e for _, u in found["/foxglove/scene"] for e in u.entities if e.id == "powertrain"][-1]
    size = last.cubes[0].size
    a2 = np.array([size.x, size.y, size.z]) ** 2
    mass = doc["truth"]["mass_kg"]["value"]  # the weighed mass: an inline 3 does not estimate it
    box = mass / 12 * np.array([a2[1] + a2[2], a2[0] + a2[2], a2[0] + a2[1]])
    # the last body drawn is at most 0.5 s of stream older than the final estimate
    np.testing.assert_allclose(box, doc["principal"]["moments_kgm2"], rtol=0.02)


def test_frames_move_and_sit_at_the_estimated_cog(
    foxglove_messages: tuple[dict[str, list[tuple[int, Any]]], dict[str, Any]],
) -> None:
    found, doc = foxglove_messages
    by_child: dict[str, list[Any]] = defaultdict(list)
    for _, tf in found["/foxglove/tf"]:
        q = tf.rotation
        assert abs(q.x**2 + q.y**2 + q.z**2 + q.w**2 - 1) < 1e-9
        by_child[(tf.parent_frame_id, tf.child_frame_id)].append(tf)
    assert set(by_child) == {("bench", "moving"), ("moving", "powertrain"), ("bench", "cog")}
    moving = by_child[("bench", "moving")]
    assert len(moving) > 100  # animated at 10 poses per second of stream over 20 s
    assert len({(m.rotation.x, m.rotation.y, m.translation.z) for m in moving}) > 20
    cog = by_child[("bench", "cog")][-1].translation
    np.testing.assert_allclose([cog.x, cog.y, cog.z], doc["cog_m"]["value"], atol=2e-3)


def test_events_and_gating_changes_are_log_lines(
    foxglove_messages: tuple[dict[str, list[tuple[int, Any]]], dict[str, Any]],
) -> None:
    found, _ = foxglove_messages
    lines = [(log.level, log.name, log.message) for _, log in found["/foxglove/log"]]
    # the order tracker's tacho synchronisation: an event of the dsp, all is well
    assert (Log.INFO, "dsp") in {(lv, name) for lv, name, msg in lines if "tacho_sync" in msg}
    rejected = [m for lv, n, m in lines if n == "gating" and lv == Log.WARNING]
    assert rejected and all(m.startswith("frames rejected from") for m in rejected)
    # the dsp settles on its first frame, then every frame is used or skipped (overlaps)
    assert [m.split(": ")[-1] for m in rejected] == ["dsp_settling"]
    assert any(m.startswith("frames used again") for lv, n, m in lines if lv == Log.INFO)
    times = [t for t, _ in found["/foxglove/log"]]
    assert all(t > 10**18 for t in times)  # on the run's date, as every other topic


def test_the_docs_layout_opens_topics_and_fields_the_recording_has(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    layout = json.loads((Path(__file__).parents[3] / "docs" / "foxglove-layout.json").read_text())
    log, _ = realistic_log(tmp_path_factory)
    with open(log, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None
        topics = {c.topic for c in summary.channels.values()}
        fields = {}
        for _, channel, _, decoded in reader.iter_decoded_messages(topics=["/estimate", "/orders"]):
            fields.setdefault(channel.topic, {f.name for f in decoded.DESCRIPTOR.fields})
    config = layout["configById"]
    panels: set[str] = set()

    def leaves(node: Any) -> None:
        if isinstance(node, str):
            panels.add(node)
        else:
            leaves(node["first"])
            leaves(node["second"])

    leaves(layout["layout"])
    assert panels == set(config)  # every panel placed, none missing
    assert set(config["3D!ptinertia"]["topics"]) <= topics
    assert config["Log!events"]["topicToRender"] in topics
    for key in (k for k in config if k.startswith("Plot!")):
        for path in config[key]["paths"]:
            topic, field = path["value"].split(".", 1)
            assert field in fields[topic], path
