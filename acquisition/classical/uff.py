"""Accelerance FRFs in Universal File Format 58 (read and written with ``pyuff``).

Reading keeps every FRF (function type 4) of the file in SI accelerance,
m/s^2/N, with the ``x(t) = Re{X exp(i w t)}`` convention of modal software:

* units: the axis unit labels of each dataset 58 when given (``g/N``,
  ``m/s^2``, ``lbf``, ...), otherwise the file's dataset 164 (factors "divide
  to get SI"), otherwise SI;
* receptance (displacement, specific data type 8) and mobility (velocity,
  11) become accelerance (``x (i w)^2``, ``x (i w)``);
* node coordinates from datasets 2411 or 15, scaled by dataset 164.

Matching the FRFs to the bench sensors is in :mod:`acquisition.classical.frf_matrix`,
the set-up file that names the nodes in :mod:`acquisition.classical.modal_setup`.

Errors are :class:`~acquisition.stream.SourceError`, one line.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.stream import SourceError

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
    import pyuff  # on use: optional, only the classical methods read UFF

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
    import pyuff  # on use, as in read_uff

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
