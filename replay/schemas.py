"""Protobuf message types of a recording, built at run time (no ``protoc`` needed).

The schema is one proto3 file, ``ptinertia/log.proto`` (package
``ptinertia.log``), written into every recording as a serialised
``FileDescriptorSet`` (schema encoding ``"protobuf"``), so any MCAP reader --
Foxglove, the ``mcap`` CLI, ``mcap-protobuf-support`` -- decodes the messages
without our code. :func:`proto_text` prints it in ``.proto`` syntax for the docs.

Bulk arrays. ``SampleBlock.data`` is ``repeated float`` and ``EdgeBlock.times_s``
``repeated double``: self-describing for any reader. A proto3 packed repeated
field is on the wire exactly a length-delimited run of little-endian values,
the same bytes as a ``bytes`` field with the same number. Our own writer and
reader use a *twin* of those two messages in a separate descriptor pool, with
``bytes`` in place of the packed arrays, so samples go through
``ndarray.tobytes`` / ``np.frombuffer``: setting a repeated field from an array
converts one Python float per sample (12 ms for a 0.1 s block of 10 channels
at 25.6 kHz, against 34 us through the twin; that is what lets a simulation
or a replay run hundreds of times real time). A test checks that the public
types decode what the twins write.
"""

from __future__ import annotations

from functools import cache
from typing import Any

from google.protobuf import descriptor_pb2
from google.protobuf.descriptor_pool import DescriptorPool
from google.protobuf.message_factory import GetMessageClass

from acquisition.stream import StreamLayout
from replay.foxglove import TOPICS as FOXGLOVE_TOPICS

PACKAGE = "ptinertia.log"
FILE_NAME = "ptinertia/log.proto"
SCHEMA_VERSION = 1

_F = descriptor_pb2.FieldDescriptorProto
_SCALARS = {
    "double": _F.TYPE_DOUBLE,
    "float": _F.TYPE_FLOAT,
    "int64": _F.TYPE_INT64,
    "uint32": _F.TYPE_UINT32,
    "bool": _F.TYPE_BOOL,
    "string": _F.TYPE_STRING,
    "bytes": _F.TYPE_BYTES,
}

# Estimator parameters that get a named value/std field pair in Estimate, so a
# plot panel can show "/estimate.Ixx" directly (``estimator.equations.ParameterLayout``).
PARAMETERS = (
    "Ixx",
    "Iyy",
    "Izz",
    "Ixy",
    "Ixz",
    "Iyz",
    "Gx",
    "Gy",
    "Gz",
    "unb_re",
    "unb_im",
    "inv_mass",
    "crank_offset",
)

# message -> [(field, number, type, repeated, comment)]; a type that is not a
# scalar names another message of this file.
MESSAGES: dict[str, list[tuple[str, int, str, bool, str]]] = {
    "SampleBlock": [
        ("time_s", 1, "double", False, "first sample time, s: t0_s + first_index / rate_hz"),
        ("group", 2, "string", False, "sample group name"),
        ("first_index", 3, "int64", False, "grid index of the first sample"),
        ("rate_hz", 4, "double", False, "sample rate of the group, Hz"),
        ("t0_s", 5, "double", False, "time of grid index 0, s"),
        ("channels", 6, "string", True, "channel names, in row order"),
        ("n_samples", 7, "uint32", False, "samples per channel"),
        ("data", 8, "float", True, "(n_channels, n_samples) channel-major, channel units"),
    ],
    "EdgeBlock": [
        ("time_s", 1, "double", False, "first edge time, s (last known time when empty)"),
        ("channel", 2, "string", False, "edge channel name"),
        ("times_s", 3, "double", True, "edge times, s"),
    ],
    "SourceEvent": [
        ("time_s", 1, "double", False, "event time, s (when has_time)"),
        ("kind", 2, "string", False, "short tag: gap, bus_off, nan, ..."),
        ("message", 3, "string", False, "one line for the user"),
        ("has_time", 4, "bool", False, "false when the event carries no time"),
        ("count", 5, "uint32", False, "how many occurrences the event stands for"),
        ("origin", 6, "string", False, "'source' (a raw stream item) or 'dsp' (from processing)"),
    ],
    "CanFrames": [
        ("time_s", 1, "double", False, "stream time when the batch was received, s"),
        ("timestamp_ns", 2, "int64", True, "receive time per frame (host or log clock), ns"),
        ("arbitration_id", 3, "uint32", True, "CAN id per frame"),
        ("flags", 4, "uint32", True, "per frame: bit 0 extended id, bit 1 CAN FD"),
        ("length", 5, "uint32", True, "payload bytes per frame"),
        ("data", 6, "bytes", False, "the payloads, concatenated"),
    ],
    "ChannelAmplitude": [
        ("channel", 1, "string", False, "channel name"),
        ("amplitude", 2, "double", False, "|X|, channel units"),
        ("phase_deg", 3, "double", False, "arg X, deg"),
        ("ok", 4, "bool", False, "channel_ok of the frame"),
    ],
    "OrderAmplitudes": [
        ("order", 1, "double", False, "engine order"),
        ("channels", 2, "ChannelAmplitude", True, "one entry per channel"),
    ],
    "OrderFrame": [
        ("time_s", 1, "double", False, "time of the window centre, s"),
        ("rpm", 2, "double", False, "mean speed over the window, rpm"),
        ("crank_angle_rad", 3, "double", False, "crank angle at time_s, rad (unwrapped)"),
        ("orders", 4, "double", True, "tracked orders"),
        ("channels", 5, "string", True, "channel names"),
        ("amplitude_re", 6, "double", True, "Re X, (n_orders, n_channels) order-major"),
        ("amplitude_im", 7, "double", True, "Im X, (n_orders, n_channels) order-major"),
        ("channel_ok", 8, "bool", True, "per channel"),
        ("rpm_change", 9, "double", False, "(rpm_last - rpm_first) / rpm across the window"),
        ("leakage", 10, "double", True, "per channel, relative"),
        ("flags", 11, "string", True, "frame flags (dsp.frames.FLAGS)"),
        ("by_order", 12, "OrderAmplitudes", True, "per order and channel, for plots"),
        ("spectrum_channel", 13, "string", False, "channel of the spectrum (empty: none)"),
        ("spectrum_re", 14, "double", True, "Re of orders 0, 0.5, 1, .. of spectrum_channel"),
        ("spectrum_im", 15, "double", True, "Im of the same (empty: the frame has no spectrum)"),
    ],
    "OrderGate": [
        ("order", 1, "double", False, "engine order"),
        ("used", 2, "bool", False, "the order's rows went into the estimate"),
        ("rejected", 3, "string", False, "why the order was rejected (empty when not)"),
        ("relative_residual", 4, "double", False, "rigid-body fit residual, relative"),
        ("has_residual", 5, "bool", False, "relative_residual was computed"),
    ],
    "Gating": [
        ("time_s", 1, "double", False, "frame time, s"),
        ("rpm", 2, "double", False, "frame rpm"),
        ("used", 3, "bool", False, "the frame went into the estimate"),
        ("reason", 4, "string", False, "why the whole frame was rejected (empty when used)"),
        ("used_orders", 5, "double", True, "orders used"),
        ("orders", 6, "OrderGate", True, "per order"),
    ],
    "Count": [
        ("key", 1, "string", False, "reason"),
        ("count", 2, "uint32", False, "occurrences"),
    ],
    "Estimate": [
        ("time_s", 1, "double", False, "time of the frame that produced this estimate, s"),
        ("rpm", 2, "double", False, "rpm of that frame"),
        ("frames_used", 3, "uint32", False, "frames in the estimate"),
        ("variance_factor", 4, "double", False, "a posteriori variance factor"),
        ("mass_kg", 5, "double", False, "1 / inv_mass when estimated, else the nominal mass"),
        ("mass_kg_std", 6, "double", False, "std of mass_kg (0 when the mass is known)"),
        *[
            item
            for i, name in enumerate(PARAMETERS)
            for item in (
                (name, 10 + 2 * i, "double", False, f"{name} (SI units; 0 when not estimated)"),
                (f"{name}_std", 11 + 2 * i, "double", False, f"std of {name} (inf: unobservable)"),
            )
        ],
        ("names", 50, "string", True, "parameter names, in theta order"),
        ("theta", 51, "double", True, "parameter values"),
        ("cov", 52, "double", True, "(n, n) total; empty: cov_random + cov_systematic"),
        ("cov_random", 53, "double", True, "(n, n) random part"),
        ("cov_systematic", 54, "double", True, "(n, n) systematic part"),
        ("observable", 55, "bool", True, "per parameter"),
        ("mass_known", 56, "bool", False, "the mass was given, not estimated"),
        ("mass_nominal", 57, "double", False, "bench mass, kg"),
        ("unbalance_point", 58, "double", True, "(3,) m, bench frame"),
        ("frames_rejected", 59, "Count", True, "rejected frames per reason"),
        ("orders_rejected", 60, "Count", True, "rejected orders per reason"),
        ("rpm_range", 61, "double", True, "(lo, hi) rpm of the used frames; empty when none"),
        ("half_order_json", 62, "string", False, "half-order sign resolution, JSON"),
        ("final", 63, "bool", False, "the run's final estimate, written at the end (rpm is NaN)"),
        ("frames_skipped", 64, "uint32", False, "overlapping frames left out (not rejected)"),
        ("crank_axis", 65, "double", True, "(3,) the crank axis the unbalance is located along"),
    ],
}

# fields that the fast twins carry as bytes (same wire format as the packed arrays)
BULK_FIELDS = {"SampleBlock": "data", "EdgeBlock": "times_s"}


def file_descriptor(twin: bool = False) -> descriptor_pb2.FileDescriptorProto:
    """The schema file; ``twin=True`` gives the bytes-for-packed-arrays variant."""
    fd = descriptor_pb2.FileDescriptorProto(name=FILE_NAME, package=PACKAGE, syntax="proto3")
    for msg_name, fields in MESSAGES.items():
        msg = fd.message_type.add(name=msg_name)
        for name, number, kind, repeated, _ in fields:
            field = msg.field.add(name=name, number=number, json_name=_json_name(name))
            bulk = twin and BULK_FIELDS.get(msg_name) == name
            field.label = _F.LABEL_REPEATED if repeated and not bulk else _F.LABEL_OPTIONAL
            if bulk:
                field.type = _F.TYPE_BYTES
            elif kind in _SCALARS:
                field.type = _SCALARS[kind]
            else:
                field.type = _F.TYPE_MESSAGE
                field.type_name = f".{PACKAGE}.{kind}"
    return fd


def _json_name(name: str) -> str:
    head, *rest = name.split("_")
    return head + "".join(p[:1].upper() + p[1:] for p in rest)


@cache
def schema_data() -> bytes:
    """The serialised ``FileDescriptorSet`` stored as every channel's schema."""
    fds = descriptor_pb2.FileDescriptorSet()
    fds.file.append(file_descriptor())
    return fds.SerializeToString()


@cache
def _classes(twin: bool) -> dict[str, Any]:
    pool = DescriptorPool()
    pool.Add(file_descriptor(twin))
    return {
        name: GetMessageClass(pool.FindMessageTypeByName(f"{PACKAGE}.{name}")) for name in MESSAGES
    }


def message_class(name: str) -> Any:
    """The public message class ``name`` (``"OrderFrame"``, ...)."""
    return _classes(False)[name]


def wire_class(name: str) -> Any:
    """The class our writer and reader use: the twin for the bulk messages, else the public one."""
    return _classes(name in BULK_FIELDS)[name]


def full_name(name: str) -> str:
    """Schema name in the recording (``ptinertia.log.SampleBlock``); a name with a package
    (``foxglove.Log``) is already one."""
    return name if "." in name else f"{PACKAGE}.{name}"


def proto_text() -> str:
    """The schema in ``.proto`` syntax, with the field comments (for the docs)."""
    lines = [
        'syntax = "proto3";',
        f"package {PACKAGE};",
        f"// schema version {SCHEMA_VERSION}",
        "",
    ]
    for msg_name, fields in MESSAGES.items():
        lines.append(f"message {msg_name} {{")
        for name, number, kind, repeated, comment in fields:
            label = "repeated " if repeated else ""
            lines.append(f"  {label}{kind} {name} = {number};  // {comment}")
        lines += ["}", ""]
    return "\n".join(lines)


# -- topics ------------------------------------------------------------------------------------

TOPIC_EVENTS = "/events"
TOPIC_ORDERS = "/orders"
TOPIC_GATING = "/gating"
TOPIC_ESTIMATE = "/estimate"
TOPIC_CAN = "/raw/can"
RAW_PREFIX = "/raw/"
EDGE_PREFIX = "/raw/edges/"

# topic (or prefix) -> message type
TOPIC_TYPES = {
    TOPIC_EVENTS: "SourceEvent",
    TOPIC_ORDERS: "OrderFrame",
    TOPIC_GATING: "Gating",
    TOPIC_ESTIMATE: "Estimate",
    TOPIC_CAN: "CanFrames",
    # Foxglove's well-known schemas (:mod:`replay.foxglove`), named in full
    **FOXGLOVE_TOPICS,
}

# metadata record names and the key that marks a ptinertia recording
META_RUN = "ptinertia"
META_END = "ptinertia.end"
FORMAT = "ptinertia-recording"
BENCH_ATTACHMENT = "bench.toml"


def raw_topic(group: str) -> str:
    """Topic of a sample group's blocks."""
    return f"{RAW_PREFIX}{group}"


def edge_topic(channel: str) -> str:
    """Topic of an edge channel's blocks."""
    return f"{EDGE_PREFIX}{channel}"


def stream_topics(layout: StreamLayout) -> dict[str, str]:
    """Topic -> message type of the raw stream of ``layout``: its groups, edge channels, events."""
    topics = {raw_topic(g.name): "SampleBlock" for g in layout.groups}
    topics.update({edge_topic(c): "EdgeBlock" for c in layout.edge_channels})
    topics[TOPIC_EVENTS] = "SourceEvent"
    return topics
