"""Letting the holding load go: a release that fails steps back, even when stepping back stalls."""
import pytest

import xshells.linkage.state as state
from xshells.inverse.guide import _release


class _Deployed:
    def __init__(self):
        self.L = object()
        self.factorized = 0

    def factorize(self):
        self.factorized += 1


class _Problem:
    def __init__(self):
        self.deployed = _Deployed()
        self._cache = {"stale": True}


class _Hold:
    """Re-solves fail below μ = 0.5; the first step back to a μ already held stalls once."""

    def __init__(self):
        self.calls = []

    def apply(self, problem, mu):
        self.calls.append(mu)
        if mu < 0.5:
            raise ArithmeticError("equilibrium did not converge")
        if len(self.calls) == 2:
            raise ArithmeticError("re-solve stalled at |g| = 5.7e-4")


@pytest.fixture(autouse=True)
def _no_linkage(monkeypatch):
    monkeypatch.setattr(state, "snapshot", lambda L: {"L": L})
    monkeypatch.setattr(state, "restore", lambda L, snap: None)


def test_a_stalled_step_back_keeps_the_saved_state_and_goes_on_halving():
    problem, hold = _Problem(), _Hold()
    reached = _release(problem, hold, 1.0, 0.0)
    assert hold.calls[:2] == [0.0, 1.0]  # tried 0, stepped back to 1 (which stalled)
    assert 0.5 <= reached < 1.0  # and then halved its way down as far as re-solves go
    assert problem.deployed.factorized == 1 and problem._cache == {}


def test_a_release_that_works_at_once_touches_nothing_else():
    problem, hold = _Problem(), _Hold()
    assert _release(problem, hold, 1.0, 0.6) == 0.6
    assert hold.calls == [0.6] and problem.deployed.factorized == 0
