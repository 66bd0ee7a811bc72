"""CAN frames <-> channel samples: one import point for the DBC plan and the frame codecs.

The codec is split along its seams; this module re-exports their public names so that
``from acquisition.can.codec import X`` keeps working for every caller:

* :mod:`acquisition.can.frames`: :class:`RawFrame` and the raw-frame log record.
* :mod:`acquisition.can.plan`: :class:`CanPlan`, :class:`MessagePlan` and their fields.
* :mod:`acquisition.can.dbc`: the DBC conventions, DBC + bench -> :class:`CanPlan`.
* :mod:`acquisition.can.fields`: batch decoding of integer fields, CRCs, scaling.
* :mod:`acquisition.can.encoder`: the simulated DAQ, stream items -> frames.
* :mod:`acquisition.can.bus_load`: frame times on the bus and a plan's bus load.
"""

from __future__ import annotations

from acquisition.can.bus_load import bus_load, frame_time_s
from acquisition.can.dbc import bench_groups, load_dbc, load_plan, plan_for_bench
from acquisition.can.encoder import (
    FrameEncoder,
    TxFrame,
    encode_edge_frames,
    encode_sample_frames,
    encode_status_frame,
)
from acquisition.can.fields import (
    CRC_INIT,
    as_rows,
    frame_crc,
    raw_fields_slow,
    read_fields,
    scale_samples,
)
from acquisition.can.frames import RawFrame, pack_frames, unpack_frames
from acquisition.can.plan import (
    STATE_RUNNING,
    STATE_STOPPED,
    CanPlan,
    ChannelScaling,
    IntField,
    MessagePlan,
)

__all__ = [
    "CRC_INIT",
    "STATE_RUNNING",
    "STATE_STOPPED",
    "CanPlan",
    "ChannelScaling",
    "FrameEncoder",
    "IntField",
    "MessagePlan",
    "RawFrame",
    "TxFrame",
    "as_rows",
    "bench_groups",
    "bus_load",
    "encode_edge_frames",
    "encode_sample_frames",
    "encode_status_frame",
    "frame_crc",
    "frame_time_s",
    "load_dbc",
    "load_plan",
    "pack_frames",
    "plan_for_bench",
    "raw_fields_slow",
    "read_fields",
    "scale_samples",
    "unpack_frames",
]
