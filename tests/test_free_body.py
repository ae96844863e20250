"""The exact free rigid body (`rbstudy.numerics.free_flow`, `rbstudy.numerics.elliptic`):
against mpmath at 40 digits, scipy's DOP853 on rotation matrices, Euler's equations by finite
differences, the symmetric closed form, and its own group property."""

import math

import mpmath as mp
import numpy as np
import pytest
from free_body_mp import angle_between, exact_state
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from rbstudy.numerics import elliptic
from rbstudy.numerics.free_flow import free_flow, free_flow_batch
from rbstudy.physics.analytic import flip_interval_exact, symmetric_top
from rbstudy.physics.metrics import orientation_error
from rbstudy.physics.references import reference_solution
from rbstudy.physics.scenes import Body, Scene

RNG = np.random.default_rng(12)

# name: principal inertias, rotation vector of the initial orientation, body angular velocity
BODIES = {
    "largest axis": ((0.345, 0.653, 1.0), (0.3, -0.2, 0.5), (0.6, 1.5, 0.9)),
    "smallest axis": ((1.0, 2.0, 3.0), (0.1, 0.2, 0.3), (2.0, 0.3, 0.1)),
    "axes unsorted (odd order)": ((3.0, 1.0, 2.0), (0.4, -0.1, 0.2), (0.2, 0.9, -1.1)),
    "axes unsorted (even order)": ((2.0, 3.0, 1.0), (0.4, -0.1, 0.2), (-0.7, 0.3, 1.1)),
    "negative spin": ((1.0, 2.0, 3.0), (0.0, 0.0, 0.0), (-0.3, 0.4, -1.0)),
    # k'^2 = 1e-6 (k^2 = 0.999999): G^2 - 2 E I2 = 3 w3^2 - w1^2 is 1e-6 of G^2 - 2 E I1
    "near the separatrix": (
        (1.0, 2.0, 3.0),
        (0.2, 0.1, -0.3),
        (0.8, 0.3, 0.8 / math.sqrt(3.0) * (1.0 + 5.7e-7)),
    ),
}


def _state(name):
    inertia, rotvec, omega = BODIES[name]
    return inertia, tuple(Rotation.from_rotvec(rotvec).as_quat()), omega


def _complement(inertia, omega):
    """k'^2 of a body (the relabelling of docs/theory.md s3), for the test's own record."""
    m = np.asarray(inertia) * omega

    def excess(j):
        return sum(m[n] ** 2 * (inertia[n] - inertia[j]) / inertia[n] for n in range(3) if n != j)

    lo, mid, hi = np.argsort(inertia)
    first, third = (lo, hi) if excess(mid) > 0 else (hi, lo)
    return (inertia[third] - inertia[first]) * excess(mid) / ((inertia[third] - inertia[mid]) * excess(first))


def test_the_near_separatrix_body_is_where_it_says():
    assert _complement(*[np.array(v) for v in BODIES["near the separatrix"][::2]]) == (
        pytest.approx(1e-6, rel=0.02)
    )


# --- the special functions -------------------------------------------------------------


@pytest.mark.slow
def test_carlson_integrals_agree_with_mpmath():
    with mp.workdps(30):
        for x, y, z, p in RNG.uniform(0.0, 4.0, (200, 4)):
            assert elliptic.carlson_rf(x, y, z) == pytest.approx(float(mp.elliprf(x, y, z)), rel=1e-15)
            assert elliptic.carlson_rj(x, y, z, p + 0.05) == pytest.approx(
                float(mp.elliprj(x, y, z, p + 0.05)), rel=1e-15
            )


@pytest.mark.parametrize("complement", ["0.7", "1e-3", "1e-6", "1e-12", "1e-20"])
def test_jacobi_functions_and_the_third_kind_keep_their_accuracy_up_to_the_separatrix(complement):
    """sn, cn, dn relatively accurate (each where it is small too), and Pi(n; am u) accurate
    absolutely, over two periods, as m -> 1: where scipy's ellipj loses digits."""
    n = -0.7
    with mp.workdps(40):
        m1 = mp.mpf(complement)
        m = 1 - m1
        quarter = elliptic.complete_first(float(m1))
        whole = elliptic.complete_third(n, float(m1), quarter)
        assert quarter == pytest.approx(float(mp.ellipk(m)), rel=1e-15)
        assert whole == pytest.approx(float(mp.ellippi(n, m)), rel=2e-15)
        worst_relative, worst_third = 0.0, 0.0
        for u in np.linspace(-2.0, 2.0, 37)[1:-1] * quarter + 0.013:
            values = elliptic.jacobi(u, float(m), float(m1), quarter)
            exact = [mp.ellipfun(name, mp.mpf(u), m=m) for name in ("sn", "cn", "dn")]
            worst_relative = max(
                worst_relative,
                *(abs(v - float(e)) / abs(float(e)) for v, e in zip(values, exact, strict=True)),
            )
            amplitude = mp.atan2(exact[0], exact[1])
            amplitude += 2 * mp.pi * mp.nint((u / float(quarter) * mp.pi / 2 - amplitude) / (2 * mp.pi))
            third = elliptic.third_kind(n, *values, u, whole)
            turns = mp.nint(amplitude / mp.pi)
            exact_third = 2 * turns * mp.ellippi(n, m) + mp.ellippi(n, amplitude - turns * mp.pi, m)
            worst_third = max(worst_third, abs(third - float(exact_third)))
    # measured: relative 8e-14 up to m1 = 1e-6, 4e-13 at 1e-12, 2e-12 at 1e-20 (next to
    # the zeros, where the rounding of u itself shows); Pi within 2e-15 up to m1 = 1e-6,
    # 3e-14 at 1e-12 and 1.3e-12 at 1e-20 (~ eps / sqrt(k'), docs/theory.md)
    assert worst_relative < 5e-12
    assert worst_third < max(1e-14, 3e-16 / float(m1) ** 0.25)


# --- the flow --------------------------------------------------------------------------


def _rhs(t, y, inertia):
    rotation, w = y[:9].reshape(3, 3), y[9:]
    skew = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    return np.concatenate([(rotation @ skew).ravel(), np.cross(inertia * w, w) / inertia])


def _dop853(inertia, q0, omega0, duration):
    start = np.concatenate([Rotation.from_quat(q0).as_matrix().ravel(), omega0])
    run = solve_ivp(
        _rhs, (0.0, duration), start, method="DOP853", rtol=1e-13, atol=1e-13, args=(np.asarray(inertia),)
    )
    return Rotation.from_matrix(run.y[:9, -1].reshape(3, 3)).as_quat(), run.y[9:, -1]


@pytest.mark.parametrize("name", list(BODIES))
def test_the_exact_flow_agrees_with_dop853_and_with_mpmath_at_10_s(name):
    """DOP853 at 1e-13 (an independent integration of R and w) agrees within its own error;
    the 40-digit evaluation of the same solution shows the float64 one within 1e-13."""
    inertia, q0, omega0 = _state(name)
    q, omega = free_flow(inertia, q0, omega0, 10.0)
    q_dop, omega_dop = _dop853(inertia, q0, np.array(omega0), 10.0)
    assert orientation_error(np.array(q), q_dop) < 2e-12  # measured 2e-13 to 7e-13
    assert np.max(np.abs(np.array(omega) - omega_dop)) < 2e-13
    q_mp, omega_mp = exact_state(inertia, q0, omega0, 10.0)
    assert angle_between(q_mp, q) < 1e-13  # measured 2e-15 to 1.3e-14
    assert max(abs(float(a) - b) for a, b in zip(omega_mp, omega, strict=True)) < 1e-13


def _one_ulp_spread(inertia, q0, omega0, duration):
    """How far the exact solution moves when one component of ``omega0`` moves by one ulp:
    the accuracy float64 input allows at all."""
    exact = exact_state(inertia, q0, omega0, duration)[0]
    moved = []
    for k in range(3):
        for direction in (-np.inf, np.inf):
            nudged = list(omega0)
            nudged[k] = float(np.nextafter(omega0[k], direction))
            moved.append(
                angle_between(exact, [float(v) for v in exact_state(inertia, q0, nudged, duration)[0]])
            )
    return max(moved)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["largest axis", "smallest axis", "axes unsorted (odd order)"])
def test_long_runs_stay_at_the_accuracy_float64_input_allows(name):
    """Up to 1e4 periods of w: the error grows linearly (1.6e-15 to 7.5e-15 rad a period,
    measured) and stays within a few times the spread of the exact solution under a one-ulp
    change of w0 (no phase is integrated, so nothing else accumulates)."""
    inertia, q0, omega0 = _state(name)
    scene = Scene(body=Body(mass=1.0, inertia=inertia), quaternion=q0, omega_body=omega0, duration=1.0)
    period = 2.0 * flip_interval_exact(scene)
    errors = []
    for periods in (1, 100, 10_000):
        duration = 1.2345 * periods * period
        q_mp = exact_state(inertia, q0, omega0, duration)[0]
        errors.append(angle_between(q_mp, free_flow(inertia, q0, omega0, duration)[0]))
        assert errors[-1] <= max(1e-13, 8.0 * _one_ulp_spread(inertia, q0, omega0, duration))
    assert errors[0] < 1e-13 and errors[-1] < 1e-10
    assert errors[2] / 10_000 < 10.0 * max(errors[0], 1e-15)  # no faster than linear


@pytest.mark.parametrize("duration", [10.0, 1e3])
def test_the_flow_is_a_group(duration):
    """flow(t1 + t2) = flow(t2) o flow(t1), up to what the rounding of the state at t1 to
    float64 allows: at 10 s to 1e-14; at 1e3 s the defect (measured 4.7e-13) is within a few
    times the change one ulp of w(t1) makes in the exact solution (1.8e-13)."""
    inertia, q0, omega0 = _state("largest axis")
    whole_q, whole_w = free_flow(inertia, q0, omega0, duration)
    half_q, half_w = free_flow(inertia, q0, omega0, 0.37 * duration)
    joined_q, joined_w = free_flow(inertia, half_q, half_w, 0.63 * duration)
    bound = 1e-14 if duration <= 10.0 else 4.0 * _one_ulp_spread(inertia, half_q, half_w, 0.63 * duration)
    assert orientation_error(np.array(whole_q), np.array(joined_q)) < bound
    assert np.max(np.abs(np.array(whole_w) - joined_w)) < bound


@pytest.mark.parametrize("name", list(BODIES))
def test_the_exact_flow_satisfies_euler_s_equations_and_keeps_the_invariants(name):
    """A sixth-order central difference of w(t) and q(t) against I dw/dt = (I w) x w and
    dq/dt = q (w, 0) / 2, to the difference's own round-off; energy and |L| to 1e-15."""
    inertia, q0, omega0 = _state(name)
    inertia_a = np.array(inertia)
    h = 2e-3
    energy0 = 0.5 * np.dot(omega0, inertia_a * omega0)
    momentum0 = Rotation.from_quat(q0).apply(inertia_a * omega0)
    for t in np.linspace(0.0, 20.0, 9):
        around = {s: free_flow(inertia, q0, omega0, t + s * h) for s in (-3, -2, -1, 1, 2, 3)}
        q, w = (np.array(v) for v in free_flow(inertia, q0, omega0, t))
        euler = np.cross(inertia_a * w, w) / inertia_a
        rate = Rotation.from_quat(q).as_matrix().T @ _angular_rate(q, _derivative(around, 0, h))
        # each evaluation is good to ~1e-15 (its phases rounded), which the difference
        # divides by h: measured up to 1.9e-12 for both
        assert np.max(np.abs(_derivative(around, 1, h) - euler)) < 5e-12
        assert np.max(np.abs(rate - w)) < 5e-12
        assert abs(0.5 * np.dot(w, inertia_a * w) - energy0) <= 1e-15 * energy0 * 4
        momentum = Rotation.from_quat(q).apply(inertia_a * w)
        assert abs(np.linalg.norm(momentum) - np.linalg.norm(momentum0)) <= (
            4e-15 * np.linalg.norm(momentum0)
        )
        assert np.max(np.abs(momentum - momentum0)) < 1e-13 * np.linalg.norm(momentum0)


def _derivative(around, part, h):
    """The sixth-order central difference of part ``part`` (0: q, 1: w) of the states
    ``around[s]`` at ``t + s h``, s = +-1, +-2, +-3."""
    a = {s: np.array(state[part]) for s, state in around.items()}
    return (45.0 * (a[1] - a[-1]) - 9.0 * (a[2] - a[-2]) + a[3] - a[-3]) / (60.0 * h)


def _angular_rate(q, q_dot):
    """The space angular velocity of q(t) from its derivative: 2 q_dot q^-1 (vector part)."""
    x, y, z, w = q
    dx, dy, dz, dw = q_dot
    # (q_dot * conj(q)), vector part, scalar-last Hamilton product
    return 2.0 * np.array(
        [
            dw * -x + dx * w + dy * -z - dz * -y,
            dw * -y - dx * -z + dy * w + dz * -x,
            dw * -z + dx * -y - dy * -x + dz * w,
        ]
    )


SEPARATRIX = ((3.0, 4.0, 6.0), (2.0, 0.7, 1.0))  # I1 (I2 - I1) w1^2 = I3 (I3 - I2) w3^2: exact


def test_on_the_separatrix_the_body_turns_towards_its_intermediate_axis():
    inertia, omega0 = SEPARATRIX
    m = np.array(inertia) * omega0
    assert (
        m[0] ** 2 * (inertia[0] - inertia[1]) / inertia[0]
        + (m[2] ** 2 * (inertia[2] - inertia[1]) / inertia[2])
        == 0.0
    )
    q0 = tuple(Rotation.from_rotvec((0.1, 0.2, 0.3)).as_quat())
    q, omega = free_flow(inertia, q0, omega0, 10.0)
    q_dop, omega_dop = _dop853(inertia, q0, np.array(omega0), 10.0)
    assert orientation_error(np.array(q), q_dop) < 2e-12
    assert np.max(np.abs(np.array(omega) - omega_dop)) < 1e-12
    late = np.array(free_flow(inertia, q0, omega0, 400.0)[1])
    g = np.linalg.norm(m)
    assert abs(late[0]) < 1e-12 and abs(late[2]) < 1e-12
    assert abs(abs(late[1]) - g / inertia[1]) < 1e-12


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("inertia", [(1.0, 2.0, 3.0), (2.0, 2.0, 2.0)])
def test_permanent_rotations_turn_at_constant_rate(axis, inertia):
    """About each principal axis (the unstable intermediate one too) and any axis of a
    spherical body: w stays, the body turns about it at |w|."""
    omega0 = tuple(0.7 if k == axis else 0.0 for k in range(3))
    if inertia[0] == inertia[1] == inertia[2]:
        omega0 = (0.3, -0.5, 0.6)
    q0 = tuple(Rotation.from_rotvec((0.2, -0.4, 0.1)).as_quat())
    q, omega = free_flow(inertia, q0, omega0, 7.5)
    assert omega == omega0
    expected = (Rotation.from_quat(q0) * Rotation.from_rotvec(np.array(omega0) * 7.5)).as_quat()
    assert orientation_error(np.array(q), expected) < 1e-15


@pytest.mark.parametrize(
    "inertia, gap",
    [((1.0, 1.0, 2.0), 0.0), ((2.0, 1.0, 1.0), 0.0), ((1.0, 1.0, 2.0), 1e-13), ((1.5, 1.0, 1.5), 1e-13)],
)
def test_the_symmetric_limit_is_the_closed_form(inertia, gap):
    """Symmetric bodies (and bodies 1e-13 from symmetric) agree with the symmetric top's
    closed form: the elliptic solution tends to it as k -> 0."""
    q0 = Rotation.from_rotvec((0.3, 0.1, -0.2)).as_quat()
    omega0 = np.array([0.25, 0.1, 0.2]) + 3.0 * (np.array(inertia) != 1.0)
    perturbed = tuple(np.array(inertia) + gap * np.array([0.0, 1.0, 0.0]))
    times = np.array([0.5, 3.0, 10.0])
    q_closed, omega_closed = symmetric_top(np.array(inertia), q0, omega0, times)
    for k, t in enumerate(times):
        q, omega = free_flow(perturbed, tuple(q0), tuple(omega0), t)
        assert orientation_error(np.array(q), q_closed[k]) < 1e-13 + 2e-12 * gap / 1e-13
        assert np.max(np.abs(np.array(omega) - omega_closed[k])) < 1e-13 + 2e-12 * gap / 1e-13


def test_a_batch_equals_its_bodies_one_by_one_and_is_the_reference_of_free_bodies():
    names = list(BODIES)
    inertia = np.array([BODIES[n][0] for n in names])
    quaternion = np.array([_state(n)[1] for n in names])
    omega = np.array([BODIES[n][2] for n in names])
    times = np.linspace(0.0, 50.0, 11)
    q_out = np.empty((len(names), times.size, 4))
    w_out = np.empty((len(names), times.size, 3))
    free_flow_batch(inertia, quaternion, omega, times, q_out, w_out)
    for b in range(len(names)):
        for k, t in enumerate(times):
            q, w = free_flow(tuple(inertia[b]), tuple(quaternion[b]), tuple(omega[b]), t)
            assert tuple(q_out[b, k]) == q and tuple(w_out[b, k]) == w
        scene = Scene(
            body=Body(mass=1.0, inertia=tuple(inertia[b])),
            quaternion=tuple(quaternion[b]),
            omega_body=tuple(omega[b]),
            duration=50.0,
        )
        reference = reference_solution(scene, times)
        assert reference.name == "exact_asymmetric"
        assert np.array_equal(reference.quaternion, q_out[b])
