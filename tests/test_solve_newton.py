"""The Newton solver: constraint by block elimination, fixed variables, saddle escape."""
import numpy as np
import scipy.sparse as sp

from xshells.solve import NewtonOptions, minimize


class Quadratic:
    """E = ½ xᵀ A x − bᵀ x + c Σ x⁴ (c = 0: a quadratic)."""

    def __init__(self, A, b, c=0.0, x0=None):
        self.A, self.b, self.c = A, b, c
        self.x = np.zeros(len(b)) if x0 is None else x0.copy()

    def get_vars(self):
        return self.x.copy()

    def set_vars(self, x):
        self.x = np.asarray(x, float).copy()

    def energy(self):
        return 0.5 * self.x @ self.A @ self.x - self.b @ self.x + self.c * np.sum(self.x**4)

    def gradient(self):
        return self.A @ self.x - self.b + 4 * self.c * self.x**3

    def hessian(self):
        return sp.csr_matrix(self.A + np.diag(12 * self.c * self.x**2))

    def mass_matrix(self):
        return sp.eye(len(self.b), format="csr")


def test_linear_constraint_matches_kkt_solution():
    rng = np.random.default_rng(0)
    n = 8
    Q = rng.standard_normal((n, n))
    A = Q @ Q.T + n * np.eye(n)
    b = rng.standard_normal(n)
    a = rng.standard_normal(n)
    target = 0.7
    P = Quadratic(A, b)
    report = minimize(P, constraint=(a, target), options=NewtonOptions(gradient_tolerance=1e-12))
    K = np.block([[A, a[:, None]], [a[None, :], np.zeros((1, 1))]])
    sol = np.linalg.solve(K, np.concatenate([b, [target]]))
    assert report.converged
    assert np.allclose(P.x, sol[:n], atol=1e-10)
    assert np.isclose(report.multiplier, sol[n], atol=1e-9)
    assert np.isclose(a @ P.x, target, atol=1e-12)


def test_a_constraint_holds_whatever_the_gradient_tolerance():
    """The residual of ``a·x = target`` is judged in its own unit: with a gradient tolerance far above the
    gradient (a stiffness the arithmetic cannot resolve swamps it), a start 0.35 off the target was
    once accepted as it was."""
    n = 4
    P = Quadratic(np.eye(n), np.zeros(n))
    a = np.full(n, 1.0 / n)
    report = minimize(P, constraint=(a, 0.35), options=NewtonOptions(gradient_tolerance=1e3))
    assert report.converged and report.iterations >= 1
    assert abs(a @ P.x - 0.35) < 1e-12


def test_fixed_variables_stay_put():
    A = np.diag([1.0, 2.0, 3.0])
    P = Quadratic(A, np.array([1.0, 1.0, 1.0]), x0=np.array([5.0, 0.0, 0.0]))
    minimize(P, fixed=[0], options=NewtonOptions(gradient_tolerance=1e-12))
    assert P.x[0] == 5.0 and np.allclose(P.x[1:], [0.5, 1 / 3])


class Quartic(Quadratic):
    """E = -x0² + x0⁴ + x1²: x = 0 is a saddle with zero gradient; minima at x0 = ±1/√2."""

    def energy(self):
        return -self.x[0] ** 2 + self.x[0] ** 4 + self.x[1] ** 2

    def gradient(self):
        return np.array([-2 * self.x[0] + 4 * self.x[0] ** 3, 2 * self.x[1]])

    def hessian(self):
        return sp.csr_matrix(np.diag([-2 + 12 * self.x[0] ** 2, 2.0]))


def test_escapes_an_exact_saddle():
    Q = Quartic(np.eye(2), np.zeros(2), x0=np.zeros(2))
    report = minimize(Q, options=NewtonOptions(gradient_tolerance=1e-10, saddle_step=1e-2))
    assert report.converged and report.saddle_escapes >= 1
    assert np.isclose(abs(Q.x[0]), 1 / np.sqrt(2), atol=1e-8)


def _semidefinite_at_rounding(lam_min):
    """A minimum of a quadratic whose Hessian has one eigenvalue ``lam_min`` (others 1…1e6)."""
    rng = np.random.default_rng(3)
    Q, _ = np.linalg.qr(rng.standard_normal((12, 12)))
    lam = np.concatenate([[lam_min], np.geomspace(1.0, 1e6, 11)])
    return Quadratic(Q @ np.diag(lam) @ Q.T, np.zeros(12))


def test_rounding_level_negative_curvature_is_a_minimum_not_a_saddle():
    # A semidefinite Hessian's zero eigenvalue rounds to ±ε·λmax; escaping it cost the
    # uniform grid's rest-length solve 92 iterations. Curvature −1e-15·λmax is accepted...
    P = _semidefinite_at_rounding(-1e-9)
    report = minimize(P, options=NewtonOptions(gradient_tolerance=1e-8))
    assert report.converged and report.iterations == 0 and report.saddle_escapes == 0
    assert "round-off" in report.message
    # ...curvature −1e-9·λmax is not: it is escaped
    P = _semidefinite_at_rounding(-1e-3)
    report = minimize(P, options=NewtonOptions(gradient_tolerance=1e-8, max_iterations=3))
    assert report.saddle_escapes >= 1


def _clustered_pencil(n=300, low=(1e-6, 1.3e-6, 2e-6), seed=0):
    """H = Q diag(λ) Qᵀ with a few tiny, clustered eigenvalues beside stiff ones (as a deployed linkage), M = I."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    lam = np.concatenate([low, np.geomspace(1.0, 1e4, n - len(low))])
    return sp.csr_matrix((q * lam) @ q.T), sp.identity(n, format="csr"), np.sort(lam)


def test_smallest_eigenvalues_of_a_clustered_spectrum():
    from xshells.solve import smallest_eigenvalues

    H, M, lam = _clustered_pencil()
    for dense_size in (0, 10_000):  # shift-invert, then the dense path of small pencils
        np.testing.assert_allclose(smallest_eigenvalues(H, M, k=2, dense_size=dense_size), lam[:2], rtol=0, atol=1e-11)  # backward error ~ eps·λmax
        np.testing.assert_allclose(smallest_eigenvalues(H, M, k=1, dense_size=dense_size), lam[:1], rtol=0, atol=1e-11)


def test_smallest_eigenvalues_of_an_indefinite_pencil():
    from xshells.solve import smallest_eigenvalues

    H, M, lam = _clustered_pencil(low=(-3e-6, 1e-6, 2e-6))
    for dense_size in (0, 10_000):
        np.testing.assert_allclose(smallest_eigenvalues(H, M, k=2, dense_size=dense_size), lam[:2], rtol=0, atol=1e-11)  # backward error ~ eps·λmax


def test_a_trial_point_outside_the_domain_shortens_the_step():
    # E = x − log x (minimum at 1): from x = 3 the Newton step lands at −3, where the
    # problem cannot be evaluated; the line search must back off, not raise
    from xshells.errors import InvalidState

    class LogBarrier(Quadratic):
        def set_vars(self, x):
            if x[0] <= 0:
                raise InvalidState(f"x = {x[0]} is not positive")
            self.x = np.asarray(x, float).copy()

        def energy(self):
            return self.x[0] - np.log(self.x[0])

        def gradient(self):
            return np.array([1.0 - 1.0 / self.x[0]])

        def hessian(self):
            return sp.csr_matrix([[1.0 / self.x[0] ** 2]])

    P = LogBarrier(np.eye(1), np.zeros(1), x0=np.array([3.0]))
    report = minimize(P, options=NewtonOptions(gradient_tolerance=1e-12))
    assert report.converged and abs(P.x[0] - 1.0) < 1e-10


class RoundedQuadratic(Quadratic):
    """A quadratic around a large constant whose energy is garbage below 1e-12 of its size,
    as a sum of many terms is: any move off the starting point reads as a small increase."""

    def energy(self):
        return 1e3 + super().energy() + 1e-3 * np.abs(self.x - self.start).max()


def test_a_newton_step_below_the_energys_round_off_is_judged_by_the_gradient():
    # The wiggly banana's deployment stalled so: full Newton steps predicted a decrease of
    # 1e-13 of the energy, measured an increase (round-off), and backtracked to nothing.
    A = np.diag([1.0, 2.0, 4.0])
    b = np.array([1.0, 1.0, 1.0])
    x_min = np.linalg.solve(A, b)
    P = RoundedQuadratic(A, b, x0=x_min + 1e-4)
    P.start = P.x.copy()
    report = minimize(P, options=NewtonOptions(gradient_tolerance=1e-10))
    assert report.converged, report.message
    assert np.allclose(P.x, x_min, atol=1e-12)
    # an energy decrease that is resolvable is still required: far from the minimum the
    # same noise does not count, and the step is judged by the energy
    P = RoundedQuadratic(A, b, x0=x_min + 1.0)
    P.start = P.x.copy()
    report = minimize(P, options=NewtonOptions(gradient_tolerance=1e-10))
    assert report.converged and np.allclose(P.x, x_min, atol=1e-12)


def test_the_shift_decays_by_the_option_after_an_indefinite_spell():
    # started at an indefinite point of the quartic: the shift then divides by shift_decay each step
    for decay in (2.0, 10.0):
        Q = Quartic(np.eye(2), np.zeros(2), x0=np.array([0.1, 1.0]))
        report = minimize(Q, options=NewtonOptions(gradient_tolerance=1e-10, shift_decay=decay))
        assert report.converged and np.isclose(abs(Q.x[0]), 1 / np.sqrt(2), atol=1e-8)
        s = np.array(report.sigma)
        first = int(np.flatnonzero(s > 0)[0])
        k = first + 1
        while k < len(s) and s[k] > 0 and s[k] < s[k - 1]:  # a decaying run (not a new spell)
            assert np.isclose(s[k - 1] / s[k], decay), (decay, s)
            k += 1
        assert k > first + 1, s  # it did decay at least once


def test_the_lower_triangle_is_used_only_where_the_class_of_hessian_defines_it():
    """A wrapper that adds to a linkage's Hessian and hands the rest to it (``__getattr__``), or a subclass
    that overrides ``hessian``, must be solved with its own Hessian, not the linkage's lower triangle."""
    from xshells.design.equilibrium import _Tethered
    from xshells.linkage.linkage import Linkage
    from xshells.solve.newton import uses_lower_triangle

    class Own:
        def hessian(self):
            return sp.eye(2)

        def hessian_lower(self):
            return sp.eye(2)

    class Delegating:
        def __init__(self, inner):
            self._inner = inner

        def __getattr__(self, name):
            return getattr(self._inner, name)

        def hessian(self):
            return 2 * self._inner.hessian()

    class Overriding(Own):
        def hessian(self):
            return 2 * sp.eye(2)

    assert uses_lower_triangle(Own())
    assert hasattr(Delegating(Own()), "hessian_lower") and not uses_lower_triangle(Delegating(Own()))
    assert not uses_lower_triangle(Overriding())
    assert "hessian_lower" in vars(Linkage) and "hessian" in vars(Linkage)
    assert "hessian" in vars(_Tethered) and "hessian_lower" not in vars(_Tethered)


class CountingQuadratic(Quadratic):
    """:class:`Quadratic` that counts its Hessians."""

    hessians = 0

    def hessian(self):
        self.hessians += 1
        return super().hessian()


def test_a_minimum_reached_by_quadratic_convergence_keeps_the_last_steps_factor():
    # positive definite everywhere (A ≻ 0, c > 0): Newton converges quadratically, and with the option the
    # last step's factor stands for the minimum's check: the same steps, one Hessian fewer
    rng = np.random.default_rng(5)
    Q = rng.standard_normal((6, 6))
    A, b = Q @ Q.T + 6 * np.eye(6), rng.standard_normal(6)
    runs = []
    for ratio in (0.0, 0.01):
        P = CountingQuadratic(A, b, c=0.5, x0=np.full(6, 1.5))
        report = minimize(P, options=NewtonOptions(gradient_tolerance=1e-10, minimum_from_last_step=ratio))
        assert report.converged
        runs.append((P.x.copy(), P.hessians, report))
    (x0, h0, r0), (x1, h1, r1) = runs
    assert np.array_equal(x0, x1) and r0.iterations == r1.iterations
    assert h1 == h0 - 1
    assert "the last Newton step's Hessian" in r1.message and "the last" not in r0.message


def test_the_option_still_escapes_a_saddle_and_checks_points_after_shifted_steps():
    opts = NewtonOptions(gradient_tolerance=1e-10, saddle_step=1e-2, minimum_from_last_step=0.01)
    Q = Quartic(np.eye(2), np.zeros(2), x0=np.zeros(2))  # at the saddle: no step taken yet, so it is checked
    report = minimize(Q, options=opts)
    assert report.converged and report.saddle_escapes >= 1
    assert np.isclose(abs(Q.x[0]), 1 / np.sqrt(2), atol=1e-8)
    # a start just off the saddle's line, inside the indefinite band: shifted steps, then a minimum
    Q = Quartic(np.eye(2), np.zeros(2), x0=np.array([0.1, 1.0]))
    report = minimize(Q, options=opts)
    assert report.converged and np.isclose(abs(Q.x[0]), 1 / np.sqrt(2), atol=1e-8)
    assert max(report.sigma) > 0
