"""Engine loads on the block: closed forms, free-body diagrams, energy, conventions."""

from __future__ import annotations

import numpy as np
import pytest
from support.engines import (
    DEG,
    GAS,
    PITCH,
    ROD,
    ROD_A,
    STROKE,
    inline3,
    inline4,
)

from powertrain.balancing import BalanceShaft, Unbalance
from powertrain.engine import Engine
from powertrain.errors import PhysicsError
from powertrain.half_orders import rpm_to_omega
from powertrain.slider_crank import kinematics, piston_acceleration_coefficients


def single(**kw) -> Engine:
    args = dict(cylinders=1, throw_angles=[0.0], firing_order=(1,), cylinder_positions=[0.0])
    args.update(kw)
    return inline3(**args)


def w2(rpm: float) -> float:
    return float(rpm_to_omega(rpm)) ** 2


# -- closed forms ---------------------------------------------------------------------------------


def test_single_cylinder_force_is_the_reciprocating_series():
    rpm, orders = 3000.0, np.arange(1, 9)
    e = single()
    sc = e.slider_crank
    f, _ = e.excitation(rpm, orders, about=np.zeros(3))
    r = sc.crank_radius
    a_k = piston_acceleration_coefficients(sc.lam, 8)[1:]
    # c = Z, t = Y x Z = X. Reciprocating along c: -m_rec r w^2 A_k cos(k t); the rod's
    # rotating share adds m_rot r w^2 (cos t c + sin t t) at order 1 (sin t = Re{-i e^(it)}).
    expected_c = -sc.reciprocating_mass * r * w2(rpm) * a_k
    expected_c[0] += sc.rotating_mass * r * w2(rpm)
    np.testing.assert_allclose(f[:, 2], expected_c, atol=1e-9 * abs(expected_c[0]))
    np.testing.assert_allclose(f[1:, 0], 0, atol=1e-9 * abs(expected_c[0]))
    assert f[0, 0] == pytest.approx(-1j * sc.rotating_mass * r * w2(rpm), rel=1e-10)
    # First terms m_rec r w^2 (cos t + lambda cos 2t): order 2 within lambda^2/4.
    assert f[1, 2].real == pytest.approx(
        sc.reciprocating_mass * r * w2(rpm) * sc.lam, rel=sc.lam**2 / 4 * 1.05
    )


@pytest.mark.parametrize("about", [np.zeros(3), np.array([0.2, -0.3, 0.15])])
def test_inline3_free_of_force_with_primary_and_secondary_couples(about):
    # Cog at the small end (a = l): the whole rod reciprocates, nothing rotates,
    # so the textbook couples hold exactly, with the exact series for order 2.
    e = inline3(conrod_cog_from_big_end=ROD)
    sc = e.slider_crank
    assert sc.rotating_mass == 0
    rpm = 4000.0
    f, m = e.excitation(rpm, [1, 2, 3], about=about)
    unit = sc.reciprocating_mass * sc.crank_radius * w2(rpm)
    assert np.abs(f[:2]).max() < 1e-9 * unit  # orders 1 and 2 are balanced
    a2 = -piston_acceleration_coefficients(sc.lam, 2)[2]
    # Forces along c = Z at axial positions along s = Y give moments along Y x Z = X (pitch).
    assert abs(m[0, 0]) == pytest.approx(np.sqrt(3) * unit * PITCH, rel=1e-10)
    assert abs(m[1, 0]) == pytest.approx(np.sqrt(3) * unit * PITCH * a2, rel=1e-10)
    assert abs(m[1, 0]) == pytest.approx(
        np.sqrt(3) * unit * PITCH * sc.lam, rel=sc.lam**2 / 4 * 1.05
    )
    assert np.abs(m[:2, 2]).max() < 1e-9 * unit * PITCH  # no yaw without rotating masses


def test_inline3_rotating_rod_share_adds_a_yaw_couple():
    e = inline3()
    sc = e.slider_crank
    _, m = e.excitation(3000.0, [1], about=np.zeros(3))
    unit = sc.crank_radius * w2(3000.0) * PITCH * np.sqrt(3)
    assert abs(m[0, 0]) == pytest.approx(
        (sc.reciprocating_mass + sc.rotating_mass) * unit, rel=1e-10
    )
    assert abs(m[0, 2]) == pytest.approx(sc.rotating_mass * unit, rel=1e-10)


def test_counterweights_move_primary_couple_into_yaw():
    # Two end counterweights at 150/330 deg with mr = 0.015: they rotate, so they
    # take part of the pitch couple and add the same amount to yaw.
    bare = inline3(conrod_cog_from_big_end=ROD)
    cw = (Unbalance(0.015, 150 * DEG, -0.125), Unbalance(0.015, 330 * DEG, 0.125))
    weighted = inline3(conrod_cog_from_big_end=ROD, unbalances=cw)
    _, m0 = bare.excitation(3000.0, [1], about=np.zeros(3))
    _, m1 = weighted.excitation(3000.0, [1], about=np.zeros(3))
    # Independent: each counterweight is a force mr w^2 e at axial y, moment y s x e.
    y, beta = np.array([-0.125, 0.125]), np.array([150, 330]) * DEG
    # e = cos(phi - b) Z + sin(phi - b) X -> complex amplitudes Z: e^{-ib}, X: -i e^{-ib}
    # moment (y Y) x (e_z Z + e_x X) = y e_z X - y e_x Z
    mx = (0.015 * w2(3000.0) * y * np.exp(-1j * beta)).sum()
    mz = -(0.015 * w2(3000.0) * y * -1j * np.exp(-1j * beta)).sum()
    np.testing.assert_allclose(m1[0] - m0[0], [mx, 0, mz], atol=1e-9 * abs(mx))


def test_inline4_free_second_order_force():
    e = inline4()
    sc = e.slider_crank
    rpm = 4500.0
    f, _ = e.excitation(rpm, [1, 2, 3, 4], about=np.zeros(3))
    unit = sc.reciprocating_mass * sc.crank_radius * w2(rpm)
    a = -piston_acceleration_coefficients(sc.lam, 4)
    assert np.abs(f[[0, 2]]).max() < 1e-9 * unit
    np.testing.assert_allclose(f[1], [0, 0, 4 * unit * a[2]], atol=1e-9 * unit)
    np.testing.assert_allclose(f[3], [0, 0, 4 * unit * a[4]], atol=1e-9 * unit)
    assert f[1, 2].real == pytest.approx(4 * unit * sc.lam, rel=sc.lam**2 / 4 * 1.05)


def test_lanchester_balance_shafts_cancel_the_inline4_second_order_force():
    e = inline4()
    sc = e.slider_crank
    a2 = -piston_acceleration_coefficients(sc.lam, 2)[2]
    # Two shafts at 2 omega, opposite senses, each (2w)^2 mr: the c-components add,
    # the t-components cancel. They must pull along -c at phi = 0 (angle 180 deg).
    mr = sc.reciprocating_mass * sc.crank_radius * a2 / 2
    shafts = tuple(BalanceShaft(2, mr, np.pi, (0.0, 0.0, -0.05), d) for d in (1, -1))
    balanced = inline4(balance_shafts=shafts)
    f, m = balanced.excitation(3000.0, [2], about=np.zeros(3))
    f0, m0 = e.excitation(3000.0, [2], about=np.zeros(3))
    assert np.abs(f).max() < 1e-9 * np.abs(f0).max()
    # Both on the axis line of the cog plane: no moment added.
    np.testing.assert_allclose(m, m0, atol=1e-9 * np.abs(f0).max())


def test_unbalance_points_along_cylinder_axis_at_its_angle():
    e = single(conrod_mass=0.0, piston_mass=0.0, unbalances=(Unbalance(0.01, 40 * DEG, 0.1),))
    f, m = e.block_loads(np.array([40 * DEG]), 3000.0, about=np.zeros(3))
    np.testing.assert_allclose(f[0], [0, 0, 0.01 * w2(3000.0)], rtol=1e-12, atol=1e-9)
    # Force along Z at y = 0.1: moment 0.1 Y x F Z = 0.1 F X.
    np.testing.assert_allclose(m[0], [0.1 * 0.01 * w2(3000.0), 0, 0], rtol=1e-12, atol=1e-9)


# -- free-body diagram and energy -----------------------------------------------------------


def cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """s-component of (a_c c + a_t t) x (b_c c + b_t t), since c x t = s."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def free_body(engine: Engine, phi: float, rpm: float, about: np.ndarray) -> tuple:
    """Block force, moment about ``about`` and crank torque from piston, rod and crank free bodies.

    Piston (point mass at the pin): gas -(p - p_cc) A c, wall side force N t, rod force R_p.
    Rod (mass at its cog, inertia J): -R_p at the small end, R_c at the crank pin.
    Crank (massless, constant speed): -R_c at the pin, bearing B = R_c, load torque.
    Block: gas +(p - p_cc) A c on the head, -N t on the wall, -B on the bearing.
    """
    n = engine.cylinders
    s = np.asarray(engine.crank_axis)
    c0 = np.asarray(engine.cylinder_axis)
    c = np.cos(engine.tilt) * c0 + np.sin(engine.tilt) * np.cross(s, c0)
    t = np.cross(s, c)
    sc = engine.slider_crank
    r, length, a = sc.crank_radius, sc.conrod_length, sc.conrod_cog_from_big_end
    m_p, m_r, j_r = sc.piston_mass, sc.conrod_mass, sc.rod_inertia
    area = np.pi * engine.bore**2 / 4
    omega2 = w2(rpm)
    fire = {cyl: 4 * np.pi * j / n for j, cyl in enumerate(engine.firing_order)}
    force, moment, torque = np.zeros(3), np.zeros(3), 0.0
    for k in range(n):
        centre = np.asarray(engine.reference_point) + engine.cylinder_positions[k] * s
        theta = phi - engine.throw_angles[k]
        kin = kinematics(np.array([theta]), r, length, a)
        pin = np.array([kin.pc[0], kin.pt[0]])
        small = np.array([kin.x[0], 0.0])
        cog = np.array([kin.gc[0], kin.gt[0]])
        acc_p = omega2 * kin.x_tt[0]
        acc_g = omega2 * np.array([kin.gc_tt[0], kin.gt_tt[0]])
        psi_dd = omega2 * kin.psi_tt[0]
        pressure = engine.cylinder_pressure(np.array([phi - fire[k + 1]]))
        gas = 0.0 if pressure is None else (pressure[0] - engine.crankcase_pressure) * area
        # unknowns [N, Rp_c, Rp_t, Rc_c, Rc_t]
        mat = np.zeros((5, 5))
        rhs = np.zeros(5)
        mat[0, 1], rhs[0] = 1.0, m_p * acc_p + gas  # piston along c
        mat[1, [0, 2]], rhs[1] = 1.0, 0.0  # piston along t
        mat[2, [1, 3]], rhs[2] = [-1.0, 1.0], m_r * acc_g[0]  # rod along c
        mat[3, [2, 4]], rhs[3] = [-1.0, 1.0], m_r * acc_g[1]  # rod along t
        arm_p, arm_c = small - cog, pin - cog  # rod rotation about its cog
        mat[4, 1:3] = [arm_p[1], -arm_p[0]]  # cross2(arm_p, -R_p)
        mat[4, 3:5] = [-arm_c[1], arm_c[0]]  # cross2(arm_c, R_c)
        rhs[4] = j_r * psi_dd
        side, _, _, rc_c, rc_t = np.linalg.solve(mat, rhs)
        torque += float(cross2(pin, -np.array([rc_c, rc_t])))
        bearing = rc_c * c + rc_t * t
        head = centre + (kin.x[0] + 0.05) * c
        wall = centre + kin.x[0] * c
        force += gas * c - side * t - bearing
        moment += (
            np.cross(head - about, gas * c)
            + np.cross(wall - about, -side * t)
            + np.cross(centre - about, -bearing)
        )
    return force, moment, torque


@pytest.mark.parametrize(
    "engine",
    [
        single(gas=GAS, tilt=12 * DEG, reference_point=[0.1, -0.2, 0.05], conrod_inertia=0.0011),
        single(gas=GAS, crank_axis=[1, 0, 0], cylinder_axis=[0, 0.6, 0.8], tilt=-20 * DEG),
        inline3(gas=GAS, tilt=12 * DEG, conrod_inertia=0.0015),
        inline4(gas=GAS),
    ],
    ids=["one-tilted-exact-rod", "one-longitudinal", "i3-tilted", "i4"],
)
def test_loads_equal_the_free_body_diagram(engine):
    about = np.array([0.035, -0.085, 0.105])
    rpm = 2700.0
    phis = np.linspace(0, 4 * np.pi, 23, endpoint=False) + 0.1
    f, m = engine.block_loads(phis, rpm, about=about)
    t = engine.crank_torque(phis, rpm)
    for i, phi in enumerate(phis):
        f_fb, m_fb, t_fb = free_body(engine, phi, rpm, about)
        scale = max(np.abs(f_fb).max(), 1.0)
        np.testing.assert_allclose(f[i], f_fb, atol=1e-9 * scale)
        np.testing.assert_allclose(m[i], m_fb, atol=1e-9 * scale)
        assert t[i] == pytest.approx(t_fb, abs=1e-9 * scale)


def test_block_roll_moment_is_minus_crank_torque_for_two_mass_rods():
    # Two-mass rod: the moving masses' angular momentum about the crank axis is
    # constant, so the block's roll moment is exactly -T_crank.
    e = inline3(gas=GAS)
    phis = np.linspace(0, 4 * np.pi, 50)
    _, m = e.block_loads(phis, 3500.0, about=np.zeros(3))
    np.testing.assert_allclose(m[:, 1], -e.crank_torque(phis, 3500.0), atol=1e-9 * np.abs(m).max())


def test_rod_inertia_changes_only_the_roll_moment_by_the_documented_amount():
    j = 0.0011
    two_mass, exact = single(), single(conrod_inertia=j)
    phis = np.linspace(0, 2 * np.pi, 40)
    f0, m0 = two_mass.block_loads(phis, 3000.0, about=np.zeros(3))
    f1, m1 = exact.block_loads(phis, 3000.0, about=np.zeros(3))
    np.testing.assert_allclose(f1, f0, atol=1e-9 * np.abs(f0).max())
    kin = kinematics(phis, STROKE / 2, ROD, ROD_A)
    delta = (
        -(j - two_mass.slider_crank.two_mass_inertia) * w2(3000.0) * kin.psi_tt * (1 - kin.psi_t)
    )
    np.testing.assert_allclose(m1 - m0, np.outer(delta, [0, 1, 0]), atol=1e-9 * np.abs(m0).max())


def test_inertia_torque_is_minus_rate_of_kinetic_energy_of_all_cylinders():
    e = inline3(conrod_inertia=0.002)
    n = 4096
    phis = np.arange(n) * 2 * np.pi / n
    omega = float(rpm_to_omega(3000.0))
    ke = sum(e.slider_crank.kinetic_energy(phis - a, omega) for a in e.throw_angles)
    k = np.fft.rfftfreq(n, 1.0 / n)
    dke_dphi = np.fft.irfft(1j * k * np.fft.rfft(ke), n)
    # T omega = -dKE/dt = -omega dKE/dphi
    np.testing.assert_allclose(
        e.inertia_torque(phis, 3000.0), -dke_dphi, atol=1e-9 * np.abs(dke_dphi).max()
    )


# -- order decomposition ---------------------------------------------------------------------


def test_inertia_torque_orders_are_the_spectrum_of_the_time_signal():
    # the orders come from the loads' pass over the cylinders, the time signal from
    # inertia_torque's own: the same torque, bit for bit on the engine's grid
    e = inline4(conrod_inertia=0.002)
    n = e.samples_per_cycle
    phis = np.arange(n) * 4 * np.pi / n
    torque = e.inertia_torque(phis, omega=1.0)
    assert e._inertia_parts(phis, e.reference_point)[2].tobytes() == torque.tobytes()
    spec = np.fft.rfft(torque) * 2 / n
    w2 = float(rpm_to_omega(2500.0)) ** 2
    np.testing.assert_allclose(
        e.inertia_torque_orders(2500.0, [2, 4, 6]),
        w2 * spec[[4, 8, 12]],
        atol=1e-12 * w2 * np.abs(spec).max(),
    )


def test_orders_rebuild_the_time_signal_and_scale_with_speed():
    e = inline3(tilt=12 * DEG, unbalances=(Unbalance(0.012, 0.3, 0.05),))
    about = np.array([0.03, -0.08, 0.1])
    orders = np.arange(0, 61) / 2
    f, m = e.excitation(2000.0, orders, about=about)
    phis = np.array([0.0, 0.7, 2.9, 8.1])
    f_t, m_t = e.block_loads(phis, 2000.0, about=about)
    basis = np.exp(1j * np.outer(phis, orders))
    np.testing.assert_allclose((basis @ f).real, f_t, atol=1e-9 * np.abs(f_t).max())
    np.testing.assert_allclose((basis @ m).real, m_t, atol=1e-9 * np.abs(m_t).max())
    f2, m2 = e.excitation(4000.0, orders, about=about)
    np.testing.assert_allclose(f2, 4 * f, atol=1e-12 * np.abs(f).max())
    np.testing.assert_allclose(m2, 4 * m, atol=1e-12 * np.abs(m).max())


def test_gas_part_does_not_depend_on_speed():
    e = inline3(gas=GAS)
    a = e.excitation_parts(1500.0, [1.5, 3.0], about=np.zeros(3))["gas"][1]
    b = e.excitation_parts(4500.0, [1.5, 3.0], about=np.zeros(3))["gas"][1]
    np.testing.assert_array_equal(a, b)


def test_moment_about_another_point_matches_a_direct_computation():
    e = inline4(tilt=-7 * DEG)  # has a free order-2 force, so the point matters
    q = np.array([0.3, -0.1, 0.4])
    n = e.samples_per_cycle
    phis = np.arange(n) * 4 * np.pi / n
    _, m_direct = e.inertia_loads(phis, about=q)
    spec = np.fft.rfft(m_direct, axis=0) * 2 / n
    _, m = e.unit_inertia_orders([1, 2, 4], about=q)
    np.testing.assert_allclose(m, spec[[2, 4, 8]], atol=1e-12 * np.abs(m).max())


def test_tilt_rotates_the_inertia_loads_about_the_crank_axis():
    ref = np.array([0.02, 0.0, -0.03])
    upright = inline3(reference_point=ref, unbalances=(Unbalance(0.01, 0.4, 0.1),))
    tilted = inline3(reference_point=ref, unbalances=(Unbalance(0.01, 0.4, 0.1),), tilt=12 * DEG)
    rot = np.array(
        [
            [np.cos(12 * DEG), 0, np.sin(12 * DEG)],
            [0, 1, 0],
            [-np.sin(12 * DEG), 0, np.cos(12 * DEG)],
        ]
    )
    f0, m0 = upright.excitation(3000.0, [1, 2, 3], about=ref)
    f1, m1 = tilted.excitation(3000.0, [1, 2, 3], about=ref)
    np.testing.assert_allclose(f1, f0 @ rot.T, atol=1e-9 * np.abs(f0).max())
    np.testing.assert_allclose(m1, m0 @ rot.T, atol=1e-9 * np.abs(m0).max())


def test_bad_input_raises_physics_error_with_numbers():
    with pytest.raises(PhysicsError, match=r"multiples of 0\.5.*0\.3"):
        inline3().excitation(3000.0, [0.3], about=np.zeros(3))
    with pytest.raises(PhysicsError, match="cylinder 2 fires at 240 deg"):
        inline3(throw_angles=np.array([0, 120, 240]) * DEG)
    with pytest.raises(PhysicsError, match="cylinder 1's throw angle"):
        inline3(throw_angles=np.array([120, 0, 240]) * DEG, firing_order=(2, 3, 1))
    with pytest.raises(PhysicsError, match="perpendicular"):
        inline3(cylinder_axis=[0, 0.6, 0.8])
    with pytest.raises(PhysicsError, match="lambda"):
        inline3(stroke=0.4)
