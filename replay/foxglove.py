"""Foxglove's well-known schemas in a recording: the 3D scene, the moving frames, the event log.

Foxglove draws a 3D panel only from its own schemas (``foxglove.SceneUpdate``,
``foxglove.FrameTransform``) and lists events only from ``foxglove.Log``; our
``ptinertia.log`` messages are plotted but never drawn. The messages here are
built with the published classes of ``foxglove-schemas-protobuf`` (the
package Foxglove maintains), and each channel's schema is the
``FileDescriptorSet`` of its class with every file it imports, which is what
Foxglove and ``mcap-protobuf-support`` decode with. (Hand-laid descriptors, as
:mod:`replay.schemas` does for our own messages, would have to follow every
change of Foxglove's; the package is that definition.)

Topics (``docs/recording-format.md``):

* ``/foxglove/scene`` (SceneUpdate): the bench (mounts, nominal cog, sensors with
  their measuring axes) once at the start, then the estimated body (the uniform
  box with the estimated principal moments and mass, its principal axes, the cog
  and its 2-sigma ellipsoid) as the estimate changes;
* ``/foxglove/tf`` (FrameTransform): ``bench`` -> ``moving`` (the animated,
  exaggerated rigid motion), ``moving`` -> ``powertrain`` (cog and principal
  axes of the estimate), ``bench`` -> ``cog`` (cog and ellipsoid axes);
* ``/foxglove/log`` (Log): the source's and the dsp's events, the estimator's
  (an elastic mode), and gating changes (frames start or stop being rejected).

Lengths in m, angles in rad; a rotation is a (3, 3) matrix whose columns are
the child frame's axes in the parent frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.ArrowPrimitive_pb2 import ArrowPrimitive
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.SpherePrimitive_pb2 import SpherePrimitive
from foxglove_schemas_protobuf.TextPrimitive_pb2 import TextPrimitive
from google.protobuf import descriptor_pb2
from google.protobuf.timestamp_pb2 import Timestamp
from scipy.spatial.transform import Rotation

TOPIC_SCENE = "/foxglove/scene"
TOPIC_TF = "/foxglove/tf"
TOPIC_LOG = "/foxglove/log"
# topic -> schema name (the message's full protobuf name, which Foxglove recognises)
TOPICS = {
    TOPIC_SCENE: "foxglove.SceneUpdate",
    TOPIC_TF: "foxglove.FrameTransform",
    TOPIC_LOG: "foxglove.Log",
}
_CLASSES: dict[str, Any] = {
    "SceneUpdate": SceneUpdate,
    "FrameTransform": FrameTransform,
    "Log": Log,
}

# frame ids
BENCH, MOVING, POWERTRAIN, COG = "bench", "moving", "powertrain", "cog"

LEVELS = {"info": Log.INFO, "warning": Log.WARNING, "error": Log.ERROR}
# events that say all is well (logged as info); the others (gaps, tacho loss, an elastic
# mode, bus errors ...) are warnings
INFO_EVENTS = frozenset({"tacho_sync", "waiting", "bus_reopened", "can_stats"})

RGBA = tuple[float, float, float, float]
Vec = Sequence[float] | np.ndarray  # (3,) m


@cache
def schema_data(name: str) -> bytes:
    """The ``FileDescriptorSet`` of the Foxglove message ``name`` and of every file it imports."""
    cls = _CLASSES[name.removeprefix("foxglove.")]
    fds = descriptor_pb2.FileDescriptorSet()
    seen: set[str] = set()

    def add(file: Any) -> None:  # dependencies first, each once
        if file.name in seen:
            return
        seen.add(file.name)
        for dep in file.dependencies:
            add(dep)
        file.CopyToProto(fds.file.add())

    add(cls.DESCRIPTOR.file)
    return fds.SerializeToString()


def _stamp(t_ns: int) -> Timestamp:
    return Timestamp(seconds=t_ns // 1_000_000_000, nanos=t_ns % 1_000_000_000)


def _pose(position: Vec, rotation: np.ndarray | None = None) -> Pose:
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in position)
    x, y, z, w = (0.0, 0.0, 0.0, 1.0) if rotation is None else _quaternion(rotation)
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = x, y, z, w
    return pose


def _quaternion(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix (scipy: orthonormalised, sign with w >= 0)."""
    q = Rotation.from_matrix(np.asarray(rotation, dtype=float)).as_quat(canonical=True)
    return float(q[0]), float(q[1]), float(q[2]), float(q[3])


def _color(rgba: RGBA) -> Color:
    return Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def cube(center: Vec, size: Vec, rgba: RGBA, rotation: Any = None) -> Any:
    """A box of full edge lengths ``size`` (m)."""
    c = CubePrimitive(pose=_pose(center, rotation), color=_color(rgba))
    c.size.x, c.size.y, c.size.z = (float(v) for v in size)
    return c


def sphere(center: Vec, size: Vec, rgba: RGBA, rotation: Any = None) -> Any:
    """An ellipsoid of full diameters ``size`` (m) along the rotated axes."""
    s = SpherePrimitive(pose=_pose(center, rotation), color=_color(rgba))
    s.size.x, s.size.y, s.size.z = (float(v) for v in size)
    return s


def arrow(origin: Vec, vector: Vec, rgba: RGBA) -> Any:
    """An arrow from ``origin`` along ``vector`` (its length is the arrow's, m)."""
    v = np.asarray(vector, dtype=float)
    length = float(np.linalg.norm(v))
    # Foxglove's arrow points along the pose's +x: rotate +x onto the vector
    rot = Rotation.align_vectors([v / max(length, 1e-12)], [[1.0, 0.0, 0.0]])[0].as_matrix()
    head = 0.25 * length
    return ArrowPrimitive(
        pose=_pose(origin, rot),
        shaft_length=length - head,
        shaft_diameter=0.08 * head,
        head_length=head,
        head_diameter=0.4 * head,
        color=_color(rgba),
    )


def text(position: Vec, label: str, rgba: RGBA = (0.1, 0.1, 0.1, 1.0)) -> Any:
    """A label that always faces the camera, 12 px whatever the zoom."""
    return TextPrimitive(
        pose=_pose(position),
        billboard=True,
        font_size=12.0,
        scale_invariant=True,
        color=_color(rgba),
        text=label,
    )


def entity(t_ns: int, frame_id: str, entity_id: str, primitives: Sequence[Any]) -> Any:
    """A scene entity holding ``primitives`` (cubes, spheres, arrows, texts) in ``frame_id``."""
    e = SceneEntity(timestamp=_stamp(t_ns), frame_id=frame_id, id=entity_id, frame_locked=True)
    kinds = {
        CubePrimitive: e.cubes,
        SpherePrimitive: e.spheres,
        ArrowPrimitive: e.arrows,
        TextPrimitive: e.texts,
    }
    for p in primitives:
        kinds[type(p)].append(p)
    return e


def scene_update(entities: Sequence[Any]) -> bytes:
    """A SceneUpdate adding (or replacing, by id) ``entities``."""
    return SceneUpdate(entities=list(entities)).SerializeToString()


def frame_transform(
    t_ns: int, parent: str, child: str, translation: Vec, rotation: np.ndarray
) -> bytes:
    """The pose of ``child`` in ``parent``: ``x_parent = rotation @ x_child + translation``."""
    msg = FrameTransform(timestamp=_stamp(t_ns), parent_frame_id=parent, child_frame_id=child)
    msg.translation.x, msg.translation.y, msg.translation.z = (float(v) for v in translation)
    x, y, z, w = _quaternion(rotation)
    msg.rotation.x, msg.rotation.y, msg.rotation.z, msg.rotation.w = x, y, z, w
    return msg.SerializeToString()


def log_line(t_ns: int, level: str, message: str, name: str) -> bytes:
    """A Log record; ``level`` is ``info``, ``warning`` or ``error``, ``name`` who says it."""
    return Log(
        timestamp=_stamp(t_ns), level=LEVELS[level], message=message, name=name
    ).SerializeToString()


class GatingLog:
    """Turns the per-frame gating decisions into log lines where they change.

    One line when frames start being rejected (or the reason changes), one when
    they are used again, with how many were rejected; frames skipped because
    they overlap the last used one are neither (their data are in the estimate).
    """

    def __init__(self) -> None:
        self.reason: str | None = None  # the current run's rejection reason, None when in use
        self.count = 0  # frames rejected in the current run

    def update(self, reason: str | None, rpm: float) -> tuple[str, str] | None:
        """``(level, message)`` when the gating changes at this frame, else None."""
        if reason == "overlapping" or reason == self.reason:
            self.count += reason is not None and reason != "overlapping"
            return None
        before, n = self.reason, self.count
        self.reason, self.count = reason, int(reason is not None)
        if reason is not None:
            return "warning", f"frames rejected from {rpm:.0f} rpm: {reason}"
        return "info", f"frames used again from {rpm:.0f} rpm, after {n} rejected ({before})"
