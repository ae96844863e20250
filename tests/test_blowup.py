"""A blow-up is a result: status, failure time, and batch-mates untouched."""

import math

import numpy as np

from rbstudy.numerics.state import NOT_CONVERGED, OK, UNSTABLE
from rbstudy.physics.scenes import Body, Scene
from rbstudy.physics.simulate import simulate


def spinner(omega, inertia=(1.0, 2.0, 3.0), duration=200.0):
    return Scene(
        body=Body(mass=1.0, inertia=inertia),
        quaternion=(0.0, 0.0, 0.0, 1.0),
        omega_body=omega,
        duration=duration,
    )


def test_euler_near_the_intermediate_axis_is_flagged_unstable_with_a_time():
    diverging = spinner((0.1, 10.0, 0.1))  # h |w| = 1 at dt = 0.1, 2000 steps
    run = simulate([diverging], "euler", 0.1, 1.0)
    assert run.status_names == ["unstable"]
    assert 0.0 < run.results["failure_time"][0] < 200.0
    assert run.results["n_steps"][0] == round(run.results["failure_time"][0] / 0.1)
    after = run.time > run.results["failure_time"][0]
    assert np.all(np.isnan(run.omega_body[0, after]))
    assert np.all(np.isfinite(run.omega_body[0, ~after]))


def test_batch_mates_of_a_blow_up_equal_their_solo_runs():
    scenes = [spinner((0.0, 0.0, 0.5)), spinner((0.1, 10.0, 0.1)), spinner((0.02, 0.0, 0.3))]
    batch = simulate(scenes, "euler", 0.1, 1.0)
    assert list(batch.results["status"]) == [OK, UNSTABLE, OK]
    for i in (0, 2):
        alone = simulate([scenes[i]], "euler", 0.1, 1.0)
        assert np.array_equal(batch.quaternion[i], alone.quaternion[0])
        assert np.array_equal(batch.omega_body[i], alone.omega_body[0])
        assert math.isnan(batch.results["failure_time"][i])


def test_every_scheme_gives_a_result_or_a_clean_unstable_at_huge_steps():
    """h |w| = 3 on I = (1, 2, 3): nothing raises; each body ends ok, unstable or
    not_converged. A finished body has finite numbers; a failed one fails at the step its
    failure time names: sampled at every step, its samples before that time are finite and
    the rest NaN, and the same body run to the step before ends ok with those samples."""
    from rbstudy.schemes import BUILTIN

    scene = spinner((1.0, 2.0, 1.5), duration=30.0)
    h = 3.0 / np.linalg.norm(scene.omega_body)
    steps = round(30.0 / h)
    failed = []
    for name, scheme in BUILTIN.items():
        if scheme.adaptive:
            continue
        run = simulate([scene.with_changes(duration=steps * h)], name, h, h)
        assert run.results["status"][0] in (OK, UNSTABLE, NOT_CONVERGED)
        if run.results["status"][0] == OK:
            assert np.all(np.isfinite(run.omega_body))
            continue
        failed.append(name)
        failing_step = round(run.results["failure_time"][0] / h)
        assert 1 <= failing_step <= steps, name
        finite = np.isfinite(run.omega_body[0]).all(axis=1)
        assert np.array_equal(finite, np.arange(steps + 1) < failing_step), name
        if failing_step > 1:  # a run of no steps is no scene
            before = simulate([scene.with_changes(duration=(failing_step - 1) * h)], name, h, h)
            assert before.status_names == ["ok"], name
            assert np.array_equal(before.omega_body[0], run.omega_body[0, :failing_step]), name
    assert len(failed) >= 2  # the huge step does make schemes fail


def test_bodies_run_side_by_side_equal_their_solo_runs_in_every_result():
    """leapfrog runs two bodies of a batch per loop (`make_entry(..., lanes=2)`): a pair
    whose first or second body blows up, a pair of two stable bodies and the odd body out
    give every sample and every result a body gives alone."""
    scenes = [
        spinner((0.0, 0.0, 0.5), duration=20.0),
        spinner((0.1, 10.0, 0.1), duration=20.0),
        spinner((0.2, 12.0, 0.1), duration=20.0),
        spinner((0.02, 0.0, 0.3), duration=20.0),
        spinner((0.3, 0.1, 0.2), duration=20.0),
    ]
    batch = simulate(scenes, "leapfrog", 0.1, 1.0, threads=1)  # rows (0,1), (2,3), (4)
    assert list(batch.results["status"]) == [OK, UNSTABLE, UNSTABLE, OK, OK]
    for i, scene in enumerate(scenes):
        alone = simulate([scene], "leapfrog", 0.1, 1.0)
        for field in ("quaternion", "omega_body", "position"):
            assert np.array_equal(getattr(batch, field)[i], getattr(alone, field)[0], equal_nan=True), (
                i,
                field,
            )
        for name, values in batch.results.items():
            assert np.array_equal(values[i], alone.results[name][0], equal_nan=True), (i, name)
