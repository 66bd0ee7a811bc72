"""The order tracker's frame assembly (dsp.assemble: a step's window amplitudes, leakage
correction, spectrum, frame figures and frame objects) alone, numpy and compiled, in CPU
seconds per minute of stream (issue 24).

The simulated i3 bench (9 accelerometers and the pressure's spectrum at 25.6 kHz, 60 s,
the pipeline benchmark's source) is tracked once per path with every step of the
assembly (:func:`dsp.assemble._batch`, 120 a minute, about 25 frames each) captured; the
captured steps are then run again, best of ``REPEAT``, beside the whole dsp stage (best
of three). Usage: ``python benchmarks/bench_frame_assembly.py`` (``PTINERTIA_NUMBA`` is
set per path here).

Measured (issue 24, tenth wave; 2 cores shared with three other sessions, so only
interleaved runs compare), this script on main at c2bcbc1 and after the wave's commits,
one after the other at load 8.9-9.2: compiled, the frame assembly 29.5 -> 24.8 ms a
minute (246 -> 207 us a step), the dsp stage 0.1009 -> 0.0882 s (594x -> 680x); numpy
70.5 -> 65.9 ms and 0.326 -> 0.310 s. What changed: ``_finish``'s figures, codes and
turn to the crank angle in one compiled call and its frame objects from one dict each;
the window sums and amplitudes, and the ramps and their coupling, one call each; the
window times one call; one parity for a settled batch; no pressure votes once every
chain is decided; fewer fills and masks. Every frame the same bits on both paths.
"""

from __future__ import annotations

import time
from typing import Any

from pipeline_cases import _bench, _load

REPEAT = 9


def _cpu(work: Any) -> float:
    t0 = time.process_time()
    work()
    return time.process_time() - t0


def assembly(compiled: bool, items: list[Any], bench: Any, layout: Any) -> tuple[float, float, int]:
    """CPU seconds of the dsp stage (best of 3) and of its frame assembly's captured steps
    (best of :data:`REPEAT`) for the stream ``items``, and the number of steps."""
    from acquisition.stream import SourceEvent
    from dsp import assemble, kernels
    from ptinertia.runner import processing_chain

    was, kernels.USE = kernels.USE, compiled
    batch = assemble._batch
    calls: list[tuple[Any, ...]] = []

    def capture(*args: Any) -> Any:
        calls.append(args)
        return batch(*args)

    def track(record: bool) -> None:
        tracker, _ = processing_chain(bench, layout)
        assemble._batch = capture if record else batch  # type: ignore[assignment]
        try:
            for item in items:
                if not isinstance(item, SourceEvent):
                    tracker.feed(item)
            tracker.finish()
        finally:
            assemble._batch = batch  # type: ignore[assignment]

    try:
        track(True)  # (the first run loads or compiles the kernels)
        stage = min(_cpu(lambda: track(False)) for _ in range(3))
        steps = min(_cpu(lambda: [batch(*args) for args in calls]) for _ in range(REPEAT))
    finally:
        kernels.USE = was
    return stage, steps, len(calls)


def main() -> None:
    from dsp import kernels

    bench, source, _ = _bench(25600.0, 60.0)
    items = list(source)
    paths = [False] + ([True] if kernels.AVAILABLE else [])
    for compiled in paths:
        stage, steps, n_steps = assembly(compiled, items, bench, source.layout)
        name = "compiled" if compiled else "numpy"
        print(
            f"dsp stage {name}: {stage:.4f} s CPU per minute ({60 / stage:.0f}x); its frame "
            f"assembly {1e3 * steps:.2f} ms ({1e6 * steps / n_steps:.0f} us a step of "
            f"{n_steps}; load {_load()})"
        )


if __name__ == "__main__":
    main()
