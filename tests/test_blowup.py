"""A blow-up is a result: status, failure time, and batch-mates untouched."""

import math

import numpy as np
import pytest
from helpers import FIXED_STEP

from rbstudy.numerics.loads import LOAD_KINDS
from rbstudy.numerics.state import NOT_CONVERGED, OK, UNSTABLE
from rbstudy.physics.scenes import Body, Scene
from rbstudy.physics.simulate import simulate
from rbstudy.schemes import get_scheme


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


# Batch sizes of the single-body loop (fewer bodies than `rbstudy.numerics.block.FEWEST`, 16,
# the last one AVX-512 register's worth), of a block partly filled, and of many blocks and a
# part (`BLOCK` = 64).
BATCH_SIZES = (1, 3, 8, 17, 1000)


def _mixed_batch(scheme, n_bodies, h):
    """The Abaqus top of `rbstudy bench` in ``n_bodies`` copies as driver rows, its spin scaled
    1 to 30 times (h |w| up to ~4: some bodies blow up, at various steps, others do not; 3 to
    90 times for an implicit scheme, whose Newton then fails on some), half of them made
    asymmetric (a top's Newton converges at any spin), a space moment on half of them, gravity
    on a third, and a lever on body 70 (its block runs the single-body loop)."""
    from rbstudy.numerics import state as S
    from rbstudy.pipeline.bench import abaqus_top_scene

    rng = np.random.default_rng(n_bodies)
    scene = abaqus_top_scene()
    state0 = np.repeat(scene.state_row()[None], n_bodies, axis=0)
    params = np.repeat(scene.param_row()[None], n_bodies, axis=0)
    spin_up = 3.0 if scheme.implicit else 1.0
    state0[:, S.OMEGA : S.OMEGA + 3] *= rng.uniform(1.0, 30.0, (n_bodies, 1)) * (spin_up * h / 0.02)
    asymmetric = rng.uniform(size=n_bodies) < 0.5
    params[:, S.INERTIA + 1] *= np.where(asymmetric, rng.uniform(1.2, 3.0, n_bodies), 1.0)
    state0[:, S.OMEGA] += rng.normal(size=n_bodies)
    params[:, S.MOMENT_SPACE : S.MOMENT_SPACE + 3] = rng.normal(size=(n_bodies, 3)) * (
        rng.uniform(size=(n_bodies, 1)) < 0.5
    )
    params[:, S.GRAVITY + 2] = -9.81 * (rng.uniform(size=n_bodies) < 0.3)
    if n_bodies > 70:
        params[70, S.LEVER] = 0.3
    options = np.repeat(scheme.option_row()[None], n_bodies, axis=0)
    return state0, params, options


@pytest.mark.parametrize("name", FIXED_STEP)
def test_every_body_of_a_batch_with_blow_ups_equals_its_solo_run(name):
    """Batch sizes 1, 3, 8, 17 and 1000, bodies blowing up among them: every sample and every
    result of each body is bit for bit that of the body alone (the blocks of
    `rbstudy.numerics.block` and the single-body loop alike)."""
    from rbstudy.numerics.driver import run_batch
    from rbstudy.schemes import get_scheme

    scheme, h, n_steps, every = get_scheme(name), 0.02, 40, 4
    statuses = set()
    for size in BATCH_SIZES:
        state0, params, options = _mixed_batch(scheme, size, h)
        batch = run_batch(scheme, state0, params, options, h, n_steps, every, threads=1)
        statuses.update(batch.results["status"].tolist())
        for b in range(size):
            alone = run_batch(
                scheme, state0[b : b + 1], params[b : b + 1], options[b : b + 1], h, n_steps, every
            )
            assert np.array_equal(batch.samples[b], alone.samples[0], equal_nan=True), (size, b)
            for field, values in batch.results.items():
                assert np.array_equal(values[b], alone.results[field][0], equal_nan=True), (size, b, field)
    # the explicit schemes blow up on some bodies here, Newton fails on some of the implicit
    # ones; exact_split, say, keeps every one
    assert OK in statuses


@pytest.mark.parametrize(
    "name", [name for name in FIXED_STEP if get_scheme(name).run_bodies_inplace.has_block]
)
def test_a_block_gives_every_body_the_bits_of_the_single_body_loop(name):
    """The kernels that take the time run every body through the single-body loop; without it
    the blocks run (`rbstudy.numerics.block`): 1000 bodies with blow-ups, run both ways, give
    the same samples and results bit for bit."""
    from rbstudy.numerics import state as S
    from rbstudy.numerics.driver import HALT_FLAG, n_samples

    scheme, h, n_steps, every = get_scheme(name), 0.02, 40, 4
    state0, params, options = _mixed_batch(scheme, 1000, h)
    runs = []
    for clock in (None, 0.0):
        samples = np.empty((1000, n_samples(n_steps, every), S.N_STATE))
        results = np.full((1000, S.N_RESULT), np.nan)
        scheme.ensure_compiled(timed=clock is not None)
        scheme.run_bodies_inplace(
            0, 1000, state0, params, options, h, n_steps, every, 0.5, samples, results, HALT_FLAG, clock
        )
        runs.append((samples, results))
    assert np.array_equal(runs[0][0], runs[1][0], equal_nan=True)
    assert np.array_equal(runs[0][1], runs[1][1], equal_nan=True)
    assert 0 < np.count_nonzero(runs[0][1][:, 0] == OK) < 1000
    if scheme.implicit:  # lanes whose Newton fails beside lanes that converge
        assert np.any(runs[0][1][:, 0] == NOT_CONVERGED)


def test_every_fixed_step_scheme_but_exact_split_steps_blocks():
    """The two tests above cover each scheme with a block step (issue 33): every fixed-step
    scheme of rbstudy's but exact_split, whose exact flow has none, and the published steps
    but jolt (buss, lgvi and simo_wong step one body at a time)."""
    without = [name for name in FIXED_STEP if not get_scheme(name).run_bodies_inplace.has_block]
    assert without == ["buss", "exact_split", "lgvi", "simo_wong"]


# A value of each load kind on every body of a batch, and a scale for its values.
LOAD_SCALES = {"gravity": 9.81, "lever": 0.3, "damping_moment": 0.05}


@pytest.mark.parametrize("kind", [kind.name for kind in LOAD_KINDS])
def test_every_load_kind_is_carried_by_the_blocks_or_kept_out_of_them(kind):
    """The load catalogue says which kinds the block path carries (`LoadKind.in_blocks`): a
    body with a kind it does not carry runs the single-body loop (`plain_loads` is False), and
    a block of bodies under a kind it carries gives each body the bits of its solo run, in
    every scheme's block step. A kind added to the catalogue as carried, and not read by the
    block steps, fails here; one not carried is kept out of the blocks by the catalogue."""
    from rbstudy.numerics import state as S
    from rbstudy.numerics.block import BLOCK
    from rbstudy.numerics.block_run import plain_loads
    from rbstudy.numerics.driver import run_batch
    from rbstudy.numerics.loads import KIND, needs_time
    from rbstudy.pipeline.bench import abaqus_top_scene

    load = KIND[kind]
    rng = np.random.default_rng(len(kind))
    scene = abaqus_top_scene()
    state0 = np.repeat(scene.state_row()[None], BLOCK, axis=0)
    state0[:, S.OMEGA : S.OMEGA + 3] += rng.normal(size=(BLOCK, 3))  # off the symmetry axis
    params = np.repeat(scene.param_row()[None], BLOCK, axis=0)
    params[:, load.offset : load.offset + load.width] = LOAD_SCALES.get(kind, 0.5) * rng.normal(
        size=(BLOCK, load.width)
    )
    assert bool(plain_loads(params[0])) == load.in_blocks
    if load.in_blocks:  # the block path runs: kernels without the time, a full block
        assert not needs_time(params).any()
    names = [name for name in FIXED_STEP if get_scheme(name).run_bodies_inplace.has_block]
    for name in names if load.in_blocks else ["rk4"]:
        scheme, h, n_steps, every = get_scheme(name), 0.01, 20, 4
        options = np.repeat(scheme.option_row()[None], BLOCK, axis=0)
        batch = run_batch(scheme, state0, params, options, h, n_steps, every, threads=1)
        assert np.all(batch.results["status"] == OK), name
        for b in range(BLOCK):
            one = slice(b, b + 1)
            alone = run_batch(scheme, state0[one], params[one], options[one], h, n_steps, every)
            assert np.array_equal(batch.samples[b], alone.samples[0]), (name, b)
            for field, result in batch.results.items():
                assert np.array_equal(result[b], alone.results[field][0], equal_nan=True), (name, b, field)


# Options that a block step reads (a composition's stages, splitting's axis order), each set on
# every body of a batch, and then on every other body, so that no block holds one option row.
BLOCK_OPTIONS = [
    ("splitting", {"axis_order": "213", "composition": 4}),
    ("splitting", {"axis_order": "312", "composition": 6}),
    ("midpoint", {"composition": 4}),
    ("no_squish", {"axis_order": "231", "composition": 4}),
    ("hht", {"alpha": -0.1}),
]


@pytest.mark.parametrize("name, values", BLOCK_OPTIONS)
def test_bodies_of_a_block_with_options_equal_their_solo_runs(name, values):
    """A block step given options (its bodies share them) and a batch whose option rows
    alternate (the single-body loop) give every body the bits of its solo run."""
    from rbstudy.numerics.driver import run_batch

    scheme, h, n_steps, every = get_scheme(name), 0.02, 30, 3
    state0, params, options = _mixed_batch(scheme, 80, h)
    options[:] = scheme.option_row(values)
    alternating = options.copy()
    alternating[::2] = scheme.option_row()
    statuses = set()
    for rows in (options, alternating):
        batch = run_batch(scheme, state0, params, rows, h, n_steps, every, threads=1)
        statuses.update(batch.results["status"].tolist())
        for b in range(80):
            one = slice(b, b + 1)
            alone = run_batch(scheme, state0[one], params[one], rows[one], h, n_steps, every)
            assert np.array_equal(batch.samples[b], alone.samples[0], equal_nan=True), (b, values)
            for field, result in batch.results.items():
                assert np.array_equal(result[b], alone.results[field][0], equal_nan=True), (b, field)
    assert OK in statuses


def test_the_blocks_compile_only_for_a_batch_that_can_fill_one():
    """A scheme's block step is compiled (`prepare`) for a batch of `FEWEST` bodies without
    the time, and never for a smaller batch or one whose kernels take the time."""
    from rbstudy.numerics import state as S
    from rbstudy.numerics.block import FEWEST
    from rbstudy.numerics.driver import HALT_FLAG, init_nothing, n_samples
    from rbstudy.numerics.entry import make_entry
    from rbstudy.schemes import euler

    def arguments(n_bodies, clock):
        state0 = np.zeros((n_bodies, S.N_STATE))
        state0[:, S.QUATERNION + 3] = 1.0
        params = np.zeros((n_bodies, S.N_PARAM))
        params[:, S.MASS] = 1.0
        params[:, S.INERTIA : S.INERTIA + 3] = 1.0
        options = np.zeros((n_bodies, S.N_OPTION))
        samples = np.empty((n_bodies, n_samples(2, 1), S.N_STATE))
        results = np.full((n_bodies, S.N_RESULT), np.nan)
        return (state0, params, options, 0.1, 2, 1, 0.5, samples, results, HALT_FLAG, clock)

    entry = make_entry(euler.step_inplace, init_nothing, euler.N_WORK, block=euler.block_step)
    for n_bodies, clock in ((FEWEST - 1, None), (FEWEST, 0.0)):
        entry.prepare(arguments(n_bodies, clock))
        entry(0, n_bodies, *arguments(n_bodies, clock))
    assert entry._blocks._dispatcher is None
    entry.prepare(arguments(FEWEST, None))
    assert entry._blocks.signatures
