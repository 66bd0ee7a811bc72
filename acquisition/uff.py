"""Accelerance FRFs in Universal File Format 58 (read and written with ``pyuff``).

Reading keeps every FRF (function type 4) of the file in SI accelerance,
m/s^2/N, with the ``x(t) = Re{X exp(i w t)}`` convention of modal software:

* units: the axis unit labels of each dataset 58 when given (``g/N``,
  ``m/s^2``, ``lbf``, ...), otherwise the file's dataset 164 (factors "divide
  to get SI"), otherwise SI;
* receptance (displacement, specific data type 8) and mobility (velocity,
  11) become accelerance (``x (i w)^2``, ``x (i w)``);
* node coordinates from datasets 2411 or 15, scaled by dataset 164.

Points and directions. A UFF direction code ``+-1..3`` is a translation
along an axis of the node's displacement frame. For a response node that
frame is the sensor's own (the rows of ``axes`` in the bench file): code k
is the sensor's channel k. For an excitation node it is the bench frame,
unless a set-up file gives the node's axes. Response nodes are matched to the
bench sensors by the set-up file, or else by position (the node within
``node_tolerance_m`` of the sensor). Excitation points come from the set-up
file, or else from the file's node table.

Set-up file (TOML, optional; see ``docs/classical-methods.md``)::

    [[responses]]       node = 1, sensor = "A_engine_mount"
    [[excitations]]     node = 101, name = "front", position_m = [...], axes = [[...], ...]

Errors are :class:`~acquisition.stream.SourceError`, one line.
"""

from __future__ import annotations

import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import Field, ValidationError, field_validator

from acquisition.pendulum_file import TomlSection
from acquisition.stream import SourceError
from ptinertia.validation import format_validation_error

G0 = 9.80665
LBF = 4.4482216152605
#: numerator unit labels per specific data type (8 displacement, 11 velocity, 12 acceleration)
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "in": 0.0254, "ft": 0.3048}
ACCEL_UNITS = {
    "g": G0,
    "gn": G0,
    **{f"{u}/s^2": f for u, f in LENGTH_UNITS.items()},
    **{f"{u}/s2": f for u, f in LENGTH_UNITS.items()},
    **{f"{u}/s**2": f for u, f in LENGTH_UNITS.items()},
    **{f"{u}/s²": f for u, f in LENGTH_UNITS.items()},
}
VELOCITY_UNITS = {f"{u}/s": f for u, f in LENGTH_UNITS.items()}
FORCE_UNITS = {"n": 1.0, "kn": 1e3, "lbf": LBF, "lb": LBF}
QUANTITY = {8: "displacement", 11: "velocity", 12: "acceleration"}
UNITS = {8: LENGTH_UNITS, 11: VELOCITY_UNITS, 12: ACCEL_UNITS}
#: a node's displacement frame numbers that mean the global (bench) frame
GLOBAL_FRAMES = (0, 1)


@dataclass(frozen=True)
class Frf:
    """One FRF in SI accelerance.

    Attributes
    ----------
    response_node, response_dir : node and direction code (+-1..3).
    reference_node, reference_dir : the excitation node and direction code.
    frequency_hz : (n,) Hz.
    accelerance : (n,) complex m/s^2/N.
    """

    response_node: int
    response_dir: int
    reference_node: int
    reference_dir: int
    frequency_hz: np.ndarray = field(repr=False)
    accelerance: np.ndarray = field(repr=False)

    @property
    def key(self) -> tuple[int, int, int, int]:
        return (self.response_node, self.response_dir, self.reference_node, self.reference_dir)


@dataclass(frozen=True)
class UffFile:
    """What :func:`read_uff` found: FRFs, node coordinates (m), datasets skipped by type."""

    path: str
    frfs: tuple[Frf, ...]
    nodes: dict[int, np.ndarray]
    node_frames: dict[int, int]
    skipped: dict[str, int]


def _label(dset: dict[str, Any], key: str) -> str:
    text = str(dset.get(key, "") or "").strip()
    return "" if text.upper() == "NONE" else text


def _units_of(text: str, table: dict[str, float], what: str, where: str) -> float:
    key = text.strip().strip("()").replace(" ", "").lower()
    for k, v in table.items():
        if key == k.lower():
            return v
    raise SourceError(f"{where}: unknown {what} unit {text!r} (known: {', '.join(sorted(table))})")


def _conversion(
    dset: dict[str, Any], units164: tuple[float, float] | None, where: str
) -> tuple[int, float]:
    """(numerator specific data type, factor to SI of the FRF ratio)."""
    spec = int(dset.get("ordinate_spec_data_type", 0) or 0)
    num = _label(dset, "ordinate_axis_units_lab")
    den = _label(dset, "orddenom_axis_units_lab")
    if num and not den and "/" in num:
        # "g/N", "m/s^2/N", "(m/s^2)/N": the force is after the last slash.
        head, _, tail = num.rpartition("/")
        if tail.strip().strip("()").lower() in FORCE_UNITS:
            num, den = head, tail
    if spec == 0 and num:
        for code, table in UNITS.items():
            if num.strip().strip("()").replace(" ", "").lower() in {k.lower() for k in table}:
                spec = code
                break
    if spec == 0:
        spec = 12
    if spec not in UNITS:
        raise SourceError(
            f"{where}: ordinate specific data type {spec} is not a motion (expected 8 "
            "displacement, 11 velocity or 12 acceleration over force)"
        )
    denom_spec = int(dset.get("orddenom_spec_data_type", 13) or 13)
    if denom_spec not in (0, 9, 13):
        raise SourceError(
            f"{where}: ordinate denominator specific data type {denom_spec} is not a force "
            "(expected 13 excitation force)"
        )
    if num or den:
        factor = _units_of(num, UNITS[spec], QUANTITY[spec], where) if num else 1.0
        factor /= _units_of(den, FORCE_UNITS, "force", where) if den else 1.0
    elif units164 is not None:
        length, force = units164  # file value / factor = SI
        factor = force / length
    else:
        factor = 1.0
    return spec, factor


def read_uff(path: str | Path) -> UffFile:
    """Read every FRF and node of a UFF file (ASCII or binary 58b).

    Raises
    ------
    SourceError
        Unreadable file, a FRF with unknown units or a rotation direction,
        two FRFs for the same response and reference.
    """
    import pyuff

    path = Path(path)
    if not path.is_file():
        raise SourceError(f"{path}: no such UFF file")
    try:
        uff = pyuff.UFF(str(path))
        types = [int(t) for t in uff.get_set_types()]
        sets = uff.read_sets() if types else []
    except Exception as err:  # pyuff raises bare Exception for every format problem
        raise SourceError(f"{path}: not a readable universal file ({err})") from None
    if isinstance(sets, dict):
        sets = [sets]
    units164 = None
    for dset in sets:
        if int(dset.get("type", 0)) == 164:
            units164 = (float(dset["length"]), float(dset["force"]))
    nodes: dict[int, np.ndarray] = {}
    frames: dict[int, int] = {}
    length = units164[0] if units164 else 1.0
    skipped: dict[str, int] = {}
    frfs: list[Frf] = []
    seen: dict[tuple[int, int, int, int], int] = {}
    for index, dset in enumerate(sets):
        kind = int(dset.get("type", 0))
        if kind in (15, 2411):
            for n, cs, x, y, z in zip(
                dset["node_nums"], dset["disp_cs"], dset["x"], dset["y"], dset["z"], strict=True
            ):
                nodes[int(n)] = np.array([x, y, z], dtype=float) / length
                frames[int(n)] = int(cs)
            continue
        if kind != 58 or int(dset.get("func_type", -1)) != 4:
            name = f"type {kind}" if kind != 58 else f"58 function type {dset.get('func_type')}"
            skipped[name] = skipped.get(name, 0) + 1
            continue
        where = (
            f"{path}: dataset {index + 1} (response {dset['rsp_node']}:{dset['rsp_dir']}, "
            f"reference {dset['ref_node']}:{dset['ref_dir']})"
        )
        for key in ("rsp_dir", "ref_dir"):
            if abs(int(dset[key])) not in (1, 2, 3):
                raise SourceError(
                    f"{where}: direction {dset[key]} is not a translation (+-1, 2, 3)"
                )
        spec, factor = _conversion(dset, units164, where)
        freq = np.asarray(dset["x"], dtype=float)
        data: np.ndarray = np.asarray(dset["data"]).astype(complex) * factor
        iw = 2j * np.pi * freq
        if spec == 8:
            data = data * iw**2
        elif spec == 11:
            data = data * iw
        frf = Frf(
            int(dset["rsp_node"]),
            int(dset["rsp_dir"]),
            int(dset["ref_node"]),
            int(dset["ref_dir"]),
            freq,
            data,
        )
        if frf.key in seen:
            raise SourceError(
                f"{where}: a second FRF for the same response and reference (first: dataset "
                f"{seen[frf.key] + 1})"
            )
        seen[frf.key] = index
        frfs.append(frf)
    return UffFile(str(path), tuple(frfs), nodes, frames, skipped)


def write_uff(
    path: str | Path,
    frfs: Sequence[Frf],
    nodes: dict[int, np.ndarray] | None = None,
    description: str = "ptinertia",
    binary: bool = False,
) -> None:
    """Write SI accelerance FRFs (and optionally node coordinates, m) to a new UFF file.

    Units dataset 164 (SI), nodes as 2411, each FRF as a dataset 58 (58b if
    ``binary``): complex double, even abscissa in Hz, ordinate acceleration
    ``m/s^2`` over excitation force ``N``.
    """
    import pyuff

    path = Path(path)
    if path.exists():
        path.unlink()
    sets: list[dict[str, Any]] = [
        pyuff.prepare_164(
            units_code=1,
            units_description="SI - mks (Newton)",
            temp_mode=2,
            length=1.0,
            force=1.0,
            temp=1.0,
            temp_offset=273.15,
        )
    ]
    if nodes:
        numbers = sorted(nodes)
        xyz = np.array([nodes[n] for n in numbers], dtype=float)
        sets.append(
            pyuff.prepare_2411(
                node_nums=np.array(numbers, dtype=int),
                def_cs=np.zeros(len(numbers), dtype=int),
                disp_cs=np.zeros(len(numbers), dtype=int),
                color=np.full(len(numbers), 8, dtype=int),
                x=xyz[:, 0],
                y=xyz[:, 1],
                z=xyz[:, 2],
            )
        )
    for frf in frfs:
        f = np.asarray(frf.frequency_hz, dtype=float)
        df = np.diff(f)
        even = len(f) > 1 and bool(np.allclose(df, df[0], rtol=1e-9, atol=0))
        sets.append(
            pyuff.prepare_58(
                binary=1 if binary else 0,
                id1=description[:80] or "NONE",
                id2=f"accelerance {frf.response_node}:{frf.response_dir} / "
                f"{frf.reference_node}:{frf.reference_dir}",
                id3="NONE",
                id4="NONE",
                id5="NONE",
                func_type=4,
                ver_num=0,
                load_case_id=0,
                rsp_ent_name="NONE",
                rsp_node=int(frf.response_node),
                rsp_dir=int(frf.response_dir),
                ref_ent_name="NONE",
                ref_node=int(frf.reference_node),
                ref_dir=int(frf.reference_dir),
                abscissa_spacing=1 if even else 0,
                abscissa_spec_data_type=18,
                abscissa_axis_units_lab="Hz",
                ordinate_spec_data_type=12,
                ordinate_axis_units_lab="m/s^2",
                orddenom_spec_data_type=13,
                orddenom_axis_units_lab="N",
                z_axis_spec_data_type=0,
                data=np.asarray(frf.accelerance, dtype=complex),
                x=f,
            )
        )
    try:
        # "add" to a fresh file: pyuff's "overwrite" reopens the file after a binary 58's
        # header and truncates it.
        pyuff.UFF(str(path)).write_sets(sets, mode="add")
    except Exception as err:  # pyuff raises bare Exception
        raise SourceError(f"{path}: cannot write universal file ({err})") from None


# -- set-up file ------------------------------------------------------------------------------------

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Matrix3 = Annotated[list[Vec3], Field(min_length=3, max_length=3)]
IDENTITY = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]


class SetupResponse(TomlSection):
    """A response node: which bench sensor it is."""

    node: int
    sensor: str


class SetupExcitation(TomlSection):
    """An excitation node: where it is and its frame (direction code k = row k of ``axes``)."""

    node: int
    name: str = ""
    position_m: Vec3
    axes: Matrix3 = Field(default_factory=lambda: [r[:] for r in IDENTITY])

    @field_validator("axes")
    @classmethod
    def _axes(cls, v: list[list[float]]) -> list[list[float]]:
        a = np.asarray(v, dtype=float)
        err = float(np.abs(a @ a.T - np.eye(3)).max())
        if err > 1e-3:
            raise ValueError(
                f"axes rows must be orthonormal unit vectors (|A A^T - 1| = {err:.3g})"
            )
        return v


class ModalSetup(TomlSection):
    """Which UFF node is which point (see module docstring)."""

    responses: list[SetupResponse] = Field(default_factory=list)
    excitations: list[SetupExcitation] = Field(default_factory=list)


def load_modal_setup(path: str | Path) -> ModalSetup:
    """Read and validate a set-up TOML file."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as err:
        raise SourceError(f"{path}: cannot read set-up file ({err.strerror})") from None
    except tomllib.TOMLDecodeError as err:
        raise SourceError(f"{path}: not valid TOML ({err})") from None
    try:
        return ModalSetup.model_validate(data)
    except ValidationError as err:
        raise SourceError(format_validation_error(err, str(path))) from None


def dumps_modal_setup(setup: ModalSetup, header: str = "") -> str:
    """TOML text of a set-up (reads back with :func:`load_modal_setup`)."""
    out = [f"# {line}" for line in header.splitlines()]
    for r in setup.responses:
        out += ["", "[[responses]]", f"node = {r.node}", f'sensor = "{r.sensor}"']
    for e in setup.excitations:
        out += ["", "[[excitations]]", f"node = {e.node}", f'name = "{e.name}"']
        out.append(f"position_m = [{', '.join(repr(float(v)) for v in e.position_m)}]")
        rows = ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in e.axes)
        out.append(f"axes = [{rows}]")
    return "\n".join(out) + "\n"


# -- FRF matrix --------------------------------------------------------------------------------------


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
