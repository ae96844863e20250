"""How fast leapfrog can go on this machine: a plain struct-of-arrays loop over bodies.

The reference of issue 33 for the driver's kernels (docs/performance.md, "SIMD across
bodies"): leapfrog's step (`rbstudy.schemes.leapfrog`) on B bodies held as rows of one
component each (one flat array of `_N_ROWS` rows of B), one loop over the bodies, innermost,
so that LLVM runs it several bodies to an instruction (4 to an AVX2 register: LLVM's choice
on this Xeon); no status checks, no drift checks, no sampling. The loads are those of the
scheme's kernel without a lever or a body-fixed force: a body moment, a space moment turned
into the body, a space force and the weight. The sine and cosine are
`rbstudy.numerics.lanes_math.sin_cos_reduced` (``--libm``: libm's, whose calls LLVM cannot
vectorise).

It prints body-steps per second at B = 100, 4096 and 1e4 on one thread, whether LLVM
vectorised the loop (packed AVX-512 or AVX2 arithmetic in its assembly), and the machine's
peak for this step: ``FLOPS_PER_STEP`` at ``PEAK_FLOPS``.

Usage: NUMBA_NUM_THREADS=1 python pipelines/bench_simd.py [--body-steps N] [--libm]
"""

import argparse
import math
import re
import time

import numba
import numpy as np

from rbstudy.numerics.jit import jit
from rbstudy.numerics.lanes_math import sin_cos_reduced
from rbstudy.pipeline.bench import BENCH_DT, abaqus_top_scene

BATCH_SIZES = (100, 4096, 10_000)
BODY_STEPS = 30_000_000
# Floating-point operations of one body-step of the loop (+, -, x, / each one; a square root
# one), counted in its source: the space moment turned into the body 27 and added 3, Euler's
# rates and the update of w 21, of v 7, of x 6, the rotation vector 3 and its angle 7, the
# sine and cosine 48 (reduction 17, kernels 31), the quaternion exp 4, the product 28 and the
# renormalisation 13. The driver's checks between steps (~44, docs/performance.md) are not in it.
FLOPS_PER_STEP = 167
# One core of this machine (Intel Xeon, AVX-512, 2.6 GHz nominal): two 8-wide fused
# multiply-adds a cycle, 32 flops a cycle (docs/performance.md); without FMA contraction
# (rbstudy's kernels never contract, so that batch and solo agree) half of that, and a quarter
# with the 4-wide registers LLVM chooses here.
CLOCK_HZ = 2.6e9
PEAK_FLOPS = 32 * CLOCK_HZ


@jit
def _rotate_inverse(q0, q1, q2, q3, a0, a1, a2):
    """``R^T a`` for the unit quaternion (q0, q1, q2, q3), scalar last, as
    `rbstudy.numerics.rotation.quat_rotate` of the conjugate writes it."""
    # t = 2 (u x a), u = -(q0, q1, q2) for the conjugate
    t0 = 2.0 * (-q1 * a2 + q2 * a1)
    t1 = 2.0 * (-q2 * a0 + q0 * a2)
    t2 = 2.0 * (-q0 * a1 + q1 * a0)
    return (
        a0 + q3 * t0 + (-q1 * t2 + q2 * t1),
        a1 + q3 * t1 + (-q2 * t0 + q0 * t2),
        a2 + q3 * t2 + (-q0 * t1 + q1 * t0),
    )


def _make_loop(sine_cosine, n_bodies):
    """The reference loop with ``sine_cosine(x) -> (sin x, cos x)`` over ``n_bodies`` bodies, a
    number known when compiling: with the rows' width known, LLVM sees that no two rows of the
    one flat array overlap (with a width known only at run time it would need a check of each
    pair of rows, and does not vectorise)."""
    width = n_bodies

    @numba.njit(error_model="numpy")
    def step_soa(rows, h, n_steps):
        """Leapfrog steps of the bodies whose components are the rows of ``rows`` (_N_ROWS *
        width,), in the order of `_ROWS`; the state rows updated in place."""
        for _ in range(n_steps):
            for b in range(width):
                x0, x1, x2 = rows[_X * width + b], rows[(_X + 1) * width + b], rows[(_X + 2) * width + b]
                v0, v1, v2 = rows[_V * width + b], rows[(_V + 1) * width + b], rows[(_V + 2) * width + b]
                w0, w1, w2 = rows[_W * width + b], rows[(_W + 1) * width + b], rows[(_W + 2) * width + b]
                q0, q1 = rows[_Q * width + b], rows[(_Q + 1) * width + b]
                q2, q3 = rows[(_Q + 2) * width + b], rows[(_Q + 3) * width + b]
                i0, i1, i2 = rows[_I * width + b], rows[(_I + 1) * width + b], rows[(_I + 2) * width + b]
                s0, s1, s2 = _rotate_inverse(
                    q0,
                    q1,
                    q2,
                    q3,
                    rows[_MS * width + b],
                    rows[(_MS + 1) * width + b],
                    rows[(_MS + 2) * width + b],
                )
                m0 = rows[_MB * width + b] + s0
                m1 = rows[(_MB + 1) * width + b] + s1
                m2 = rows[(_MB + 2) * width + b] + s2
                w0 = w0 + h * ((m0 - (i2 - i1) * w1 * w2) / i0)
                w1 = w1 + h * ((m1 - (i0 - i2) * w2 * w0) / i1)
                w2 = w2 + h * ((m2 - (i1 - i0) * w0 * w1) / i2)
                a = h / rows[_MASS * width + b]
                v0 = v0 + a * rows[_F * width + b]
                v1 = v1 + a * rows[(_F + 1) * width + b]
                v2 = v2 + a * rows[(_F + 2) * width + b]
                r0, r1, r2 = h * w0, h * w1, h * w2
                angle = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
                sine, cosine = sine_cosine(0.5 * angle)
                s = sine / angle
                e0, e1, e2, e3 = s * r0, s * r1, s * r2, cosine
                n0 = q3 * e0 + q0 * e3 + q1 * e2 - q2 * e1
                n1 = q3 * e1 + q1 * e3 + q2 * e0 - q0 * e2
                n2 = q3 * e2 + q2 * e3 + q0 * e1 - q1 * e0
                n3 = q3 * e3 - q0 * e0 - q1 * e1 - q2 * e2
                norm = 1.0 / math.sqrt(n0 * n0 + n1 * n1 + n2 * n2 + n3 * n3)
                rows[_X * width + b] = x0 + h * v0
                rows[(_X + 1) * width + b] = x1 + h * v1
                rows[(_X + 2) * width + b] = x2 + h * v2
                rows[_V * width + b], rows[(_V + 1) * width + b], rows[(_V + 2) * width + b] = v0, v1, v2
                rows[_W * width + b], rows[(_W + 1) * width + b], rows[(_W + 2) * width + b] = w0, w1, w2
                rows[_Q * width + b], rows[(_Q + 1) * width + b] = n0 * norm, n1 * norm
                rows[(_Q + 2) * width + b], rows[(_Q + 3) * width + b] = n2 * norm, n3 * norm

    return step_soa


@jit
def _libm_sin_cos(x):
    return math.sin(x), math.cos(x)


# The rows of the reference loop's one array: position, velocity, spin, orientation, then
# inertia, body and space moments, the force in space (weight included) and the mass.
_X, _V, _W, _Q, _I, _MB, _MS, _F, _MASS = 0, 3, 6, 9, 13, 16, 19, 22, 25
_N_ROWS = 26


def _bodies(n_bodies):
    """The Abaqus top of `rbstudy bench`, B copies, as the loop's rows (_N_ROWS * B,)."""
    from rbstudy.numerics import state as S

    scene = abaqus_top_scene()
    y, p = scene.state_row(), scene.param_row()
    weight = p[S.MASS] * p[S.GRAVITY : S.GRAVITY + 3]
    columns = [
        (_X, y[S.POSITION : S.POSITION + 3]),
        (_V, y[S.VELOCITY : S.VELOCITY + 3]),
        (_W, y[S.OMEGA : S.OMEGA + 3]),
        (_Q, y[S.QUATERNION : S.QUATERNION + 4]),
        (_I, p[S.INERTIA : S.INERTIA + 3]),
        (_MB, p[S.MOMENT_BODY : S.MOMENT_BODY + 3]),
        (_MS, p[S.MOMENT_SPACE : S.MOMENT_SPACE + 3]),
        (_F, p[S.FORCE_SPACE : S.FORCE_SPACE + 3] + weight),
        (_MASS, p[S.MASS : S.MASS + 1]),
    ]
    rows = np.empty((_N_ROWS, n_bodies))
    for first, values in columns:
        rows[first : first + len(values)] = values[:, None]
    return rows.ravel()


def packed_ops(loop):
    """The packed double-precision arithmetic in the loop's assembly: {"zmm": n, "ymm": n}."""
    assembly = "\n".join(loop.inspect_asm().values())
    packed = re.findall(r"\bv(?:mul|add|sub|div|sqrt|fmadd\w*)pd\s[^\n]*?%(zmm|ymm)", assembly)
    return {register: packed.count(register) for register in ("zmm", "ymm")}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--body-steps", type=float, default=BODY_STEPS)
    parser.add_argument("--libm", action="store_true", help="libm's sine and cosine")
    args = parser.parse_args(argv)
    sine_cosine = _libm_sin_cos if args.libm else sin_cos_reduced
    print(f"SoA leapfrog, {'libm' if args.libm else 'own'} sine, one thread")
    print(
        f"peak: {FLOPS_PER_STEP} flops a body-step at {PEAK_FLOPS / 1e9:.0f} GFlop/s "
        f"= {PEAK_FLOPS / FLOPS_PER_STEP:.2e} body-steps/s (without FMA: half)"
    )
    for size in BATCH_SIZES:
        loop = _make_loop(sine_cosine, size)
        rows = _bodies(size)
        loop(rows, BENCH_DT, 1)  # compile
        steps = max(1, int(args.body_steps) // size)
        start = time.thread_time()
        loop(rows, BENCH_DT, steps)
        rate = steps * size / (time.thread_time() - start)
        print(
            f"B = {size:6d}: {rate:.3e} body-steps/s, {rate * FLOPS_PER_STEP / 1e9:5.1f} GFlop/s, "
            f"{rate / (PEAK_FLOPS / FLOPS_PER_STEP):.0%} of peak; packed ops {packed_ops(loop)}"
        )


if __name__ == "__main__":
    main()
