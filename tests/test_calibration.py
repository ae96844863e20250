"""The cost of a step as calibrated: a figure measured while other programs kept the machine
busy is never passed off as a quiet one (the recommendation rests on these figures, and a busy
core reordered it), and it is measured again by the next process that calibrates."""

import json
import os
import subprocess
import sys
import time

import pytest

from rbstudy.pipeline import calibration as C
from rbstudy.pipeline.calibration import StepCost

BUSY_LOOP = "import time\nend = time.time() + 30\nwhile time.time() < end: pass\n"


def _busy(cores):
    """Programs that each keep one core busy for up to 30 s (killed by the caller)."""
    return [subprocess.Popen([sys.executable, "-c", BUSY_LOOP]) for _ in range(cores)]


@pytest.mark.skipif(C.load_mark()[0] is None, reason="the system does not count its cores' busy time")
def test_other_programs_keeping_a_core_busy_are_counted():
    (program,) = _busy(1)
    try:
        time.sleep(0.3)  # started and spinning
        mark = C.load_mark()
        time.sleep(0.5)
        busy = C.others_cores(mark)
    finally:
        program.kill()
    # one core spinning, whatever else runs; this process, asleep, is not counted
    assert busy >= 0.8


def _rounds(monkeypatch, rounds):
    """`_rates_in_rounds` over planted rounds: each a (rates by name, quiet) pair."""
    planted = iter(rounds)
    monkeypatch.setattr(C, "_quiet_round", lambda run_round: next(planted))
    return C._rates_in_rounds({"a": None, "b": None})


def test_a_figure_is_the_least_of_the_quiet_rounds_and_a_busy_round_does_not_count(monkeypatch):
    quiet = [({"a": 1.0 + 0.01 * k, "b": 2.0}, True) for k in range(C.REPEATS)]
    # a busy round, cheaper for "a" than any quiet one (as a busy core can make a scheme seem)
    costs = _rounds(monkeypatch, [({"a": 0.5, "b": 9.0}, False), *quiet])
    assert costs["a"] == StepCost(1.0, C.BETWEEN_CALIBRATIONS, False)
    assert costs["b"] == StepCost(2.0, C.BETWEEN_CALIBRATIONS, False)
    spread = [({"a": 1.0 + k, "b": 2.0}, True) for k in range(C.REPEATS)]
    assert _rounds(monkeypatch, spread)["a"].uncertainty == pytest.approx((C.REPEATS - 1) / 2)


def test_a_machine_busy_throughout_gives_figures_said_to_be_measured_under_load(monkeypatch):
    busy = [({"a": 1.0 + 0.1 * k, "b": 2.0}, False) for k in range(C.MAX_ROUNDS)]
    costs = _rounds(monkeypatch, busy)
    assert costs["a"] == StepCost(1.0, C.BUSY_UNCERTAINTY, True)
    # quiet rounds between busy ones count, as many as are needed
    every_other = [({"a": 1.0, "b": 2.0}, k % 2 == 0) for k in range(2 * C.REPEATS)]
    assert _rounds(monkeypatch, every_other)["a"] == StepCost(1.0, C.BETWEEN_CALIBRATIONS, False)
    # too few quiet rounds is a busy machine: every round counts, none is passed as quiet
    few = [({"a": 1.0, "b": 2.0}, k < C.REPEATS - 1) for k in range(C.MAX_ROUNDS)]
    assert _rounds(monkeypatch, few)["a"] == StepCost(1.0, C.BUSY_UNCERTAINTY, True)


def test_a_figure_measured_under_load_is_measured_again_by_the_next_process_only(tmp_path, monkeypatch):
    monkeypatch.setattr(C, "calibration_path", lambda: str(tmp_path / "calibration.json"))
    monkeypatch.setattr(C, "_measured_here", set())
    monkeypatch.setattr(C, "_said_busy", set())
    measured = []

    def measure(schemes):
        measured.append([scheme.name for scheme in schemes])
        return {scheme.name: (StepCost(1e-7, C.BUSY_UNCERTAINTY, True), 0.1) for scheme in schemes}

    monkeypatch.setattr(C, "measure", measure)

    class Said:
        def __init__(self):
            self.lines = []

        def phase(self, what):
            pass

        def say(self, text):
            self.lines.append(text)

    said = Said()
    assert C.calibrate({"rk4"})["rk4"].loaded  # the forecast: measured, nothing to say it on
    C.calibrate({"rk4"}, said)  # the sweep says what the forecast measured
    (line,) = said.lines
    assert " ".join(line.split()) == (
        "other programs kept this machine busy while the costs of rk4 were measured: they are "
        "uncertain to 50%, and the next sweep measures them again"
    )
    assert max(len(part) for part in line.splitlines()) <= 100  # a terminal 100 columns wide
    with open(tmp_path / "calibration.json", encoding="utf-8") as file:
        stored = json.load(file)[C.machine_key()]
    assert [figure["loaded"] for figure in stored.values()] == [True]
    C.calibrate({"rk4"}, said)  # the step search, then the sweep, of one command: said once
    assert measured == [["rk4"]]
    assert len(said.lines) == 1
    monkeypatch.setattr(C, "_measured_here", set())  # the next process
    C.calibrate({"rk4"})
    assert measured == [["rk4"], ["rk4"]]
    # a quiet figure stays, in this process and the next
    monkeypatch.setattr(C, "measure", lambda schemes: {s.name: (StepCost(1e-7, 0.1), 0.1) for s in schemes})
    monkeypatch.setattr(C, "_measured_here", set())
    C.calibrate({"rk4"})
    monkeypatch.setattr(C, "_measured_here", set())
    monkeypatch.setattr(C, "measure", lambda schemes: pytest.fail("a quiet figure was measured again"))
    assert C.calibrate({"rk4"})["rk4"] == StepCost(1e-7, 0.1, False)


@pytest.mark.slow
@pytest.mark.skipif(C.load_mark()[0] is None, reason="the system does not count its cores' busy time")
def test_a_calibration_on_a_machine_kept_busy_says_so(tmp_path, monkeypatch):
    """The whole measurement, each core kept busy by another program: every figure comes out
    as measured under load, with the wide uncertainty that makes the findings count the
    schemes' costs as ties."""
    from rbstudy.schemes import get_scheme

    schemes = [get_scheme(name) for name in ("euler", "rk4")]
    for scheme in schemes:
        scheme.ensure_compiled()
    programs = _busy(os.cpu_count() or 1)
    try:
        time.sleep(0.3)
        costs = C.measure(schemes)
    finally:
        for program in programs:
            program.kill()
    for cost, _ in costs.values():
        assert cost.loaded and cost.uncertainty == C.BUSY_UNCERTAINTY
        assert 0 < cost.seconds < 1e-5
