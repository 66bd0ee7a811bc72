"""FRFs arranged as a (frequency, channel, excitation) matrix for the bench sensors.

Points and directions. A UFF direction code ``+-1..3`` is a translation
along an axis of the node's displacement frame. For a response node that
frame is the sensor's own (the rows of ``axes`` in the bench file): code k
is the sensor's channel k. For an excitation node it is the bench frame,
unless a set-up file (:mod:`acquisition.classical.modal_setup`) gives the node's axes.
Response nodes are matched to the bench sensors by the set-up file, or else
by position (the node within ``node_tolerance_m`` of the sensor). Excitation
points come from the set-up file, or else from the file's node table.

Its own module because it is the mass-line method's view of the FRFs, not
file I/O. :mod:`acquisition.classical.uff` re-exports it, so this module must not import
``acquisition.classical.uff`` when it loads: the types are imported for annotations
only, and :class:`~acquisition.classical.uff.Frf` where it is built.
Errors are :class:`~acquisition.stream.SourceError`, one line.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from acquisition.classical.modal_setup import ModalSetup
from acquisition.classical.uff import Frf, UffFile
from acquisition.stream import SourceError

#: a node's displacement frame numbers that mean the global (bench) frame
GLOBAL_FRAMES = (0, 1)


@dataclass(frozen=True)
class SensorPoint:
    """A bench sensor: name, position (3,) m, axes (3, 3) rows, channel names (``""`` unused)."""

    name: str
    position: np.ndarray
    axes: np.ndarray
    channels: tuple[str, ...]


@dataclass(frozen=True)
class FrfMatrix:
    """FRFs arranged for the mass-line method.

    Attributes
    ----------
    frequency_hz : (n_f,).
    h : (n_f, n_ch, n_e) complex m/s^2/N.
    channel_names, channel_positions (n_ch, 3), channel_directions (n_ch, 3), channel_sensor (n_ch,).
    excitation_names, excitation_positions (n_e, 3), excitation_directions (n_e, 3).
    response_nodes : sensor name -> UFF node.
    unused : FRFs of the file not used (other response nodes), count.
    """

    frequency_hz: np.ndarray
    h: np.ndarray
    channel_names: tuple[str, ...]
    channel_positions: np.ndarray
    channel_directions: np.ndarray
    channel_sensor: np.ndarray
    excitation_names: tuple[str, ...]
    excitation_positions: np.ndarray
    excitation_directions: np.ndarray
    response_nodes: dict[str, int]
    unused: int


def _response_nodes(
    uff: UffFile, sensors: Sequence[SensorPoint], setup: ModalSetup | None, tol: float
) -> dict[str, int]:
    if setup is not None and setup.responses:
        by_sensor = {r.sensor: r.node for r in setup.responses}
        names = [s.name for s in sensors]
        unknown = sorted(set(by_sensor) - set(names))
        if unknown:
            raise SourceError(
                f"set-up names sensors {unknown} that the bench does not have ({names})"
            )
        missing = [n for n in names if n not in by_sensor]
        if missing:
            raise SourceError(f"set-up gives no response node for bench sensors {missing}")
        return by_sensor
    if not uff.nodes:
        raise SourceError(
            f"{uff.path}: no node coordinates (dataset 2411 or 15) to find the bench sensors in; "
            "give a set-up file with [[responses]]"
        )
    numbers = np.array(sorted(uff.nodes))
    xyz = np.array([uff.nodes[n] for n in numbers])
    out = {}
    for s in sensors:
        dist = np.linalg.norm(xyz - s.position, axis=1)
        k = int(np.argmin(dist))
        if dist[k] > tol:
            raise SourceError(
                f"{uff.path}: bench sensor {s.name} at {np.round(s.position, 4).tolist()} m has no "
                f"node within {1e3 * tol:g} mm (nearest: node {numbers[k]} at "
                f"{1e3 * dist[k]:.0f} mm)"
            )
        out[s.name] = int(numbers[k])
    return out


def frf_matrix(
    uff: UffFile,
    sensors: Sequence[SensorPoint],
    setup: ModalSetup | None = None,
    node_tolerance_m: float = 0.005,
) -> FrfMatrix:
    """Arrange the FRFs of ``uff`` as (frequency, channel, excitation) for the bench sensors.

    Every named channel of every sensor must have a FRF from every excitation
    (an excitation is a reference node and direction found in the file for
    one of the response nodes).

    Raises
    ------
    SourceError
        A sensor without a node, an excitation without a position, a missing
        FRF, FRFs on different frequency axes.
    """
    nodes = _response_nodes(uff, sensors, setup, node_tolerance_m)
    response_set = set(nodes.values())
    used = [f for f in uff.frfs if f.response_node in response_set]
    if not used:
        raise SourceError(
            f"{uff.path}: no FRF has a response at the sensors' nodes {sorted(response_set)} "
            f"(the file has response nodes {sorted({f.response_node for f in uff.frfs})})"
        )
    # Excitations: (node, |direction|) in file order; a negative code is the same hit reversed.
    exc_keys: list[tuple[int, int]] = []
    for f in used:
        key = (f.reference_node, abs(f.reference_dir))
        if key not in exc_keys:
            exc_keys.append(key)
    setup_exc = {e.node: e for e in (setup.excitations if setup else [])}
    names, positions, directions = [], [], []
    for node, code in exc_keys:
        if node in setup_exc:
            e = setup_exc[node]
            pos = np.asarray(e.position_m, dtype=float)
            axis = np.asarray(e.axes, dtype=float)[code - 1]
            label = f"{e.name or f'node{node}'}:{code}"
        elif node in uff.nodes:
            frame = uff.node_frames.get(node, 0)
            if frame not in GLOBAL_FRAMES:
                raise SourceError(
                    f"{uff.path}: excitation node {node} uses displacement frame {frame}; give "
                    "its axes in a set-up file [[excitations]]"
                )
            pos = uff.nodes[node]
            axis = np.eye(3)[code - 1]
            label = f"node{node}:+{'XYZ'[code - 1]}"
        else:
            raise SourceError(
                f"{uff.path}: excitation node {node} has no position: neither a node table "
                "(dataset 2411 or 15) in the file nor an [[excitations]] entry in a set-up file"
            )
        names.append(label)
        positions.append(pos)
        directions.append(axis)
    table = {f.key: f for f in used}
    ch_names, ch_pos, ch_dir, ch_sensor, columns = [], [], [], [], []
    freq = used[0].frequency_hz
    for si, s in enumerate(sensors):
        node = nodes[s.name]
        for k, channel in enumerate(s.channels):
            if not channel:
                continue
            row = []
            for node_e, code in exc_keys:
                frf, sign = None, 1.0
                for rd, rs in ((k + 1, 1.0), (-(k + 1), -1.0)):
                    for ed, es in ((code, 1.0), (-code, -1.0)):
                        if (node, rd, node_e, ed) in table:
                            frf, sign = table[(node, rd, node_e, ed)], rs * es
                if frf is None:
                    raise SourceError(
                        f"{uff.path}: no FRF from excitation node {node_e} direction {code} to "
                        f"sensor {s.name} (node {node}) direction {k + 1} (channel {channel})"
                    )
                if len(frf.frequency_hz) != len(freq) or not np.allclose(
                    frf.frequency_hz, freq, rtol=1e-6, atol=1e-9
                ):
                    raise SourceError(
                        f"{uff.path}: FRF {node}:{frf.response_dir} / {node_e}:{frf.reference_dir} "
                        f"has {len(frf.frequency_hz)} lines {frf.frequency_hz[0]:g} to "
                        f"{frf.frequency_hz[-1]:g} Hz, the first has {len(freq)} lines "
                        f"{freq[0]:g} to {freq[-1]:g} Hz: one frequency axis expected"
                    )
                row.append(sign * frf.accelerance)
            columns.append(np.array(row).T)  # (n_f, n_e)
            ch_names.append(channel)
            ch_pos.append(np.asarray(s.position, dtype=float))
            ch_dir.append(np.asarray(s.axes, dtype=float)[k])
            ch_sensor.append(si)
    h = np.stack(columns, axis=1)
    return FrfMatrix(
        frequency_hz=np.asarray(freq, dtype=float),
        h=h,
        channel_names=tuple(ch_names),
        channel_positions=np.array(ch_pos),
        channel_directions=np.array(ch_dir),
        channel_sensor=np.array(ch_sensor),
        excitation_names=tuple(names),
        excitation_positions=np.array(positions, dtype=float).reshape(-1, 3),
        excitation_directions=np.array(directions, dtype=float).reshape(-1, 3),
        response_nodes=nodes,
        unused=len(uff.frfs) - len(used),
    )


def frfs_from_matrix(
    frequency_hz: np.ndarray,
    h: np.ndarray,
    response_nodes: Sequence[int],
    channel_codes: Sequence[tuple[int, int]],
    excitations: Sequence[tuple[int, int]],
) -> list[Frf]:
    """:class:`Frf` objects from a (n_f, n_ch, n_e) matrix.

    ``channel_codes[c] = (sensor index, direction code)``, ``response_nodes[sensor]``
    its node, ``excitations[e] = (node, direction code)``.
    """

    out = []
    for c, (sensor, rdir) in enumerate(channel_codes):
        for e, (node, edir) in enumerate(excitations):
            out.append(
                Frf(response_nodes[sensor], rdir, node, edir, frequency_hz, h[:, c, e].copy())
            )
    return out
