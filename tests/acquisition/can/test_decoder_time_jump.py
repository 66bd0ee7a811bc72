"""A receive time far ahead (a corrupt log timestamp) costs neither time nor memory.

With a 16-bit counter the decoder unwraps against the receive time, so one frame dated
1e11 s late lands 5.7e13 frames ahead: the frames between are counted lost at once and
never allocated (they used to be counted one by one: a hang, then 32 PiB of NaNs).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.can_streams import sim_frames

from acquisition.can.decoder import decode_frames
from acquisition.stream import SampleBlock
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.to_can import can_plan

JUMP_NS = int(1e11 * 1e9)


@pytest.fixture(scope="module")
def plan16(i3, tmp_path_factory):
    text = (EXAMPLES_DIR / "bench.dbc").read_text()
    short = text.replace(
        "SG_ SEQ : 0|32@1+ (1,0) [0|4294967295]", "SG_ SEQ : 0|16@1+ (1,0) [0|65535]"
    )
    assert short != text
    path = Path(tmp_path_factory.mktemp("dbc")) / "short-counter.dbc"
    path.write_text(short)
    return can_plan(i3, path)


@pytest.mark.parametrize("how", ["one frame", "every later frame"])
def test_a_receive_time_far_ahead_is_decoded_without_a_hang(i3, plan16, how):
    frames, _ = sim_frames(i3, plan16, duration_s=0.5)
    status = max(m.frame_id for m in plan16.messages if m.kind == "status")
    frames = [f for f in frames if f.arbitration_id != status]  # no end marker: a cut log
    reference = list(frames)
    k = len(frames) // 2
    if how == "one frame":
        frames[k] = frames[k]._replace(timestamp_ns=frames[k].timestamp_ns + JUMP_NS)
    else:
        frames[k:] = [f._replace(timestamp_ns=f.timestamp_ns + JUMP_NS) for f in frames[k:]]
    items, stats = decode_frames(plan16, frames)
    blocks = [b for b in items if isinstance(b, SampleBlock)]
    assert blocks, "nothing decoded"
    # no block is longer than the recording: no span between the frames was allocated
    rate = max(m.rate_hz for m in plan16.messages if m.kind == "samples")
    assert max(b.n_samples for b in blocks) <= 0.5 * rate + 64
    # every sample sent is given out, before or after the jump (one frame may be dropped)
    # every sample of the clean decode is given out, before or after the jump (the lone
    # late frame may be dropped)
    first = next(m for m in plan16.messages if m.kind == "samples" and m.group == "accel")

    def count(items):
        row = first.rows[0]
        return sum(
            int(np.isfinite(b.data[row]).sum())
            for b in items
            if isinstance(b, SampleBlock) and b.group == "accel"
        )

    clean, _ = decode_frames(plan16, reference)
    assert count(clean) - count(items) in (0, first.samples_per_frame)
    lost = sum(s.lost for s in stats.streams.values())
    if how == "one frame":
        # the lone frame waits for a second opinion that never comes: it alone is dropped
        assert lost <= 1
    else:
        # two frames agree on the new counter: a resynchronisation, the jump counted lost
        assert lost > 1e12
