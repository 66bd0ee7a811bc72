"""One random sequence of MCAP writer calls, driven through any writer with mcap's interface."""

from __future__ import annotations

import random
from typing import Any


def drive(writer: Any, seed: int) -> None:
    """One sequence of calls: metadata and attachments, messages of random sizes and times,
    explicit flushes, metadata in the middle and at the end."""
    rng = random.Random(seed)
    writer.start(profile="", library="ptinertia test")
    writer.add_metadata("run", {"a": "1", "b": "two"})
    writer.add_attachment(5, 6, "bench.toml", "application/toml", b"[bench]\n")
    s1 = writer.register_schema("S1", "protobuf", b"descriptor")
    s2 = writer.register_schema("S2", "jsonschema", b"{}")
    channels = [
        writer.register_channel(f"/t{i}", "protobuf", s1 if i % 2 else s2) for i in range(4)
    ]
    for k in range(2000):
        t = 10**18 + rng.randrange(10**9)  # not in order: chunk and file bounds are min and max
        size = rng.choice([0, 5, 100, 3000])
        writer.add_message(rng.choice(channels), t, rng.randbytes(size), t + 7, rng.randrange(3))
        if rng.random() < 0.01:
            writer.flush()
        if k == 1000:
            writer.add_metadata("mid", {"k": "v"})
    writer.add_metadata("end", {"status": "finished"})
    writer.finish()
