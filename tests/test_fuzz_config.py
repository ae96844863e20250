"""Fuzzing `rbstudy validate` over config text: random bytes, control characters, YAML's
punctuation and tags, deep nesting, huge scalars, long keys, aliases that multiply
(billion laughs), and ``--set`` overrides made of the same. Every outcome is exit 0, 1 or 2
with at most one line on stderr (never 70, a traceback), within bounded time and memory.

Hypothesis runs derandomized (its examples a function of the test alone), so CI meets the
same inputs on every run; the slow test draws more of them, `FUZZ_EXAMPLES` (or as many as
the environment's ``RBSTUDY_FUZZ_EXAMPLES`` asks: 3,000 passed in 389 s on 2 cores).
"""

import contextlib
import os
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_hostile import _run

# The slow test's examples: ~80 s on 2 cores, within CI's whole-suite run.
FUZZ_EXAMPLES = int(os.environ.get("RBSTUDY_FUZZ_EXAMPLES", 600))
# A valid config, to mutate: most mutations then reach validation instead of the parser.
GOOD = (
    "name: x\nscene: {body: {inertia: [1, 1, 2]}, initial: {angular_velocity: {body: [0.1, 0, 1]}}}\n"
    "run: {scheme: rk4, dt: 0.1}\noutput: {interval: 0.1}\n"
)
# What YAML and the config make of text: punctuation, tags, anchors, special values, keys.
TOKENS = (
    *"[]{}:,-?|>'\"#&*!%@`\n\t ",
    ": ",
    "- ",
    "\n  ",
    "&a ",
    "*a",
    "<<: *a",
    "? ",
    "---\n",
    "...\n",
    "%YAML 1.1\n",
    "%TAG ! tag:x,2000:\n",
    "!!binary ",
    "!!set ",
    "!!omap ",
    "!!python/object:os.system ",
    "!!float ",
    "!!bool ",
    "!!timestamp ",
    "!!map ",
    "!!seq ",
    "!!int ",
    "!!str ",
    "!x ",
    "1e400",
    "-.inf",
    ".nan",
    "0x1f",
    "0o17",
    "1_000",
    "0b101",
    "1:20:30",
    "~",
    "null",
    "true",
    "2001-12-14",
    "1e-3",
    "-0.0",
    "9" * 400,
    "name",
    "title",
    "scene",
    "run",
    "sweep",
    "output",
    "dt",
    "scheme",
    "zip",
    "linspace",
    "halving",
    "count",
    "all",
    "hht",
    "body",
    "inertia",
    "nodes",
    "loads",
    "duration",
    "interval",
    "variables",
    "spin",
)
KEYS = ("name", "title", "scene", "run", "sweep", "output", "run.dt", "run.scheme", "sweep.dt", "scene.body")
# A validate of a plain config takes ~30 ms here; the worst drawn input (a nesting of 5,000
# levels, a billion laughs) under a second. "Bounded" is far above both, far below a hang.
SECONDS_PER_EXAMPLE = 20
# What the examples together may add to the process's peak memory (a billion laughs expanded
# would take gigabytes).
PEAK_GROWTH_BYTES = 1024 * 2**20

soup = st.lists(st.sampled_from(TOKENS) | st.text(max_size=8), max_size=60).map("".join)
control = st.characters(max_codepoint=0x9F, categories=["Cc"]) | st.sampled_from(
    ["\ufeff", "\ufffe", "\uffff", "\u2028", "\x85", "\ud7ff", "\U0010ffff"]
)


@st.composite
def inserted(draw, what):
    """GOOD with ``what`` drawn and inserted at a drawn position."""
    at = draw(st.integers(0, len(GOOD)))
    return GOOD[:at] + draw(what) + GOOD[at:]


@st.composite
def nested(draw):
    depth = draw(st.integers(1, 5000))
    opening, closing = draw(st.sampled_from([("[", "]"), ("{a: ", "}"), ("- ", "")]))
    key = draw(st.sampled_from(KEYS[:6]))
    return f"{GOOD}{key}: {opening * depth}1{closing * depth}\n"


@st.composite
def huge(draw):
    size = draw(st.integers(100, 200_000))
    piece = draw(st.sampled_from(["9", "a", " ", "é", "\\x41", "1.5, "]))
    where = draw(st.sampled_from(["title: ", "name: ", "run: {dt: ", "sweep: {spin: [", "", "scene: {"]))
    closing = "}" * where.count("{") + "]" * where.count("[")
    if not where:  # a long key
        return f"{GOOD}{piece * size}: 1\n"
    return (
        f"{GOOD.replace('name: x', 'name: y') if where == 'name: ' else GOOD}{where}{piece * size}{closing}\n"
    )


@st.composite
def laughs(draw):
    """Aliases nine-fold ``levels`` deep, under a drawn key, or an alias of itself."""
    levels, fan = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    key = draw(st.sampled_from(KEYS[:6]))
    lines = f"{key}:\n  a0: &a0 x\n" + "".join(
        f"  a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * fan) + "]\n" for k in range(1, levels + 1)
    )
    return draw(st.sampled_from([GOOD + lines, GOOD + f"{key}: &s [*s]\n", lines + GOOD]))


texts = st.one_of(
    st.binary(max_size=400),
    inserted(control),
    inserted(soup),
    soup,
    nested(),
    huge(),
    laughs(),
)
overrides = st.lists(
    st.tuples(st.sampled_from(KEYS) | soup, soup | st.sampled_from(TOKENS) | control).map("=".join) | soup,
    max_size=3,
)


def check(tmp_path, text, sets):
    config = tmp_path / "fuzz.yaml"
    config.write_bytes(text if isinstance(text, bytes) else text.encode("utf-8", "surrogatepass"))
    started = time.perf_counter()
    code, err = _run(["validate", str(config), *(f"--set={s}" for s in sets)])
    seconds = time.perf_counter() - started
    assert code in (0, 1, 2), err[-3000:]
    assert "Traceback" not in err, err[-3000:]
    if code == 1:
        assert "\n" not in err and err.startswith("rbstudy: error: "), err[-3000:]
    if code == 2:  # argparse: the usage, then one line of error
        assert err.splitlines()[-1].startswith("rbstudy validate: error: "), err[-3000:]
    assert seconds < SECONDS_PER_EXAMPLE, (seconds, text[:300], sets)


@pytest.mark.parametrize(
    "text",
    # what the fuzzer found: PyYAML's constructors of explicit tags failed with IndexError,
    # KeyError, AttributeError and, in rbstudy's own mapping constructor, TypeError
    [
        f"{GOOD}title: {value}\n"
        for value in ('!!float ""', '!!int ""', "!!bool x", "!!timestamp x", "!!map [1]")
    ]
    + ["\x7f" + GOOD, f"{GOOD}{'9' * 100}: 1\n"],
)
def test_what_the_fuzzer_found_is_one_line(tmp_path, text):
    check(tmp_path, text, [])
    check(tmp_path, text, ["name=y"])  # an unknown key of a number, with an override: exit 70


def fuzz(examples):
    """The test of ``examples`` drawn inputs, reproducible."""

    @settings(
        max_examples=examples,
        derandomize=True,
        deadline=None,  # `check` bounds the time itself, with a margin for a loaded machine
        database=None,
        suppress_health_check=[
            HealthCheck.too_slow,
            HealthCheck.data_too_large,
            HealthCheck.large_base_example,
        ],
    )
    @given(text=texts, sets=overrides)
    def run(tmp_path, text, sets):
        check(tmp_path, text, sets)

    return run


def _peak_bytes():
    """The process's peak resident memory since it was last reset (`peak_growth_bounded`)."""
    with open("/proc/self/status") as status:
        (line,) = [line for line in status if line.startswith("VmHWM:")]
    return int(line.split()[1]) * 1024


@contextlib.contextmanager
def peak_growth_bounded():
    """Fail when the process's resident memory peaks at `PEAK_GROWTH_BYTES` or more above
    what it held before the block. The peak is reset first (Linux's clear_refs), else an
    earlier test's higher peak would hide the block's (tracemalloc, which would not, made the
    fast fuzzing 40 times slower)."""
    try:
        with open("/proc/self/clear_refs", "w") as refs:
            refs.write("5")  # VmHWM := the resident memory now
    except OSError:
        pytest.skip("no /proc/self/clear_refs to reset the process's peak memory")
    before = _peak_bytes()
    yield
    assert _peak_bytes() - before < PEAK_GROWTH_BYTES


@pytest.mark.slow
def test_validate_survives_fuzzed_config_text(tmp_path):
    with peak_growth_bounded():
        fuzz(150)(tmp_path)


@pytest.mark.slow
def test_validate_survives_many_more_fuzzed_config_texts(tmp_path):
    with peak_growth_bounded():
        fuzz(FUZZ_EXAMPLES)(tmp_path)
