"""Compile once per machine: a second process loads each scheme's entry point from numba's
cache and compiles nothing, and changed code never finds an old entry module."""

import json
import os
import subprocess
import sys
import textwrap

import pytest

from rbstudy.numerics.entry import _module_text

# Three schemes (one with an init kernel, one composed), both variants: with and without
# the time.
GET_READY = textwrap.dedent("""
    import json
    from numba.core import event

    compiled = []

    class Compiles(event.Listener):
        def on_start(self, ev):
            compiled.append(ev.data["dispatcher"].py_func.__qualname__)

        def on_end(self, ev):
            pass

    event.register("numba:compile", Compiles())
    from rbstudy.schemes import SCHEMES

    loaded = {}
    for name in ("rk4", "hht", "splitting"):
        for timed in (False, True):
            SCHEMES[name].ensure_compiled(timed=timed)
        stats = SCHEMES[name].run_bodies_inplace.dispatcher.stats
        loaded[name] = [sum(stats.cache_hits.values()), sum(stats.cache_misses.values())]
    print(json.dumps({"compiled": compiled, "loaded": loaded}))
""")


def get_ready(cache):
    done = subprocess.run(
        [sys.executable, "-c", GET_READY],
        capture_output=True,
        text=True,
        env={**os.environ, "NUMBA_CACHE_DIR": str(cache)},
        check=True,
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_a_second_process_loads_every_entry_point_without_compiling(tmp_path):
    first = get_ready(tmp_path)
    assert "run_bodies_inplace" in first["compiled"]  # an empty cache: it compiled
    assert first["loaded"] == {"rk4": [0, 2], "hht": [0, 2], "splitting": [0, 2]}
    second = get_ready(tmp_path)
    assert second["compiled"] == []
    assert second["loaded"] == {"rk4": [2, 0], "hht": [2, 0], "splitting": [2, 0]}


def test_changed_code_gets_another_entry_module(tmp_path):
    kernels = tmp_path / "my_kernels.py"
    source = (
        "from rbstudy.numerics.jit import jit\n\n@jit\ndef step(y, p, opt, t, h, work):\n    return 0, 0\n"
    )
    kernels.write_text(source)
    sys.path.insert(0, str(tmp_path))
    try:
        import my_kernels

        text, name = _module_text(my_kernels.step, my_kernels.step, 0)
        assert "from my_kernels import step as step" in text
        wrapped, other = _module_text(my_kernels.step, my_kernels.step, 0, (my_kernels.step, 3))
        assert "return wrapper(stage, 3, y, p, opt, t, h, work)" in wrapped and other != name
        # the wrapper's option at another slot of the row: another module
        assert _module_text(my_kernels.step, my_kernels.step, 0, (my_kernels.step, 0))[1] != other
        assert _module_text(my_kernels.step, my_kernels.step, 3)[1] != name  # other work size
        kernels.write_text(source + "# an edit\n")
        assert _module_text(my_kernels.step, my_kernels.step, 0)[1] != name  # edited kernels
    finally:
        sys.path.remove(str(tmp_path))
        sys.modules.pop("my_kernels", None)


# A sweep's first run on a machine: the schemes the cache lacks are compiled in child
# processes, and this process then loads them (`rbstudy.schemes.get_ready`).
IN_CHILDREN = textwrap.dedent("""
    import json
    from rbstudy.schemes import SCHEMES, get_ready

    variants = [("leapfrog", False), ("rk4", False), ("rk4", True)]
    before = [SCHEMES[name].is_cached(timed) for name, timed in variants]
    seen = []
    wanted = [(SCHEMES[name], timed) for name, timed in variants]
    in_children = get_ready(wanted, processes=2, watch=seen.append)
    stats = {name: SCHEMES[name].run_bodies_inplace.dispatcher.stats for name in ("leapfrog", "rk4")}
    print(json.dumps({"before": before, "in_children": in_children,
                      "hits": {name: sum(s.cache_hits.values()) for name, s in stats.items()},
                      "misses": {name: sum(s.cache_misses.values()) for name, s in stats.items()},
                      "after": [SCHEMES[name].is_cached(timed) for name, timed in variants],
                      "took": dict(seen[-1].took) if seen else {},
                      "names": list(seen[0].names) if seen else []}))
""")


@pytest.mark.slow
def test_a_cold_cache_is_filled_by_child_processes_and_loaded_here(tmp_path):
    done = subprocess.run(
        [sys.executable, "-c", IN_CHILDREN],
        capture_output=True,
        text=True,
        env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)},
        check=True,
    )
    ready = json.loads(done.stdout.strip().splitlines()[-1])
    assert ready["before"] == [False, False, False]
    assert ready["in_children"] == 3
    # this process compiled nothing: it loaded what the children wrote
    assert ready["misses"] == {"leapfrog": 0, "rk4": 0}
    assert ready["hits"] == {"leapfrog": 1, "rk4": 2}
    assert ready["after"] == [True, True, True]
    # the seconds each took, which the next compile's time left is told by
    assert ready["names"] == ["leapfrog", "rk4"]
    assert sorted(ready["took"]) == ["leapfrog", "rk4"] and all(0 < s < 600 for s in ready["took"].values())
    again = subprocess.run(
        [sys.executable, "-c", IN_CHILDREN],
        capture_output=True,
        text=True,
        env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)},
        check=True,
    )
    assert json.loads(again.stdout.strip().splitlines()[-1])["in_children"] == 0  # all cached
