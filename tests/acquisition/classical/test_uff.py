"""UFF58 FRFs: our writer, pyuff's own writer, a single-precision file, node mapping."""

from __future__ import annotations

import numpy as np
import pytest
import pyuff

from acquisition.classical.frf_matrix import SensorPoint, frf_matrix, frfs_from_matrix
from acquisition.classical.modal_setup import (
    ModalSetup,
    SetupExcitation,
    SetupResponse,
    dumps_modal_setup,
    load_modal_setup,
)
from acquisition.classical.uff import G0, read_uff, write_uff
from acquisition.stream import SourceError
from powertrain.rigidbody import rotation_matrix

FREQ = np.arange(1.0, 64.0 + 1e-9, 0.5)
SENSORS = (
    SensorPoint("A", np.array([0.05, 0.30, 0.29]), np.eye(3), ("A_x", "A_y", "A_z")),
    SensorPoint(
        "B",
        np.array([0.02, -0.42, 0.25]),
        rotation_matrix([0, 0, 1], np.pi / 2).T,
        ("B_x", "B_y", "B_z"),
    ),
    SensorPoint("C", np.array([-0.26, -0.02, -0.12]), np.eye(3), ("C_x", "", "C_z")),
)
HIT_NODES = {101: np.array([0.05, 0.33, 0.31]), 102: np.array([0.02, -0.45, 0.27])}


def random_frfs(seed: int = 0) -> tuple[np.ndarray, list]:
    """(n_f, 8 channels, 3 hits) random complex data and the matching Frf objects."""
    rng = np.random.default_rng(seed)
    h = rng.normal(size=(len(FREQ), 8, 3)) + 1j * rng.normal(size=(len(FREQ), 8, 3))
    codes = [(0, 1), (0, 2), (0, 3), (1, 1), (1, 2), (1, 3), (2, 1), (2, 3)]
    return h, frfs_from_matrix(FREQ, h, [1, 2, 3], codes, [(101, 1), (101, 3), (102, 2)])


def nodes() -> dict[int, np.ndarray]:
    return {1: SENSORS[0].position, 2: SENSORS[1].position, 3: SENSORS[2].position, **HIT_NODES}


@pytest.mark.parametrize("binary", [False, True], ids=["ascii", "58b"])
def test_write_then_read_is_exact_to_the_format(tmp_path, binary):
    h, frfs = random_frfs()
    path = tmp_path / "frf.uff"
    write_uff(path, frfs, nodes(), binary=binary)
    back = read_uff(path)
    assert [f.key for f in back.frfs] == [f.key for f in frfs]
    got = np.array([f.accelerance for f in back.frfs])
    want = np.array([f.accelerance for f in frfs])
    if binary:
        assert np.array_equal(got, want)  # doubles, bit for bit
    else:
        np.testing.assert_allclose(got, want, rtol=1e-11)  # "%20.11e": 12 significant digits
    assert np.array_equal(back.frfs[0].frequency_hz, FREQ)  # 1.0 and 0.5 are exact in E13.5
    for n, xyz in nodes().items():
        assert np.array_equal(back.nodes[n], xyz)
    # And arranged for the method: channel k of a sensor is its direction code k.
    data = frf_matrix(back, SENSORS)
    assert data.channel_names == ("A_x", "A_y", "A_z", "B_x", "B_y", "B_z", "C_x", "C_z")
    np.testing.assert_allclose(data.h, h, rtol=1e-11)
    np.testing.assert_allclose(data.channel_directions[3], SENSORS[1].axes[0])
    np.testing.assert_allclose(data.excitation_directions, [[1, 0, 0], [0, 0, 1], [0, 1, 0]])
    np.testing.assert_allclose(data.excitation_positions[2], HIT_NODES[102])


def pyuff_58(data: np.ndarray, **fields) -> dict:
    args = dict(
        binary=0, func_type=4, rsp_node=1, rsp_dir=1, ref_node=101, ref_dir=1,
        data=data, x=FREQ, id1="another tool", rsp_ent_name="NONE", ref_ent_name="NONE",
        abscissa_spacing=1, abscissa_spec_data_type=18, ordinate_spec_data_type=12,
        orddenom_spec_data_type=13,
    )  # fmt: skip
    args.update(fields)
    return pyuff.prepare_58(**args)


@pytest.mark.parametrize(
    ("fields", "expected"),
    [
        ({}, lambda d: d),
        ({"binary": 1}, lambda d: d),
        ({"abscissa_spacing": 0}, lambda d: d),
        ({"ordinate_axis_units_lab": "g/N"}, lambda d: G0 * d),
        (
            {"ordinate_axis_units_lab": "m/s^2", "orddenom_axis_units_lab": "lbf"},
            lambda d: d / 4.4482216152605,
        ),
        (
            {"ordinate_spec_data_type": 8, "ordinate_axis_units_lab": "mm/N"},
            lambda d: 1e-3 * d * (2j * np.pi * FREQ) ** 2,
        ),
        ({"ordinate_spec_data_type": 11}, lambda d: d * 2j * np.pi * FREQ),
    ],
    ids=["ascii", "58b", "uneven", "g-per-N", "per-lbf", "receptance-mm", "mobility"],
)
def test_pyuffs_own_writer_reads_back_exactly(tmp_path, fields, expected):
    rng = np.random.default_rng(1)
    data = rng.normal(size=len(FREQ)) + 1j * rng.normal(size=len(FREQ))
    path = tmp_path / "other.uff"
    # A fresh file in "add" mode: pyuff's "overwrite" truncates a first binary 58's header.
    pyuff.UFF(str(path)).write_sets([pyuff_58(data, **fields)], mode="add")
    (frf,) = read_uff(path).frfs
    assert (frf.response_node, frf.response_dir, frf.reference_node, frf.reference_dir) == (
        1,
        1,
        101,
        1,
    )
    if fields.get("binary"):
        assert np.array_equal(frf.accelerance, expected(data))
    else:
        np.testing.assert_allclose(frf.accelerance, expected(data), rtol=1e-11)
    np.testing.assert_allclose(frf.frequency_hz, FREQ, rtol=1e-6)


def test_units_dataset_scales_nodes_and_unlabelled_frfs(tmp_path):
    """A file in mm and mN (dataset 164, factors 1000 and 1000): divide by the factor for SI."""
    path = tmp_path / "mm.uff"
    data = np.linspace(1, 2, len(FREQ)) * (1 + 0.5j)
    units = pyuff.prepare_164(
        units_code=5,
        units_description="mm (milli newton)",
        temp_mode=1,
        length=1000.0,
        force=1000.0,
        temp=1.0,
        temp_offset=273.15,
    )
    node_set = pyuff.prepare_2411(
        node_nums=np.array([1, 101]),
        def_cs=np.zeros(2, int),
        disp_cs=np.zeros(2, int),
        color=np.ones(2, int),
        x=np.array([50.0, 20.0]),
        y=np.array([300.0, -450.0]),
        z=np.array([290.0, 270.0]),
    )
    pyuff.UFF(str(path)).write_sets([units, node_set, pyuff_58(data)], mode="add")
    back = read_uff(path)
    np.testing.assert_allclose(back.nodes[1], [0.05, 0.30, 0.29], rtol=1e-15)
    np.testing.assert_allclose(back.nodes[101], [0.02, -0.45, 0.27], rtol=1e-15)
    # (mm/s^2) / mN: acceleration / 1000, force / 1000: the ratio is unchanged.
    np.testing.assert_allclose(back.frfs[0].accelerance, data, rtol=1e-11)


def test_a_single_precision_file_written_field_by_field(tmp_path):
    """Complex single precision (ordinate type 5, 6E13.5) in g/N, as older modal software writes."""
    values = [0.125 + 0.5j, -1.5e-3 + 2.0e-4j, 3.25 - 0.0625j, 7.5e2 + 0j]
    lines = [
        "    -1",
        "    58",
        "FRF from a 1998 analyser".ljust(80),
        "NONE".ljust(80),
        "12-MAR-98 10:41:07".ljust(80),
        "NONE".ljust(80),
        "NONE".ljust(80),
        f"{4:5d}{1:10d}{1:5d}{0:10d} {'NONE':10s}{7:10d}{-3:4d} {'NONE':10s}{201:10d}{2:4d}",
        f"{5:10d}{len(values):10d}{1:10d}{2.0:13.5E}{0.5:13.5E}{0.0:13.5E}",
        f"{18:10d}{0:5d}{0:5d}{0:5d} {'Frequency':20s} {'Hz':20s}",
        f"{12:10d}{0:5d}{0:5d}{0:5d} {'Acceleration':20s} {'g':20s}",
        f"{13:10d}{0:5d}{0:5d}{0:5d} {'Force':20s} {'N':20s}",
        f"{0:10d}{0:5d}{0:5d}{0:5d} {'NONE':20s} {'NONE':20s}",
    ]
    flat = [x for v in values for x in (v.real, v.imag)]
    for k in range(0, len(flat), 6):
        lines.append("".join(f"{x:13.5E}" for x in flat[k : k + 6]))
    lines.append("    -1")
    path = tmp_path / "old.unv"
    path.write_text("\n".join(lines) + "\n")
    (frf,) = read_uff(path).frfs
    assert (frf.response_node, frf.response_dir, frf.reference_node, frf.reference_dir) == (
        7,
        -3,
        201,
        2,
    )
    np.testing.assert_allclose(frf.frequency_hz, [2.0, 2.5, 3.0, 3.5])
    np.testing.assert_allclose(frf.accelerance, G0 * np.array(values), rtol=1e-15)


def test_missing_points_are_named(tmp_path):
    _, frfs = random_frfs()
    path = tmp_path / "frf.uff"
    write_uff(
        path,
        [
            f
            for f in frfs
            if not (f.response_node == 3 and f.response_dir == 3 and f.reference_node == 102)
        ],
        nodes(),
    )
    with pytest.raises(
        SourceError,
        match=r"no FRF from excitation node 102 direction 2 to sensor C \(node 3\) direction 3 \(channel C_z\)",
    ):
        frf_matrix(read_uff(path), SENSORS)
    write_uff(path, frfs, {n: x for n, x in nodes().items() if n != 102})
    with pytest.raises(SourceError, match="excitation node 102 has no position"):
        frf_matrix(read_uff(path), SENSORS)
    moved = (
        SensorPoint(
            "A", SENSORS[0].position + np.array([0, 0, 0.02]), np.eye(3), SENSORS[0].channels
        ),
        *SENSORS[1:],
    )
    write_uff(path, frfs, nodes())
    with pytest.raises(
        SourceError,
        match=r"bench sensor A at \[0.05, 0.3, 0.31\] m has no node within 5 mm \(nearest: node 1 at 20 mm\)",
    ):
        frf_matrix(read_uff(path), moved)
    write_uff(path, frfs)
    with pytest.raises(SourceError, match="no node coordinates"):
        frf_matrix(read_uff(path), SENSORS)
    with pytest.raises(SourceError, match="no such UFF file"):
        read_uff(tmp_path / "nothing.uff")


def test_setup_file_maps_nodes_and_turns_hits(tmp_path):
    h, frfs = random_frfs()
    path = tmp_path / "frf.uff"
    write_uff(path, frfs)  # no node table: everything from the set-up file
    skew = rotation_matrix([1, 1, 0], 0.3)
    setup = ModalSetup(
        responses=[
            SetupResponse(node=n, sensor=s.name) for n, s in zip((1, 2, 3), SENSORS, strict=True)
        ],
        excitations=[
            SetupExcitation(
                node=101, name="front", position_m=HIT_NODES[101].tolist(), axes=skew.T.tolist()
            ),
            SetupExcitation(node=102, name="rear", position_m=HIT_NODES[102].tolist()),
        ],
    )
    setup_path = tmp_path / "setup.toml"
    setup_path.write_text(dumps_modal_setup(setup, "test set-up"))
    assert load_modal_setup(setup_path) == setup
    data = frf_matrix(read_uff(path), SENSORS, load_modal_setup(setup_path))
    np.testing.assert_allclose(data.h, h, rtol=1e-11)
    np.testing.assert_allclose(data.excitation_directions[0], skew[:, 0], atol=1e-15)
    np.testing.assert_allclose(data.excitation_directions[1], skew[:, 2], atol=1e-15)
    assert data.excitation_names == ("front:1", "front:3", "rear:2")
    bad = setup.model_copy(
        update={"responses": [*setup.responses[:2], SetupResponse(node=3, sensor="D")]}
    )
    with pytest.raises(SourceError, match=r"sensors \['D'\] that the bench does not have"):
        frf_matrix(read_uff(path), SENSORS, bad)


def test_a_reversed_response_direction_is_the_same_channel_negated(tmp_path):
    h, frfs = random_frfs()
    flipped = [
        type(f)(
            f.response_node,
            -f.response_dir,
            f.reference_node,
            f.reference_dir,
            f.frequency_hz,
            -f.accelerance,
        )
        if f.response_node == 2
        else f
        for f in frfs
    ]
    path = tmp_path / "frf.uff"
    write_uff(path, flipped, nodes())
    np.testing.assert_allclose(frf_matrix(read_uff(path), SENSORS).h, h, rtol=1e-11)
