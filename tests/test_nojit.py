"""With NUMBA_DISABLE_JIT=1 the kernels run as plain Python, so coverage sees them, and they
must give the compiled numbers. Run in a subprocess: the flag is read when
numba is imported."""

import os
import subprocess
import sys

import pytest

SCRIPT = r"""
import json, math
from rbstudy.inputs.scenes import scene_from_mapping
from rbstudy.physics.scenes import Body, Scene
from rbstudy.physics.simulate import simulate
from rbstudy.schemes import BUILTIN, SCHEMES
scene = Scene(body=Body(mass=2.0, inertia=(1.0, 2.0, 3.0)), quaternion=(0.1, 0.2, 0.3, 0.927),
              omega_body=(0.6, 1.5, 0.9), velocity=(1.0, 0.0, 0.0), duration=0.2)
# and one under loads tabulated in time, at a node and at the centre
timed = scene_from_mapping({"body": {"inertia": [1.0, 2.0, 3.0]},
                            "initial": {"angular_velocity": {"body": [0.6, 1.5, 0.9]}},
                            "nodes": {"a": [0.5, 0.2, 0.1]}, "duration": 0.2,
                            "loads": {"moment_body": {"table": [[0, 0, 0, 0], [0.1, 1, 0, 2]]},
                                      "nodes": {"a": {"force_space": {"table": [
                                          [0.05, 0, 0, 0], [0.3, 0, 3, 0]]}}}}})
out = {}
for name, scheme in BUILTIN.items():
    if not scheme.adaptive:
        for label, body in (("", scene), (" timed", timed)):
            run = simulate([body], name, 0.02, 0.1)
            out[name + label] = run.quaternion[0, -1].tolist() + run.omega_body[0, -1].tolist()
# the exact free body, in each circulation and next to the separatrix
from rbstudy.numerics.free_flow import free_body, free_flow
from rbstudy.numerics.free_increment import free_increment
for omega in ((0.6, 1.5, 0.9), (2.0, 0.3, 0.1), (0.8, 0.3, 0.4618802153517006)):
    q, w = free_flow((1.0, 2.0, 3.0), (0.1, 0.2, 0.3, 0.927), omega, 7.5)
    out["free_flow %s" % (omega,)] = list(q) + list(w)
    dq, dw = free_increment(free_body((1.0, 2.0, 3.0), omega), (0.1, 0.2, 0.3, 0.927), 0.3)
    out["free_increment %s" % (omega,)] = list(dq) + list(dw)
print(json.dumps(out))
"""


def run(disable):
    env = dict(os.environ, NUMBA_DISABLE_JIT="1" if disable else "0")
    result = subprocess.run(
        [sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, check=True, timeout=600
    )
    import json

    return json.loads(result.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_interpreted_kernels_match_compiled():
    import numpy as np

    compiled, interpreted = run(False), run(True)
    assert compiled.keys() == interpreted.keys()
    for name in compiled:
        assert np.allclose(compiled[name], interpreted[name], rtol=1e-13, atol=1e-15), name
