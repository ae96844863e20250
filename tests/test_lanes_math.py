"""The sine and cosine that vectorise (`rbstudy.numerics.lanes_math`) against numpy's (glibc's,
correctly rounded in all but rare cases), within their stated ulps."""

import math

import numba
import numpy as np
import pytest

from rbstudy.numerics import block as B
from rbstudy.numerics.lanes_math import REDUCED, ULPS, quat_exp_poly, sin_cos
from rbstudy.numerics.rotation import SMALL_ANGLE, quat_exp


@numba.njit
def _sin_cos_all(x):
    sine, cosine = np.empty_like(x), np.empty_like(x)
    for i in range(x.size):
        sine[i], cosine[i] = sin_cos(x[i])
    return sine, cosine


def _ulps(ours, reference):
    """|ours - reference| in units of the last place of the larger of the two."""
    return np.abs(ours - reference) / np.spacing(np.maximum(np.abs(ours), np.abs(reference)))


def _edges():
    """Zeros, the multiples of pi/4 and pi/2 where the reduction changes quadrant and cancels,
    their neighbours, tiny and denormal arguments, the ends of the reduced range."""
    multiples = np.arange(-2000, 2001) * (math.pi / 4)
    near = np.concatenate([multiples, np.nextafter(multiples, np.inf), np.nextafter(multiples, -np.inf)])
    tiny = np.array([0.0, -0.0, 5e-324, -5e-324, 1e-300, 1e-16, 1e-8, SMALL_ANGLE, 0.5 * SMALL_ANGLE])
    ends = np.array([REDUCED, -REDUCED, np.nextafter(REDUCED, 0.0), 2.0**19 * math.pi, 355.0, 103993.0])
    return np.concatenate([near, tiny, ends])


# A component ``sin(a/2) v_i / a`` of the rotation: the sine's ulp, and a division and a
# product whose roundings may fall either way on each side (measured: up to 3).
_ROTATION_ULPS = ULPS + 3


@pytest.mark.parametrize("scale", [1e-6, 0.5, math.pi, 100.0, 1e4, REDUCED])
def test_sine_and_cosine_are_within_their_ulps_of_numpy(scale):
    x = np.random.default_rng(int(scale * 1e6) % 2**32).uniform(-scale, scale, 1_000_000)
    x = np.concatenate([x, _edges()])
    sine, cosine = _sin_cos_all(x)
    assert _ulps(sine, np.sin(x)).max() <= ULPS
    assert _ulps(cosine, np.cos(x)).max() <= ULPS
    # mostly the very bits: a wrong kernel would differ in many more
    assert np.mean(sine == np.sin(x)) > 0.8


def test_beyond_the_reduced_range_they_are_libm_and_nan_stays_nan():
    x = np.array([np.nextafter(REDUCED, np.inf), 1e7, -3e12, 1e300, np.inf, -np.inf, np.nan])
    sine, cosine = _sin_cos_all(x)
    with np.errstate(invalid="ignore"):  # numpy warns of the infinities, as it should
        assert np.array_equal(sine, np.sin(x), equal_nan=True)
        assert np.array_equal(cosine, np.cos(x), equal_nan=True)
    assert np.isnan(sine[-3:]).all() and np.isnan(cosine[-3:]).all()


def test_signs_of_zero_follow_the_argument():
    sine, cosine = _sin_cos_all(np.array([0.0, -0.0]))
    assert math.copysign(1.0, sine[0]) == 1.0 and math.copysign(1.0, sine[1]) == -1.0
    assert np.all(cosine == 1.0)


def test_the_rotation_of_a_step_is_libm_s_within_an_ulp_or_two():
    """quat_exp_poly, the rotation of the schemes that step blocks, against
    `rotation.quat_exp` (libm's sine): the Taylor branch to the bit, the rest within
    `_ROTATION_ULPS` of each component."""
    rng = np.random.default_rng(7)
    for scale in (1e-5, 1e-3, 0.3, 3.0):
        for v in rng.normal(size=(2000, 3)) * scale:
            ours, libm = np.array(quat_exp_poly(tuple(v))), np.array(quat_exp(tuple(v)))
            if np.linalg.norm(v) < SMALL_ANGLE:
                assert np.array_equal(ours, libm)
            assert _ulps(ours, libm).max() <= _ROTATION_ULPS, v


@numba.njit
def _block_rotations(vectors):
    """`block.quat_exp_columns` of the rotation vectors ``vectors`` (BLOCK, 3), one a lane."""
    rows = np.zeros(B.N_ROWS * B.BLOCK)
    for lane in range(B.BLOCK):
        B.set_column3(rows, B.TEMP, lane, (vectors[lane, 0], vectors[lane, 1], vectors[lane, 2]))
    B.quat_exp_columns(rows, B.TEMP, B.TEMP + 3)
    out = np.empty((B.BLOCK, 4))
    for lane in range(B.BLOCK):
        out[lane] = B.column4(rows, B.TEMP + 3, lane)
    return out


@pytest.mark.slow
@pytest.mark.parametrize("odd_lanes", [False, True])
def test_a_block_s_rotations_are_quat_exp_poly_s_lane_for_lane(odd_lanes):
    """The rotations of a block's lanes (`block.quat_exp_columns`) have the bits of
    quat_exp_poly on every lane: angles from the Taylor branch to 3 rad, and with
    ``odd_lanes`` a lane past `REDUCED` and a NaN lane among them (libm's sine there)."""
    rng = np.random.default_rng(33)
    vectors = rng.normal(size=(B.BLOCK, 3)) * np.logspace(-6, 0.5, B.BLOCK)[:, None]
    if odd_lanes:
        vectors[5] = (1e12, 1.0, -2.0)  # where the polynomial's reduction is no longer exact
        vectors[9, 1] = np.nan
    ours = _block_rotations(vectors)
    for lane in range(B.BLOCK):
        assert np.array_equal(ours[lane], quat_exp_poly(tuple(vectors[lane])), equal_nan=True), lane
