"""The published rotation steps (group ``published``): each against what its source states,
written here from the source and not from the scheme's code.

Their orders, their claimed invariants, batch = solo and loads are checked with every other
fixed-step scheme (test_schemes.py, test_conventions.py); here are the properties that single
each one out, each of which fails when its step is changed."""

import numpy as np
import pytest
import yaml
from helpers import CONFIGS, final_orientation_errors
from scipy.optimize import fsolve
from scipy.spatial.transform import Rotation

from rbstudy.archive.load import open_results
from rbstudy.inputs.scenes import scene_from_mapping
from rbstudy.physics.references import reference_solution
from rbstudy.physics.simulate import simulate
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study
from rbstudy.schemes import get_scheme, scheme_groups

INERTIA = np.array([1.0, 2.0, 3.0])


def free_body(omega, duration, inertia=INERTIA, rotation_vector=(0.3, -0.2, 0.5)):
    return scene_from_mapping(
        {
            "body": {"inertia": list(map(float, inertia))},
            "initial": {
                "angular_velocity": {"body": list(map(float, omega))},
                "orientation": {"rotation_vector": list(rotation_vector)},
            },
            "duration": duration,
        },
        source="test",
    )


def one_step(scheme, omega, h, options=None):
    """The body frame's rotation vector over one step (rad, body axes at the step's start)
    and the spin after it, for a free body starting at ``omega``."""
    run = simulate([free_body(omega, h)], scheme, h, h, options)
    start, end = Rotation.from_quat(run.quaternion[0, 0]), Rotation.from_quat(run.quaternion[0, -1])
    return (start.inv() * end).as_rotvec(), run.omega_body[0, -1]


def test_the_shipped_study_stores_each_steps_error_against_the_exact_solution(tmp_path):
    """configs/published_steps.yaml, shortened to 0.48 s and three steps: every published
    step sweeps the Abaqus top and the asymmetric body through the pipeline, and the archive's
    final orientation errors are those of the step run alone against the exact solution
    (`reference` symmetric_top and exact_asymmetric), to 1e-12 relative."""
    study = yaml.safe_load((CONFIGS / "published_steps.yaml").read_text())
    study["scene"]["duration"] = 0.48
    study["sweep"]["dt"] = {"halving": 0.04, "count": 3}
    path = tmp_path / "published_steps.yaml"
    path.write_text(yaml.safe_dump(study))
    loaded = load_study(path)
    ds = open_results(run_study(loaded, tmp_path / "out", quiet=True).path)
    meanings = ds["reference"].attrs["flag_meanings"].split()
    assert [meanings[code] for code in ds["reference"].values] == ["symmetric_top", "exact_asymmetric"]
    scenes = {case.index[-1]: case.scene for case in loaded.cases}
    dts = ds["dt"].values
    for scheme in scheme_groups()["published"]:
        for body, scene in scenes.items():
            options = {"augmented": 1} if scheme == "buss" else None
            expected = final_orientation_errors(scene, scheme, dts, 0.04, options)
            stored = ds["final_orientation_error"].sel(scheme=scheme, body=body)
            if "augmented" in stored.dims:
                stored = stored.sel(augmented=1 if scheme == "buss" else 0)
            np.testing.assert_allclose(stored.transpose("dt").values, expected, rtol=1e-12)


def test_the_published_group_is_its_own():
    """``scheme: published`` names the four steps; ``all`` (builtin) does not take them."""
    groups = scheme_groups()
    assert groups["published"] == ["buss", "jolt", "lgvi", "simo_wong"]
    assert not set(groups["published"]) & set(groups["builtin"])
    assert all(get_scheme(name).group == "published" for name in groups["published"])


@pytest.mark.parametrize("augmented", [0, 1])
def test_buss_one_step_error_is_the_omitted_taylor_term(augmented):
    """Buss's rotation vector is the Magnus expansion of the frame's equation for a spin
    linear in time: ``h w + h^2/2 a (+ h^3/12 a x w)``. Against the exact rotation, the step
    then misses ``h^3/6 w''`` (space frame, seen in body axes: ``w_b'' + w_b x a``), and the
    plain step the commutator ``h^3/12 a x w`` besides. Both coefficients, computed here from
    Euler's equations, are matched to 0.5% at h = 1e-3 s: the term's sign is checked."""
    omega = np.array([0.6, 1.5, 0.9])
    m = INERTIA * omega
    alpha = np.cross(m, omega) / INERTIA  # Euler: I w' = I w x w
    jerk = (np.cross(INERTIA * alpha, omega) + np.cross(m, alpha)) / INERTIA  # w_b''
    beta = jerk + np.cross(omega, alpha)  # R^T (d^2/dt^2 of the space spin)
    missing = beta / 6.0 + (0.0 if augmented else np.cross(alpha, omega) / 12.0)
    h = 1e-3
    scene = free_body(omega, h)
    exact = reference_solution(scene, np.array([0.0, h]))
    turned = (
        Rotation.from_quat(exact.quaternion[0]).inv() * Rotation.from_quat(exact.quaternion[1])
    ).as_rotvec()
    step, _ = one_step("buss", omega, h, {"augmented": augmented})
    observed = (turned - step) / h**3
    np.testing.assert_allclose(observed, missing, rtol=5e-3, atol=5e-3 * np.linalg.norm(missing))


def test_jolt_is_leapfrog_with_the_momentum_rescaled():
    """Jolt's gyroscopic update is leapfrog's Euler step on the body momentum, scaled back to
    the length it had; both then turn the frame by ``h w+``. One step of each from the same
    free body shows it."""
    omega, h = np.array([0.6, 1.5, 0.9]), 0.05
    jolt_turn, jolt_omega = one_step("jolt", omega, h)
    leap_turn, leap_omega = one_step("leapfrog", omega, h)
    m0, leap_m = INERTIA * omega, INERTIA * leap_omega
    rescaled = leap_m * np.linalg.norm(m0) / np.linalg.norm(leap_m)
    np.testing.assert_allclose(INERTIA * jolt_omega, rescaled, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(jolt_turn, h * jolt_omega, rtol=1e-13, atol=1e-16)
    assert not np.allclose(leap_omega, jolt_omega, rtol=1e-6)  # the rescale is not the identity
    np.testing.assert_allclose(leap_turn, h * leap_omega, rtol=1e-13, atol=1e-16)


@pytest.mark.parametrize("axis", [0, 2])
def test_jolt_drives_the_energy_to_the_intermediate_axis(axis):
    """Avian PR 993's observation of Jolt's step: keeping ``|L|`` while the Euler step adds
    its O(h^2) a step, the energy of a body spun near its minor (axis 0) or major (axis 2) axis
    drifts to ``L^2 / (2 I_2)``, the intermediate axis's. Over 2,000 s at h = 0.05 s it
    closes at least 95% of the gap; exact (`reference = exact_asymmetric`) keeps the energy."""
    omega = np.full(3, 0.05)
    omega[axis] = 1.0
    run = simulate([free_body(omega, 2000.0)], "jolt", 0.05, 20.0)
    m = INERTIA * run.omega_body[0]
    energy = 0.5 * (m * run.omega_body[0]).sum(-1)
    intermediate = (m[0] ** 2).sum() / (2.0 * INERTIA[1])
    gap = np.abs(energy - intermediate)
    assert gap[-1] < 0.05 * gap[0], (energy[0], energy[-1], intermediate)
    np.testing.assert_allclose(np.linalg.norm(m, axis=-1), np.linalg.norm(m[0]), rtol=1e-12)


def moser_veselov_step(pi, h):
    """One step of Moser & Veselov's discrete body in its matrix form, solved here by scipy:
    the rotation ``F`` with ``h [Pi]x = F J_d - J_d F^T``, ``J_d = tr(I)/2 - I``, then
    ``Pi+ = F^T Pi``; returns ``(F, Pi+)``."""
    j_d = np.diag(0.5 * INERTIA.sum() - INERTIA)

    def unskew(a):
        return np.array([a[2, 1], a[0, 2], a[1, 0]])

    def equation(rotation_vector):
        f = Rotation.from_rotvec(rotation_vector).as_matrix()
        return unskew(f @ j_d - j_d @ f.T) - h * pi

    start = h * pi / INERTIA
    f = Rotation.from_rotvec(fsolve(equation, start, xtol=1e-15)).as_matrix()
    return f, f.T @ pi


def test_lgvi_free_step_is_the_discrete_moser_veselov_body():
    """lgvi's free step, solved in the Cayley vector, is Moser & Veselov's matrix equation
    solved by scipy in the rotation vector: same frame and momentum to 1e-13, for a step of
    h|w| = 0.9 where the scheme differs from the exact flow by 1e-2."""
    omega, h = np.array([0.6, 1.5, 0.9]), 0.5
    turn, omega_next = one_step("lgvi", omega, h)
    f, pi_next = moser_veselov_step(INERTIA * omega, h)
    np.testing.assert_allclose(Rotation.from_rotvec(turn).as_matrix(), f, atol=1e-13)
    np.testing.assert_allclose(INERTIA * omega_next, pi_next, rtol=1e-13, atol=1e-14)
    exact = reference_solution(free_body(omega, h), np.array([0.0, h])).omega_body[1]
    assert np.linalg.norm(omega_next - exact) > 1e-3  # a real step, not the exact flow


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_lgvi_turns_a_steady_spin_by_asin_h_w_and_has_no_step_past_one(axis):
    """About a principal axis ``k`` the Moser-Veselov equation reads ``h I_k w = I_k sin(psi)``
    (``F J_d - J_d F^T`` of a turn ``psi`` about ``e_k`` is ``sin(psi) (tr I - I_i - I_j)``):
    a steady spin turns by ``asin(h w)`` a step, the exact flow at a time stretched by
    ``asin(h w)/(h w)``, and no rotation solves it past ``h w = 1``, where lgvi ends
    ``not_converged``, a result and no crash."""
    h, spins = 0.1, np.zeros(3)
    spins[axis] = 9.9  # h w = 0.99
    run = simulate([free_body(spins, 5 * h, rotation_vector=(0.0, 0.0, 0.0))], "lgvi", h, h)
    angles = Rotation.from_quat(run.quaternion[0]).magnitude()
    np.testing.assert_allclose(angles[1], np.arcsin(0.99), rtol=1e-12)
    np.testing.assert_allclose(run.omega_body[0, -1], spins, rtol=1e-13)
    spins[axis] = 10.1  # h w = 1.01
    past = simulate([free_body(spins, 5 * h, rotation_vector=(0.0, 0.0, 0.0))], "lgvi", h, h)
    assert past.status_names == ["not_converged"]


def test_simo_wong_turns_by_the_mean_spin_and_keeps_the_energy():
    """Simo & Wong's step turns the frame by ``exp(h/2 (w + w+))`` and the momentum back by
    it (their beta = 1/2, gamma = 1): the step's own rotation vector equals the mean spin
    times h to round-off, and the energy and ``|L|`` are those of the start."""
    omega, h = np.array([0.6, 1.5, 0.9]), 0.3
    turn, omega_next = one_step("simo_wong", omega, h)
    np.testing.assert_allclose(turn, 0.5 * h * (omega + omega_next), rtol=1e-13, atol=1e-15)
    energy = lambda w: 0.5 * (INERTIA * w * w).sum()  # noqa: E731
    assert abs(energy(omega_next) / energy(omega) - 1.0) < 1e-14
    assert abs(np.linalg.norm(INERTIA * omega_next) / np.linalg.norm(INERTIA * omega) - 1.0) < 1e-14


def test_simo_wong_and_midpoint_differ_only_in_the_map():
    """midpoint (Austin, Krishnaprasad & Wang) turns by the Cayley transform of the same mean
    spin: both keep the energy, yet they are different steps, apart by O(h^3) a step (the
    exponential and the Cayley map agree to second order)."""
    omega = np.array([0.6, 1.5, 0.9])
    gaps = []
    for h in (0.2, 0.1, 0.05):
        sw_turn, sw_omega = one_step("simo_wong", omega, h)
        mid_turn, mid_omega = one_step("midpoint", omega, h)
        gaps.append(np.linalg.norm(sw_turn - mid_turn) + np.linalg.norm(sw_omega - mid_omega) * h)
    slopes = np.diff(np.log(gaps)) / np.diff(np.log([0.2, 0.1, 0.05]))
    assert gaps[-1] > 1e-9  # not the same step
    np.testing.assert_allclose(slopes, 3.0, atol=0.15)
