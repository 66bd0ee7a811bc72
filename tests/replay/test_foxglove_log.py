"""Gating changes as Foxglove log lines: one line per change, overlaps are not rejections."""

from __future__ import annotations

import numpy as np
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Log_pb2 import Log
from scipy.spatial.transform import Rotation

from replay.foxglove import GatingLog, frame_transform, log_line


def test_a_run_of_rejections_is_two_lines_and_overlaps_are_none() -> None:
    gate = GatingLog()
    reasons = [None, "overlapping", None, "rpm_unsteady", "overlapping", "rpm_unsteady", None]
    lines = [gate.update(r, 2000.0 + 10 * k) for k, r in enumerate(reasons)]
    assert lines == [
        None,
        None,
        None,
        ("warning", "frames rejected from 2030 rpm: rpm_unsteady"),
        None,
        None,
        ("info", "frames used again from 2060 rpm, after 2 rejected (rpm_unsteady)"),
    ]


def test_a_log_line_and_a_transform_read_back_with_foxglove_classes() -> None:
    log = Log.FromString(log_line(1_700_000_000_123_456_789, "warning", "gap: lost 3", "source"))
    assert (log.timestamp.seconds, log.timestamp.nanos) == (1_700_000_000, 123_456_789)
    assert (log.level, log.name, log.message) == (Log.WARNING, "source", "gap: lost 3")
    rot = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix()
    tf = FrameTransform.FromString(frame_transform(5, "bench", "moving", [0.1, 0.2, 0.3], rot))
    q = [tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w]
    # the quaternion Foxglove applies rotates child axes as the matrix does
    np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), rot, atol=1e-12)
    assert (tf.parent_frame_id, tf.child_frame_id) == ("bench", "moving")
