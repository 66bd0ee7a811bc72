"""The modal test set-up file (TOML): which UFF node is which bench point.

Optional beside a UFF file of FRFs (see ``docs/classical-methods.md``)::

    [[responses]]       node = 1, sensor = "A_engine_mount"
    [[excitations]]     node = 101, name = "front", position_m = [...], axes = [[...], ...]

A response node names the bench sensor it is (its direction code k is the
sensor's channel k); an excitation node gives its position (m) and its frame
(direction code k is row k of ``axes``). Without a set-up file,
:func:`acquisition.classical.frf_matrix.frf_matrix` matches nodes by position.

Its own module because it is TOML validation (pydantic), independent of the
UFF reading and writing in :mod:`acquisition.classical.uff` (which re-exports it).
Errors are :class:`~acquisition.stream.SourceError`, one line.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Field, ValidationError, field_validator

from acquisition.stream import SourceError
from acquisition.tables import TomlTable, format_validation_error

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Matrix3 = Annotated[list[Vec3], Field(min_length=3, max_length=3)]
IDENTITY = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]


class SetupResponse(TomlTable):
    """A response node: which bench sensor it is."""

    node: int
    sensor: str


class SetupExcitation(TomlTable):
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


class ModalSetup(TomlTable):
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
