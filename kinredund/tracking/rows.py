"""General inequality rows in the constrained stepper: c_i(theta) >= 0 with gradient rows G_i (issue 27).

Along the path the joints follow theta*(t) = argmin z s.t. g(theta) = x(t), the joint bounds and c_i(theta) >= 0.
With the active rows A the first-order conditions are

    grad z + J^T lambda - G_A^T nu = 0,   g(theta) = x(t),   c_A(theta) = 0,   nu >= 0,

so between switching times the active rows are further equations of the thesis's system: with w = -nu
appended to lambda, G_A under J, c_A under the task residual r, zeros under xdot (the obstacles do not
move) and sum_i w_i Hess c_i added to M (Eqs. 4.23, 4.24 extended),

    R = [[M + sum_i w_i Hess c_i, J^T, G_A^T], [J, 0, 0], [G_A, 0, 0]],

and the predictor and the Newton corrector of :mod:`kinredund.tracking.predictor_corrector` run on it
unchanged. :class:`RowPoint` is that extended evaluation; the stepper's ``lam`` then holds [lambda; w]
(``task_lam`` the task's part). A row switches on when c_i reaches zero within a step and off when
nu_i reaches zero, each located as the bounds' are (:mod:`kinredund.tracking.limited`).

Where a switch leaves the direction undetermined (a rate and a multiplier both near zero after it), the
rate QP with the weakly active row as an inequality decides (:func:`row_rate_qp`, through qpsolvers).
Between switching times the rates need no QP (the active set is known: one LU of the extended R), so the
QP is off the hot path: it is solved afresh through ``qpsolvers.solve_problem`` at such a switch only,
without a solver object kept across steps.
"""

from __future__ import annotations

import numpy as np

from kinredund.errors import OptionError, TrackingError, check_choice
from kinredund.tracking.constraints.base import Constraint
from kinredund.tracking.linalg import convexified
from kinredund.tracking.point import Point

#: the QP solvers :func:`row_rate_qp` takes through qpsolvers (proxsuite's dense solver the default)
QP_SOLVERS = ("proxqp", "daqp")


class RowPoint(Point):
    """A :class:`~kinredund.tracking.point.Point` with the active rows appended to the task's.

    Attributes (besides Point's, which are the extended ones): ``base``, the task's own evaluation.
    """

    __slots__ = ("base", "_curvature", "_m")

    def __init__(self, base: Point, G: np.ndarray, c: np.ndarray, curvature):
        super().__init__(base.q, base.t, base.Q, base.p, base.sample, base.terms, base.grad, base.hess, base.dgrad_dt)
        self.base, self._curvature, self._m = base, curvature, len(base.r)
        self.r = np.concatenate([base.r, c])
        self.J = np.vstack([base.J, G])
        self.xdot = np.concatenate([base.xdot, np.zeros(len(c))])

    def system(self, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(M + sum_i w_i Hess c_i, top) for lam = [lambda; w] (the rows' share of Eq. 4.23; top is the task's)."""
        m = self._m
        M, top = self.base.system(lam[:m])
        return M + self._curvature(lam[m:]), top


def row_point(pt: Point, constraints: list[Constraint], rows: tuple) -> RowPoint:
    """The evaluation ``pt`` extended by the active ``rows`` ((constraint number, row) pairs) at pt.q."""
    q = pt.q
    G = np.empty((len(rows), len(q)))
    c = np.empty(len(rows))
    cache: dict[int, tuple] = {}
    for i, (ci, ri) in enumerate(rows):
        if ci not in cache:
            cache[ci] = constraints[ci].rows_at(q)
        c[i], G[i] = cache[ci][0][ri], cache[ci][1][ri]

    def curvature(w: np.ndarray) -> np.ndarray:
        H = np.zeros((len(q), len(q)))
        for ci in cache:
            mine = [i for i, (cj, _) in enumerate(rows) if cj == ci]
            H += constraints[ci].curvature(q, w[mine], np.array([rows[i][1] for i in mine]))
        return H

    return RowPoint(pt, G, c, curvature)


def row_rate_qp(M: np.ndarray, top: np.ndarray, A: np.ndarray, b: np.ndarray, g: np.ndarray,
                solver: str = "proxqp") -> tuple[float, float] | None:
    """The rate QP at a weakly active row: min 1/2 v^T M v - top^T v s.t. A v = b, g^T v >= 0.

    Eq. (4.24)'s rates as a QP (Theorem 2, Eq. 4.28) over the free joints, with the task and the other
    active rows as equalities (``A``, ``b``) and the row's rate as the inequality. M is replaced by sym(M)
    + rho A^T A where it is not positive definite (the same minimiser on A v = b). Solved through
    qpsolvers (``proxqp`` or ``daqp``) to 1e-12. Returns (g^T v, the row's multiplier >= 0), or None: no
    solution, also without calling the solver where no rho up to 1e12 makes that matrix positive definite (M is
    then not positive definite on the null space of A, Finsler's lemma: the QP is unbounded along a direction of
    negative curvature, which the inequality cannot bound in both senses; proxqp iterated to its limit on
    one such QP of a random obstacle task before it gave up, and daqp returned a point).
    """
    import qpsolvers

    H = convexified(M, A)
    if H is None:
        return None
    problem = qpsolvers.Problem(H, -top, G=-g[None, :], h=np.zeros(1), A=A, b=b)
    options = {"eps_abs": 1e-12, "eps_rel": 0.0} if solver == "proxqp" else {}
    sol = qpsolvers.solve_problem(problem, solver=solver, **options)
    if not sol.found or sol.x is None:
        return None
    return float(g @ sol.x), float(sol.z[0])


#: an inactive row below -ROW_TOL [m] after a step is a switch (rounding below that is not)
ROW_TOL = 1e-13
#: two rows of one constraint within TWIN_VALUE [m] and TWIN_RATE max(1, |G|) [m/rad] of each other at q are one contact
TWIN_VALUE, TWIN_RATE = 1e-9, 1e-4


class GeneralRows:
    """The general rows' part of :class:`~kinredund.tracking.limited.LimitedPredictorCorrector` (a mixin).

    ``general``: the constraints of general rows; ``rows`` (state): the active rows' numbers among all
    their rows (``row_pairs``: (constraint, row) per number); ``lam`` = [lambda; w], w = -nu.
    """

    #: the general rows' compiled check of a step (a :class:`~kinredund.tracking.constraints.base.RowCheck`: the
    #: compiled backend's, :mod:`kinredund.tracking.compiled`), or None: every step is searched (:meth:`_rows_cleared`)
    step_check = None

    def _init_rows(self, constraints, q0: np.ndarray, qp_solver: str) -> None:
        check_choice("QP solver of the rate QP", qp_solver, QP_SOLVERS)
        self.qp_solver = qp_solver
        self.general = list(constraints)
        self._smallest = (None, 0.0)  # (q, the smallest c there) from a compiled check (:meth:`keep_smallest`)
        if not self.general:  # no rows: none active, and no values to keep
            self.row_pairs, self.rows = [], ()
            self._vals_key, self._vals, self._prev_key, self._prev_vals = q0, np.zeros(0), None, None
            return
        import qpsolvers

        if qp_solver not in qpsolvers.available_solvers:
            raise OptionError(f"the QP solver {qp_solver!r} is not installed (qpsolvers has "
                              f"{', '.join(qpsolvers.available_solvers)}; e.g. pip install daqp)")
        for c in self.general:
            if not isinstance(c, Constraint) or c.bounds() is not None:
                raise OptionError(f"constraints must be general-row Constraints (e.g. kr.SphereClearance); joint "
                                  f"bounds go in limits=; got {c!r}")
        self.row_pairs = [(ci, ri) for ci, c in enumerate(self.general) for ri in range(c.size)]
        self._vals_key, self._vals = None, None
        self._prev_key, self._prev_vals = None, None  # and the values before them (:meth:`_row_values`)
        values = self._row_values(q0)
        bad = np.flatnonzero(values < -1e-10)
        if bad.size:
            names = self.row_names(tuple(bad))
            hints = "".join(c.start_hint([ri for cj, ri in (self.row_pairs[f] for f in bad) if cj == ci])
                            for ci, c in enumerate(self.general))
            raise TrackingError(
                "the starting configuration violates " + "; ".join(f"{nm} by {-values[f]:.3g} m"
                                                                   for nm, f in zip(names, bad, strict=True)) + hints,
                cause=self.general[self.row_pairs[bad[0]][0]].cause, t=0.0, q=None,
                watched={"constraint_values": values.tolist(), "constraints": names})
        self.rows = tuple(int(f) for f in np.flatnonzero(values <= 1e-10))  # on the constraint: active

    @property
    def task_lam(self) -> np.ndarray:
        """The task's multipliers lambda (``lam`` without the active rows' w)."""
        return self.lam[: self._m]

    def evaluate(self, q: np.ndarray, t: float, need_dJ: bool = True) -> Point:
        pt = self.ev.point(q, t, need_dJ=need_dJ)
        if not self.rows:
            return pt
        return row_point(pt, self.general, [self.row_pairs[f] for f in self.rows])

    def _row_values(self, q: np.ndarray) -> np.ndarray:
        """c of every general row at q [m] (the last two kept, by the q array: the steppers never change one in
        place)."""
        if self._vals_key is not q:
            if self._prev_key is q:  # the one before (a step's start, after its end was asked for)
                return self._prev_vals
            self._prev_key, self._prev_vals = self._vals_key, self._vals
            self._vals, self._vals_key = self._values_at(q), q
        return self._vals

    def _values_at(self, q: np.ndarray) -> np.ndarray:
        """c of every general row at q [m], afresh."""
        vals = [c.values(q) for c in self.general]
        return np.concatenate(vals) if vals else np.zeros(0)

    def _segment_bounds(self, q0, q1, c0, c1, move) -> np.ndarray:
        """Lower bounds on every general row along the step from q0 to q1 (-inf where a constraint knows none:
        :meth:`Constraint.segment_lower_bounds`)."""
        if len(self.general) == 1:  # the common case (one Scene), without the slices and the concatenation
            bound = self.general[0].segment_lower_bounds(q0, q1, c0, c1, move)
            return np.full(len(c0), -np.inf) if bound is None else bound
        out, k = [], 0
        for c in self.general:
            part = slice(k, k + c.size)
            bound = c.segment_lower_bounds(q0, q1, c0[part], c1[part], move)
            out.append(np.full(c.size, -np.inf) if bound is None else bound)
            k += c.size
        return np.concatenate(out) if out else np.zeros(0)

    def row_names(self, rows) -> list[str]:
        names = [c.names() for c in self.general]
        return [names[ci][ri] for ci, ri in (self.row_pairs[f] for f in rows)]

    def _event_name(self, key: int, kind: str) -> str:
        """The name of an event's joint (a bound's) or row (``row_reach``/``row_release``)."""
        return self.row_names((key,))[0] if kind.startswith("row") else f"joint {self.joint_names[key]}"

    def _cause(self) -> str:
        return self.general[self.row_pairs[self.rows[0]][0]].cause if self.rows else "limits_infeasible"

    def _rows_cleared(self, snap) -> bool:
        """Does the rows' compiled check (:attr:`step_check`) rule out a row's switch within the step from ``snap`` to
        now (no inactive row below -ROW_TOL at its end, none able to dip below it inside: the tests of
        :meth:`_row_events`' reach and ``SwitchLocation._row_dips``, by the constraints' ``segment_lower_bounds``, the
        rows held left out)? False where there is none or it cannot tell (no rate at the start, the rows held
        changed within the step)."""
        check, h = self.step_check, self.t - snap.t
        if check is None or snap.qdot is None or not h > 0.0 or snap.rows != self.rows:
            return False
        return check.clear(snap.q, self.q, snap.qdot, self.qdot, h, self.rows)

    def _row_events(self, reach: bool = True) -> list[tuple[int, str]]:
        """(row, ``row_reach``): an inactive row below zero; (row, ``row_release``): an active row's nu < 0.
        ``reach`` False: the releases only (a check ruled the reaches out: :meth:`_rows_cleared`)."""
        if not self.row_pairs:
            return []
        out = []
        if reach:
            values = self._row_values(self.q)
            if not values.min() < -ROW_TOL and not self.rows:  # the common case: one reduction
                return []
            out = [(int(f), "row_reach") for f in np.flatnonzero(values < -ROW_TOL) if int(f) not in self.rows]
        if self.rows:
            scale = max(1.0, float(np.abs(self.pt.grad).max()))
            nu = -self.lam[self._m:]
            out += [(f, "row_release") for f, v in zip(self.rows, nu, strict=True) if v < -1e-12 * scale]
        return out

    def _row_watch(self, key: int, kind: str) -> float:
        """The zero of the switch: the row's value c (reach) or its multiplier nu (release), >= 0 before. A row
        below zero that does not stand for itself there (:meth:`_own`: it equals a row that does, which is that
        event) counts as 2 ROW_TOL: its own reach is where it goes under that row (the switches' search looks for
        it inside the step, ``SwitchLocation._crossing`` in :mod:`kinredund.tracking.switches`)."""
        if kind == "row_reach":
            c = float(self._row_values(self.q)[key])
            return c if c >= 0.0 or self._own(key) else 2.0 * ROW_TOL
        return float(-self.lam[self._m + self.rows.index(key)])

    def _apply_row_switch(self, key: int, kind: str) -> float:
        if kind == "row_reach":
            self._representatives()
            twin = self._twin(key)
            if twin is not None:  # the same contact as an active row: it takes that row's place and multiplier
                pos = self.rows.index(twin)
                self.rows = self.rows[:pos] + (key,) + self.rows[pos + 1:]
                self._handed_over = key  # (its direction is its twin's: _check_row_direction)
            else:
                self.rows, self.lam = self.rows + (key,), np.append(self.lam, 0.0)
        else:
            pos = self.rows.index(key)
            self.rows, self.lam = self.rows[:pos] + self.rows[pos + 1:], np.delete(self.lam, self._m + pos)
        self._update_sel()
        return 0.0

    def _twin(self, key: int) -> int | None:
        """An active row of ``key``'s constraint equal to it at q to first order (values within :data:`TWIN_VALUE`,
        gradients within :data:`TWIN_RATE` max(1, |G|) [m/rad]: absolute below 1 m/rad): one contact seen as two
        of the constraint's pieces (a vertex's and the pair's own distance, two vertices' against each other).
        Holding both would put one gradient twice into the system; None where there is none."""
        ci, ri = self.row_pairs[key]
        mates = [f for f in self.rows if self.row_pairs[f][0] == ci]
        if not mates:
            return None
        c, G = self.general[ci].rows_at(self.q)
        for f in mates:
            rf = self.row_pairs[f][1]
            scale = max(1.0, float(np.linalg.norm(G[rf])))
            if abs(c[rf] - c[ri]) <= TWIN_VALUE and np.linalg.norm(G[rf] - G[ri]) <= TWIN_RATE * scale:
                return f
        return None

    def _own(self, key: int) -> bool:
        """Does row ``key`` stand for itself at q (:meth:`~Constraint.representative`)? One that does not (the pair's
        own distance realised at a vertex) reaches zero with the row that stands for it (:meth:`_row_watch`)."""
        ci, ri = self.row_pairs[key]
        return self.general[ci].representative(self.q, ri) == ri

    def _representatives(self) -> None:
        """Each active row replaced by its constraint's :meth:`~Constraint.representative` at q (the row to hold
        where another joins: a vertex's rather than the pair's own distance it equals), keeping its multiplier."""
        rows = list(self.rows)
        for pos, f in enumerate(rows):
            ci, ri = self.row_pairs[f]
            g = self.general[ci].representative(self.q, ri)
            if g != ri:
                key = self.row_pairs.index((ci, g))
                if key not in rows:
                    rows[pos] = key
        self.rows = tuple(rows)

    def _check_row_direction(self, key: int, kind: str) -> None:
        """After a row's switch: a reached row's nu grows, a released row's c grows; else the rate QP decides. A
        row that took its twin's place (:meth:`_twin`) carries on its multiplier: nothing to decide."""
        if kind == "row_reach" and self.__dict__.pop("_handed_over", None) == key:
            return
        if kind == "row_reach":
            rate = -float(self.lamdot[self._m + self.rows.index(key)])
        else:
            ci, ri = self.row_pairs[key]
            rate = float(self.general[ci].gradients(self.q)[ri] @ self.qdot)
        if rate > 0.0:
            return
        stay = self._qp_keeps_row(key)
        if stay == (key in self.rows):
            return
        self._apply_row_switch(key, "row_reach" if stay else "row_release")
        self._newton()
        self._rates()

    def _qp_keeps_row(self, key: int) -> bool:
        """The rate QP (:func:`row_rate_qp`) over the free joints with ``key`` as the inequality: True where
        the row stays active (its rate 0, its multiplier > 0)."""
        pt = self.evaluate(self.q, self.t)
        M, top = pt.system(self.lam)
        F = np.flatnonzero(~self.fixed)
        eq = list(range(self._m)) + [self._m + i for i, f in enumerate(self.rows) if f != key]
        ci, ri = self.row_pairs[key]
        g = self.general[ci].gradients(self.q)[ri][F]
        out = row_rate_qp(M[np.ix_(F, F)], top[F], pt.J[np.ix_(eq, F)], pt.xdot[eq], g, self.qp_solver)
        name = self.row_names((key,))[0]
        if out is None:
            raise self._failure("not_strongly_stable", f"the rate QP at the switch of {name} (t = {self.t:.6g} s) "
                                "has no solution")
        rate, mult = out
        if abs(rate) <= 1e-12 and abs(mult) <= 1e-12:
            raise self._failure("not_strongly_stable", f"{name} is weakly active at t = {self.t:.6g} s (rate and "
                                "multiplier both zero): the active set is not determined")
        return rate <= 1e-12

    def _name_row_failure(self, err, snap, involved: set | None = None) -> None:
        """A stop with a general row active (or switched in the step) is the constraint's: ``err.cause``
        becomes its cause (``collision``), the former one ``watched["underlying_cause"]``, and the message names the
        rows (``watched["constraints"]``) where it does not yet. ``involved``: the
        rows of :meth:`_rows_involved`, where the caller has already put the state back."""
        involved = self._rows_involved(snap) if involved is None else involved
        if not involved:
            return
        cause = self.general[self.row_pairs[min(involved)][0]].cause
        if err.cause != cause:
            err.watched["underlying_cause"] = err.cause
            err.cause = cause
        names = err.watched["constraints"] = self.row_names(sorted(involved))
        if not all(n in err.args[0] for n in names):  # the message names the pairs (the issue: cause and pair)
            err.args = (f"{err.args[0]}; the constraints involved: {'; '.join(names)}",) + tuple(err.args[1:])
        notes = self._discontinuities(snap, involved, err.watched.get("substep_q"))
        if notes:
            err.watched["nonsmooth"] = notes
            err.args = (f"{err.args[0]}; {'; '.join(notes)}",) + tuple(err.args[1:])

    def _discontinuities(self, snap, involved, near=None) -> list[str]:
        """What the involved rows' constraints say of gradient jumps (:meth:`Constraint.discontinuities`) on the
        way the run went in its last step (from its start ``snap`` to the nearest good sub-step point ``near``),
        along the step's motion from there (the rates at the start times dt) and 1e-3 [rad] along each joint."""
        q = np.asarray(snap.q if near is None else near, float)
        probes = [(np.asarray(snap.q, float), q - snap.q)] if near is not None else []
        probes += [(q, np.asarray(snap.qdot, float) * self.dt)] if snap.qdot is not None else []
        probes += [(q, s * 1e-3 * e) for e in np.eye(self.n) for s in (1.0, -1.0)]
        notes: list[str] = []
        for ci in sorted({self.row_pairs[f][0] for f in involved}):
            rows = [self.row_pairs[f][1] for f in sorted(involved) if self.row_pairs[f][0] == ci]
            for start, dq in probes:
                notes += [m for m in self.general[ci].discontinuities(start, dq, rows)
                          if m.split(" is not")[0] not in " ".join(notes)]
        return notes

    def _rates_stale(self, y: np.ndarray) -> bool:
        """Did the corrector end far from the prediction ``y`` (farther than 1e-8 [rad or m])? Its rates,
        solved at the predicted point, then carry that miss into the next prediction: on an active row's
        curved manifold the Hermite predictor then misses by ~1e-5 for tens of steps after a switch (and
        each step needs chord iterations), where rates afresh at the corrected point restore its O(h^6)."""
        d = self.q - y[: self.n]
        return float(d @ d) > 1e-16

    def _rows_involved(self, snap) -> set:
        """The rows active at the step's start (``snap``) or now, or switched within the step."""
        if not self.row_pairs:
            return set()
        return set(snap.rows) | set(self.rows) | {w["row"] for w in self.switches[len(snap.switches):] if "row" in w}

    def _rows_watched(self, state) -> dict:
        if not self.row_pairs:
            return {}
        return {"constraint_values": self._row_values(state.q).tolist(), "active_rows": self.row_names(state.rows)}

    def keep_smallest(self, value: float) -> None:
        """The smallest c over the general rows at the current q [m] as the compiled check of the step to it computed
        it (its ``smallest``: a scene's exact at or below the constraint's skip margin, a lower bound above it, as
        :meth:`~kinredund.tracking.constraints.base.Constraint.values` may be), for :meth:`row_record` at this q."""
        self._smallest = (self.q, value)

    def row_record(self) -> tuple[float, tuple, np.ndarray]:
        """(the smallest c over the general rows [m], the active rows, their multipliers nu >= 0) now: the smallest
        c the compiled check of the step kept for this q (:meth:`keep_smallest`), else from the rows' values."""
        q, smallest = self._smallest
        if q is not self.q:
            smallest = float(self._row_values(self.q).min())
        return smallest, self.rows, -self.lam[self._m:]
