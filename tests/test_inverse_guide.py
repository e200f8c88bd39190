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


def _fake_optimize(monkeypatch, seen):
    """``optimize`` that runs ``max_iterations`` iterations, noting in ``seen`` the iterations it reports."""
    import types

    import xshells.design.optimize as opt

    def optimize(problem, options, callback=None):
        history = []
        for it in range(options.max_iterations + 1):
            rec = types.SimpleNamespace(iteration=it, J=1.0 / (it + 1))
            history.append(rec)
            seen.append(it)
            if callback is not None and callback(rec):
                return opt.OptimizeResult(q=None, rest_lengths=None, iterations=it, history=history,
                                          message="stopped by request", stopped=True)
        return opt.OptimizeResult(q=None, rest_lengths=None, iterations=options.max_iterations, history=history,
                                  message="reached the iteration limit")

    monkeypatch.setattr(opt, "optimize", optimize)


class _NoHold:
    def apply(self, problem, mu):
        pass


@pytest.mark.parametrize("every, expected", [(10, [1.0, (0.0, 10), (0.0, 20), (0.0, 25)]), (0, [1.0, (0.0, 25)])])
def test_the_last_stage_design_is_checked_every_few_iterations(monkeypatch, every, expected):
    from xshells.inverse.guide import GuideOptions, guided_optimization

    seen, checked = [], []
    _fake_optimize(monkeypatch, seen)

    def after_stage(mu):
        checked.append(mu if mu else (mu, seen[-1]))

    opts = GuideOptions(schedule=(1.0, 0.0), iterations=3, final_iterations=25, checkpoint_every=every, polish=0.0)
    stages = guided_optimization(_Problem(), _NoHold(), opts, after_stage=after_stage)
    assert [s.load_factor for s in stages] == [1.0, 0.0]
    assert checked == expected  # in the last stage at 10 and 20 (not again at the limit), and once it ends


def test_a_stop_request_skips_the_checkpoint(monkeypatch):
    from xshells.inverse.guide import GuideOptions, guided_optimization

    seen, checked = [], []
    _fake_optimize(monkeypatch, seen)
    opts = GuideOptions(schedule=(0.0,), final_iterations=25, checkpoint_every=10)
    stages = guided_optimization(_Problem(), _NoHold(), opts, callback=lambda mu, rec: rec.iteration == 10,
                                 after_stage=lambda mu: checked.append(seen[-1]))
    assert stages[0].message == "stopped by request" and checked == [10]  # once, after the stage, not twice
    assert len(stages) == 1  # and no polish after a stop


def test_the_polish_goes_on_with_twice_the_fit_weight_and_is_checked_like_the_last_stage(monkeypatch):
    from xshells.inverse.guide import GuideOptions, guided_optimization

    seen, checked, weights = [], [], []
    _fake_optimize(monkeypatch, seen)
    from xshells.design.objective import DesignWeights

    problem = _Problem()
    problem.w = DesignWeights(beta=1000.0)

    def after_stage(mu):
        checked.append((mu, seen[-1]))
        weights.append(problem.w.beta)

    opts = GuideOptions(schedule=(1.0, 0.0), iterations=3, final_iterations=25, checkpoint_every=10)
    stages = guided_optimization(problem, _NoHold(), opts, after_stage=after_stage)
    assert [s.load_factor for s in stages] == [1.0, 0.0, 0.0] and stages[2].message.startswith("polish, beta x2")
    assert stages[2].iterations == 20 and problem._cache == {}  # the derivatives of the old weight are gone
    # the last stage at 10, 20 and its end; the polish at 10 and its end (20), with the weight doubled
    assert checked == [(1.0, 3), (0.0, 10), (0.0, 20), (0.0, 25), (0.0, 10), (0.0, 20)]
    assert weights == [1000.0] * 4 + [2000.0] * 2
