"""Joint least-squares fit of the paper's parameters and the extensions.

``identify`` fits the paper's parameters in stages (the quasi-static fit, eq 37; the valve
fits, eqs 8–10 and 28) on data whose effect nobody declared: part of the missing effect is
absorbed into them (a valve lag into the valve constants, end stops into the gas spring).
An effect fitted on top of those parameters, frozen, then explains only what is left.
:func:`joint_fit` fits them again *with* the effect inside the model: every free
parameter of the paper's model (:data:`BASE_PARAMETERS`) and of each extension together,
by bounded least squares on the compressible model simulated over the whole
identification records.

Parameters live in normalised coordinates ``s ∈ [0, 1]`` between their bounds (log10 for
scales); the Jacobian is by forward differences (the compiled kernel is real-valued, so a
complex step is not available; one difference costs one simulation per parameter), taken
the other way where the model refuses the step (:meth:`Space.jacobian`).  Bounds
scale with the identified damper, never with the paper's numbers: a factor around each
identified value (:data:`BASE_PARAMETERS`), the friction up to a multiple of its own value,
and a gas volume that always leaves the rod room for the largest compression in the data.

Slow records are simulated for the fit with a longer sub-step (:func:`fit_substep`): the
quasi-static test at 4 mm/s on 5 ms sub-steps differs from the 0.5 ms reference by at most
0.05 N r.m.s. (every extension), and costs a ninth.  Scores and the
figures reported are always from the full model.  A record is simulated only where one of
its simulation's inputs changed: a Jacobian's column of the rig's delay or of a discovered
term's coefficient filters and sums the forces at the Jacobian's point, one of the
quasi-static friction ratio simulates the quasi-static records alone (the same numbers,
fewer simulations).
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
from scipy.optimize import OptimizeResult, least_squares

from damper_emulator.acquisition.rig import RigParams
from damper_emulator.diagnose.base import (
    ACQUISITION_DELAY,
    BASE_PARAMETERS,
    OIL_COMPRESSIBILITY,
    QUASI_STATIC_FRICTION_RATIO,
    TERM_PREFIX,
    Record,
    TermSource,
    base_parameters,
    config_value,
    config_with,
    delay_rig,
    fit_substep,
    model_of,
)
from damper_emulator.diagnose.candidates import Candidate, Parameter
from damper_emulator.diagnose.statistics import bic_gain, delta_bic, lag1
from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import ModelConfig
from damper_emulator.schema import ParameterError

#: Forward-difference step, relative to the normalised coordinate ``s`` (scipy's
#: ``diff_step`` rule: ``DIFF_STEP·s``, or ``MIN_DIFF_STEP`` where that is lost to rounding,
#: i.e. at ``s = 0``) ...
DIFF_STEP = 1e-3
#: ... and its least (√ε of a double, scipy's value).
MIN_DIFF_STEP = float(np.sqrt(np.finfo(float).eps))
#: Threads a Jacobian's columns run on (:meth:`Space.jacobian`): the CPUs this process may
#: use.  Beside a diagnosis's other fits in a pool of processes they share the cores; alone
#: (a round's last fit, the stages before and after the rounds) they fill them.
JACOBIAN_THREADS = len(os.sched_getaffinity(0))
#: Least-squares evaluations of the joint fit (Jacobians not counted).
JOINT_NFEV = 25
#: ... relative cost change below which it stops.
JOINT_FTOL = 1e-6
#: ... and it stops after a step that moved neither of the two measures the selection
#: decides by: the cost (the r.m.s.) by less than this fraction ...
JOINT_MIN_RELATIVE_STEP = 1e-3
#: ... and the effective BIC of the identification files (:func:`bic_gain`) by less than
#: this.  A cost 10⁻³ lower is an r.m.s. 0.05 % lower, a hundredth of the least held-out
#: gain that counts (``MIN_SCORE``, 5 %); one BIC unit is a tenth of the threshold
#: (``MAX_DELTA_BIC``, −10) and half of what Kass & Raftery (1995) call "not worth more than
#: a bare mention".  Either alone would not do: a residual far above its noise is strongly
#: autocorrelated, and its effective sample count so small that a first step 7 % down
#: gains under one BIC unit; a residual at its noise is white, and 10⁻³ of it is ~60 units.
#: On the sport damper with LuGre friction and valve lag, a valve-lag fit with end stops
#: on top crawled by 2.8·10⁻⁴ … 2.3·10⁻⁵ of its cost per step for 25 steps, each
#: a simulation per parameter, and its held-out r.m.s. did not change by 0.1 N.
JOINT_MIN_BIC_STEP = 1.0
#: Evaluations per start of the extension-only pre-fit, and for the best start after.
SCREEN_NFEV = 4
PREFIT_NFEV = 10
#: An optional parameter (``Parameter.optional``) whose σ is at least its value is held
#: at its low end where it lies above this fraction of its search range (the normalised
#: coordinate; below it, it has next to no force anyway): on the sport damper with
#: plain end stops, files entering the stops slowly left a hydraulic stop's damping at
#: 7758 ± 69096 N·s²/m², and the held-out 3 Hz sine, fast into the stops, at 166 N
#: against 4.
OPTIONAL_ON = 0.05
#: A sample counts as one where a local effect acts when the effect changes the force
#: there by more than this fraction of the record's force r.m.s. ...
ACTIVE_FORCE_FRACTION = 0.02
#: ... and an effect is local (its samples are left out of a re-identification) when it
#: acts on at most this fraction of each record.
MAX_ACTIVE_FRACTION = 0.6
#: A re-identification's valve fits take at most this many chirp samples per direction
#: (``identify``'s ``max_valve_samples``): half of what the paper's protocol selects (about
#: 13,400).  It is only a start for the joint fit, which takes every sample; its
#: complex-step valve Jacobian was a quarter of a candidate's time (end stops).  A quarter
#: (3,400) was faster still, but the valve lag fitted on top of a cavity then started in
#: the other of the two basins docs/diagnose.md describes (3 Hz sine 784 N against 129 N):
#: the sport damper's cavity is that sensitive to the start.
REIDENTIFY_VALVE_SAMPLES = 6_700
#: Cost of a residual vector for parameters the model refuses (every element); a simulation
#: whose weighted residual leaves ±FAILED_COST anywhere (a force error of order 10⁹ N: the
#: model ran away) counts as refused too.
FAILED_COST = 1e6
@dataclass
class JointFit:
    """Result of :func:`joint_fit`."""

    base_values: dict[str, float]
    base_std: dict[str, float]
    #: per effect (in order): fitted values and standard deviations by parameter name
    values: list[dict[str, float]]
    std: list[dict[str, float]]
    cost: float
    evaluations: int
    #: whether the start came from a re-identification without the effect's samples
    reidentified: bool = False
    #: where the friction at speed was searched (``Candidate.friction_coupled``): the
    #: factor over the quasi-static friction of the re-identification started from
    friction_factor: float | None = None

    def model(self, cfg: ModelConfig, candidates: Sequence[Candidate]) -> DamperModel:
        return model_of(cfg, self.base_values, list(zip(candidates, self.values)))

    def models(self, cfg: ModelConfig, candidates: Sequence[Candidate], n_records: int,
               n_quasi_static: int) -> list[DamperModel]:
        """The fitted model for each of ``n_records`` records, the first
        ``n_quasi_static`` quasi-static (:func:`record_models`): the model the fit took
        each record's residual of."""
        return record_models(cfg, self.base_values, list(zip(candidates, self.values)),
                             n_records, n_quasi_static)


def record_models(cfg: ModelConfig, base: Mapping[str, float],
                  effects: Sequence[tuple[Candidate, Mapping[str, float]]], n_records: int,
                  n_quasi_static: int) -> list[DamperModel]:
    """The model of ``base`` and ``effects`` for each of ``n_records`` records: its
    friction scaled by :data:`QUASI_STATIC_FRICTION_RATIO` on the first
    ``n_quasi_static`` (the quasi-static tests)."""
    model = model_of(cfg, base, effects)
    out = [model] * n_records
    ratio = base.get(QUASI_STATIC_FRICTION_RATIO, 1.0)
    if ratio != 1.0 and n_quasi_static > 0:
        slow = model_of(cfg, {**base, "friction_force_n": ratio * base["friction_force_n"]},
                        effects)
        out[:n_quasi_static] = [slow] * min(n_quasi_static, n_records)
    return out


class _Converged(Exception):
    """A joint fit's step gained too little to go on (:meth:`Space.solve`)."""


#: one record's simulation at a point: that point's inputs of it (:meth:`Space._keys`),
#: the model's force before the chain, and the discovered term's columns (or ``None``)
_Simulated = tuple[np.ndarray, np.ndarray, "np.ndarray | None"]


class Space:
    """The search space of a fit: the free parameters (paper's and each effect's), the
    held ones, and the residual function over the fit records."""

    def __init__(self, cfg: ModelConfig, base_free: Sequence[Parameter],
                 base_values: Mapping[str, float], cands: Sequence[Candidate],
                 values: Sequence[Mapping[str, float]], free_effects: Sequence[bool],
                 records: Sequence[Record], weights: Sequence[float],
                 n_quasi_static: int = 1, terms: TermSource | None = None):
        self.cfg, self.cands, self.records, self.weights = cfg, list(cands), records, weights
        #: a discovered term's parts, added to the force (their coefficients:
        #: ``TERM_PREFIX k`` in ``base_values``)
        self.terms = terms
        #: the first this many records are quasi-static tests (their own friction level:
        #: :data:`QUASI_STATIC_FRICTION_RATIO`)
        self.n_quasi_static = n_quasi_static
        self.base_values = dict(base_values)
        self.values = [dict(v) for v in values]
        self.slots: list[tuple[int, Parameter]] = [(-1, p) for p in base_free]
        for i, (c, free) in enumerate(zip(cands, free_effects)):
            if free:
                self.slots += [(i, p) for p in c.parameters]
        self.lo = np.array([p.bounds[0] for _, p in self.slots])
        self.hi = np.array([p.bounds[1] for _, p in self.slots])
        self.width = np.where(self.hi > self.lo, self.hi - self.lo, 1.0)
        self.n = sum(r.counted for r in records)
        self.evaluations = 0
        #: whether the last :meth:`residuals` was refused (the FAILED_COST vector), and the
        #: last point evaluated with its residual and that flag (the Jacobian's base point)
        self.refused = False
        self._last: tuple[np.ndarray, np.ndarray, bool] | None = None
        #: the last point :meth:`solve` accepted with its residual and Jacobian, and its
        #: stop's BIC step
        self._accepted: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._min_bic_step = JOINT_MIN_BIC_STEP
        #: where each record's residual ends in the concatenated vector
        self._ends = np.cumsum([r.counted for r in records])[:-1]
        #: each record's model force (before the chain) and the discovered term's columns
        #: at the last point it was simulated at, with that point's coordinates that are
        #: its simulation's inputs (:meth:`_keys`)
        self._raw: list[_Simulated | None] = [None] * len(records)
        #: the same at the point a Jacobian is taken (:meth:`jacobian`): a step of a
        #: parameter that is no input of a record's simulation takes that record from here
        self._anchor: list[_Simulated | None] = [None] * len(records)
        #: the free slots that are no simulation's input: the delay and the term's
        #: parameters (a step of them alone filters and sums what the cache holds)
        self._output_slots = [k for k, (i, p) in enumerate(self.slots)
                              if i < 0 and (p.name == ACQUISITION_DELAY
                                            or p.name.startswith(TERM_PREFIX))]
        #: the slot of the quasi-static friction ratio: an input of the quasi-static
        #: records' simulations only (a step of it alone simulates them alone)
        self._slow_slots = [k for k, (i, p) in enumerate(self.slots)
                            if i < 0 and p.name == QUASI_STATIC_FRICTION_RATIO]

    def encode(self, base_values: Mapping[str, float], values: Sequence[Mapping[str, float]]
               ) -> np.ndarray:
        u = []
        for i, p in self.slots:
            v = base_values[p.name] if i < 0 else values[i][p.name]
            u.append(p.to_internal(min(max(v, p.lo), p.hi)))
        s: np.ndarray = np.clip((np.array(u) - self.lo) / self.width, 0.0, 1.0)
        return s

    def decode(self, s: np.ndarray) -> tuple[dict[str, float], list[dict[str, float]]]:
        base = dict(self.base_values)
        values = [dict(v) for v in self.values]
        for k, (i, p) in enumerate(self.slots):
            # (a plain float: a params file written from the values must hold numbers)
            v = float(p.from_internal(self.lo[k] + self.width[k] * s[k]))
            if i < 0:
                base[p.name] = v
            else:
                values[i][p.name] = v
        return base, values

    def model(self, s: np.ndarray) -> DamperModel:
        base, values = self.decode(s)
        return model_of(self.cfg, base, list(zip(self.cands, values)))

    def models(self, s: np.ndarray) -> list[DamperModel]:
        """The model at ``s`` for each record (:func:`record_models`)."""
        base, values = self.decode(s)
        return record_models(self.cfg, base, list(zip(self.cands, values)),
                             len(self.records), self.n_quasi_static)

    def cost(self, s: np.ndarray | None = None) -> float:
        """``½ Σ r²`` of :meth:`residuals` at ``s`` (default: the start values)."""
        r = self.residuals(self.encode(self.base_values, self.values) if s is None else s)
        return 0.5 * float(np.dot(r, r))

    def residuals(self, s: np.ndarray) -> np.ndarray:
        """The weighted residual ``w_f (F_sim − F_meas)`` of every record at ``s``,
        concatenated; ``FAILED_COST`` everywhere for parameters the model refuses.  Any
        simulation counts one in :attr:`evaluations`."""
        residuals, self.refused, simulated, fresh = self._evaluate(s, self._raw)
        self.evaluations += fresh
        if simulated is not None:
            self._raw = list(simulated)
        self._last = (s.copy(), residuals, self.refused)
        return residuals

    def _evaluate(self, s: np.ndarray, known: Sequence[_Simulated | None]
                  ) -> tuple[np.ndarray, bool, list[_Simulated] | None, bool]:
        """:meth:`residuals` at ``s`` without a change to the space: the residual, whether
        it was refused, each record's simulation at ``s`` (``None`` where the model
        refused), and whether any record had to be simulated (:meth:`_known`)."""
        held = self._known(s, known)
        fresh = any(h is None for h in held)
        try:
            simulated = self._simulated(s, held)
            residuals: np.ndarray = np.concatenate(
                [rec.counted_residual(force) * w
                 for rec, w, force in zip(self.records, self.weights,
                                          self._forces(s, simulated))])
        except (ParameterError, ValueError):
            return np.full(self.n, FAILED_COST), True, None, fresh
        # a series spring with a nearly closed gas volume can run away on the 5 ms sub-step
        # of a slow record (forces of 1e299 N); trf's Jacobian would overflow to inf and
        # end the diagnosis with a traceback
        if not np.all(np.abs(residuals) < FAILED_COST):
            return np.full(self.n, FAILED_COST), True, simulated, fresh
        return residuals, False, simulated, fresh

    def _keys(self, s: np.ndarray) -> list[np.ndarray]:
        """Each record's simulation inputs among the coordinates ``s``: every slot but
        the output slots, and on a record past the quasi-static ones not the quasi-static
        friction ratio either."""
        key = s.copy()
        key[self._output_slots] = 0.0
        fast = key.copy()
        fast[self._slow_slots] = 0.0
        return [key if k < self.n_quasi_static else fast for k in range(len(self.records))]

    def _known(self, s: np.ndarray, known: Sequence[_Simulated | None]
               ) -> list[_Simulated | None]:
        """Each record's simulation at ``s`` where the Jacobian's anchor or ``known`` holds
        one at the same inputs (:meth:`_keys`: none is needed again for a step of the
        delay or the term's coefficients alone, and only the quasi-static records' for a
        step of their friction ratio); ``None`` where the record must be simulated."""
        return [next((c for c in (anchor, cached)
                      if c is not None and np.array_equal(c[0], key)), None)
                for key, anchor, cached in zip(self._keys(s), self._anchor, known)]

    def _simulated(self, s: np.ndarray, held: Sequence[_Simulated | None]
                   ) -> list[_Simulated]:
        """``held`` with each missing record simulated at ``s``: the model's force before
        the chain, and the discovered term's columns."""
        models = self.models(s) if any(h is None for h in held) else []
        keys = self._keys(s)
        out: list[_Simulated] = []
        for k, (rec, key, hit) in enumerate(zip(self.records, keys, held)):
            if hit is None:
                m = models[k]
                if self.terms is None:
                    hit = (key, rec.simulate(m, fast=True), None)
                else:
                    raw, col = self.terms(m.with_max_substep(fit_substep(m, rec.velocity)),
                                          rec)
                    hit = (key, raw, col)
            out.append(hit)
        return out

    def _forces(self, s: np.ndarray, simulated: Sequence[_Simulated]) -> list[np.ndarray]:
        """The model's force at ``s`` over each record as the record holds it, from its
        simulation ``simulated`` at ``s``: with the discovered term's parts added and
        through the estimated chain."""
        base = self.decode(s)[0]
        rig = delay_rig(base)
        if self.terms is None:
            return [rec.recorded(raw, rig) for rec, (_, raw, _) in zip(self.records, simulated)]
        cols = [self.terms.at(rec, c, base)
                for rec, (_, _, c) in zip(self.records, simulated) if c is not None]
        assert len(cols) == len(simulated)  # the term's columns with every record's force
        coef = [base[f"{TERM_PREFIX}{k}"] for k in range(cols[0].shape[1])]
        return [rec.with_term(raw, c, coef, rig)
                for rec, (_, raw, _), c in zip(self.records, simulated, cols)]

    def jacobian(self, s: np.ndarray) -> np.ndarray:
        """Forward differences of :meth:`residuals` at ``s``, each parameter stepped by
        ``DIFF_STEP·s`` (``MIN_DIFF_STEP`` at least), backwards where that leaves the
        bounds.  A step the model refuses is taken the other way instead; a parameter
        refused both ways (or with no room) gets a zero column: the data show no slope for
        it, and its σ is undetermined (:meth:`std`).

        The case this guards against (the FSAE data): ``identify`` can leave the
        compression valve's blow-off stiffness where 1 % more makes its Δp(Q)
        non-monotonic at Q = 0 (a ``ValveTableError``).  scipy's own differences would
        then take ``(FAILED_COST − r)/h``, a column of 10¹¹ against 10²–10³ of the
        others, and the covariance's pseudo-inverse would cut every other direction: each
        σ would come out 10⁻¹⁵ of its value.

        The columns are independent: they run on :data:`JACOBIAN_THREADS` threads (the
        compiled simulation releases the GIL), each from the records as simulated at
        ``s``; the matrix is the same as one thread's, bit for bit.
        """
        if self._last is None or not np.array_equal(self._last[0], s):
            self.residuals(s)
        assert self._last is not None  # set by every residuals()
        _, f0, base_refused = self._last
        self._anchor = list(self._raw)  # each record as simulated at s
        jac = np.zeros((f0.size, s.size))

        def column(k: int) -> int:
            """Column ``k`` into ``jac``; the simulations it took."""
            h = DIFF_STEP * s[k]
            if (s[k] + h) - s[k] == 0.0:
                h = MIN_DIFF_STEP * max(1.0, s[k])
            if s[k] + h > 1.0:
                h = -h
            taken = 0
            for step in (h, -h):
                if not 0.0 <= s[k] + step <= 1.0:
                    continue
                x = s.copy()
                x[k] += step
                fk, refused, _, fresh = self._evaluate(x, self._anchor)
                taken += fresh
                if refused and not base_refused:
                    continue
                jac[:, k] = (fk - f0) / (x[k] - s[k])  # the step as represented
                break
            return taken

        threads = min(JACOBIAN_THREADS, s.size)
        if threads > 1:
            with ThreadPoolExecutor(threads, thread_name_prefix="jacobian") as pool:
                self.evaluations += sum(pool.map(column, range(s.size)))
        else:
            self.evaluations += sum(column(k) for k in range(s.size))
        self._last = (s.copy(), f0, base_refused)
        return jac

    def _jacobian_unless_done(self, s: np.ndarray) -> np.ndarray:
        """:meth:`jacobian` at ``s``, the point the solver has just accepted, unless the
        step there lowered the cost by less than :data:`JOINT_MIN_RELATIVE_STEP` and the
        effective BIC by less than ``self._min_bic_step`` (:func:`bic_gain`): then
        :class:`_Converged` (the Jacobian is not needed to go on)."""
        if self._last is None or not np.array_equal(self._last[0], s):
            self.residuals(s)
        assert self._last is not None  # set by every residuals()
        _, f, refused = self._last
        if self._accepted is not None and not refused:
            f0 = self._accepted[1]
            ss0, ss1 = float(np.dot(f0, f0)), float(np.dot(f, f))
            if (ss1 > (1.0 - JOINT_MIN_RELATIVE_STEP) * ss0
                    and bic_gain(np.split(f0, self._ends),
                                 np.split(f, self._ends)) < self._min_bic_step):
                raise _Converged
        jac = self.jacobian(s)
        self._accepted = (s.copy(), f, jac)
        return jac

    def solve(self, s0: np.ndarray, nfev: int, min_bic_step: float | None = None
              ) -> OptimizeResult:
        """Bounded least squares from ``s0``: at most ``nfev`` evaluations (Jacobians not
        counted), until the relative cost change is below ``JOINT_FTOL`` or (with
        ``min_bic_step``) a step has lowered the cost by less than
        :data:`JOINT_MIN_RELATIVE_STEP` and the effective BIC by less than that."""
        self._accepted = None
        jac = self.jacobian
        if min_bic_step is not None:
            self._min_bic_step, jac = min_bic_step, self._jacobian_unless_done
        try:
            return least_squares(self.residuals, s0, jac=jac, bounds=(0.0, 1.0),
                                 method="trf", x_scale="jac", max_nfev=nfev,
                                 ftol=JOINT_FTOL, xtol=1e-6)
        except _Converged:
            # where the step that gained nothing that counts started: its Jacobian is at
            # hand (the point that step reached would need one more, one simulation per
            # free parameter, for a cost lower by under JOINT_MIN_RELATIVE_STEP)
            assert self._accepted is not None
            s, f, jac = self._accepted
            return OptimizeResult(x=s, fun=f, cost=0.5 * float(np.dot(f, f)), jac=jac,
                                  status=-2)

    def std(self, sol: OptimizeResult, rho: float) -> dict[tuple[int, str], float]:
        """One standard deviation of each free parameter from the Jacobian at ``sol``
        (``σ² (JᵀJ)⁻¹``, σ² the weighted residual's variance), inflated by
        ``(1 + ρ)/(1 − ρ)`` for an AR(1) residual of lag-1 autocorrelation ρ.

        ``math.inf`` (undetermined) for a parameter the data show no slope for (a zero
        column of :meth:`jacobian`) or that lies along a direction the Jacobian cannot
        resolve: a singular value below ``ε·max(m, n)·s_max`` (the rank rule of
        ``numpy.linalg.matrix_rank``), whose direction would otherwise be dropped and its
        σ understated."""
        base, values = self.decode(sol.x)
        dof = max(sol.fun.size - len(self.slots), 1)
        s2 = 2.0 * sol.cost / dof * (1.0 + rho) / (1.0 - rho)
        jac = sol.jac
        undetermined = ~np.any(jac != 0.0, axis=0)
        var = np.full(len(self.slots), math.inf)
        if not np.all(undetermined):
            try:
                _, sv, vt = np.linalg.svd(jac[:, ~undetermined], full_matrices=False)
            except np.linalg.LinAlgError:
                sv = np.zeros(0)
            if sv.size:
                keep = sv > np.finfo(float).eps * max(jac.shape) * sv[0]
                v_kept = vt[keep] / sv[keep, None]
                var_det = np.sum(v_kept * v_kept, axis=0) * s2
                lost = np.any(np.abs(vt[~keep]) > NULL_COMPONENT, axis=0)
                var[~undetermined] = np.where(lost, math.inf, var_det)
        out: dict[tuple[int, str], float] = {}
        for k, (i, p) in enumerate(self.slots):
            su = math.sqrt(var[k]) * self.width[k]
            v = base[p.name] if i < 0 else values[i][p.name]
            out[(i, p.name)] = v * math.log(10.0) * su if p.log else su
        return out


#: a parameter whose unit vector has a component above this along a direction the
#: Jacobian cannot resolve (:meth:`Space.std`) has an undetermined σ
NULL_COMPONENT = 1e-3
def active_samples(records: Sequence[Record], without: DamperModel, with_: DamperModel
                   ) -> list[np.ndarray] | None:
    """Per record, the samples where ``with_`` differs from ``without`` by more than
    :data:`ACTIVE_FORCE_FRACTION` of the record's force r.m.s.; ``None`` when the effect
    acts nowhere or is not local (more than :data:`MAX_ACTIVE_FRACTION` of a record)."""
    out = []
    for rec in records:
        scale = float(np.sqrt(np.mean(np.square(rec.data.force))))
        diff = np.abs(rec.simulate(with_, fast=True) - rec.simulate(without, fast=True))
        mask = diff > ACTIVE_FORCE_FRACTION * scale
        if mask.mean() > MAX_ACTIVE_FRACTION:
            return None
        out.append(mask)
    return out if any(m.any() for m in out) else None


def acting(cfg: ModelConfig, records: Sequence[Record], base_values: Mapping[str, float],
           effects: Sequence[tuple[Candidate, Mapping[str, float]]]
           ) -> list[np.ndarray] | None:
    """Per record, where the local ones of ``effects`` act on the model ``base_values``
    (each alone: where it says it may, ``Candidate.may_act``, or :func:`active_samples`);
    ``None`` where none is local."""
    plain = model_of(cfg, base_values, [])
    masks = None
    for c, v in effects:
        m = ([c.may_act(r.data) for r in records] if c.may_act is not None
             else active_samples(records, plain, model_of(cfg, base_values, [(c, v)])))
        if m is not None:
            masks = m if masks is None else [a | b for a, b in zip(masks, m)]
    return masks


def reidentify(cfg: ModelConfig, records: Sequence[Record], n_quasi_static: int,
               masks: Sequence[np.ndarray] | None = None, friction_factor: float = 1.0,
               rig: RigParams | None = None) -> dict[str, float] | None:
    """The paper's parameters identified again (``identify``, the staged fits) on
    ``records`` with ``cfg`` (its data sheet values), without the samples ``masks`` (where
    an effect acts; ``None``: every sample), its valve fits on at most
    :data:`REIDENTIFY_VALVE_SAMPLES` chirp samples per direction; ``None`` when that
    identification fails.  ``friction_factor``: the friction at speed (the chirp's, the
    model's) is this multiple of the quasi-static fit's, which the result's
    :data:`QUASI_STATIC_FRICTION_RATIO` then holds (``identify(chirp_friction_factor=)``).
    ``rig``: the estimated chain (:func:`delay_rig`), which the staged fits align the
    records by where they carry none.
    """
    from damper_emulator.identify.pipeline import identify
    from damper_emulator.identify.quasi_static import IdentificationError

    data = [r.data if r.data.acquisition is not None or rig is None
            else dataclasses.replace(r.data, acquisition=rig) for r in records]
    qs = data[:n_quasi_static]
    chirp = data[n_quasi_static:]
    if not qs or not chirp:
        return None
    exclude = (None if masks is None else
               (np.concatenate(masks[:n_quasi_static]), np.concatenate(masks[n_quasi_static:])))
    try:
        ident = identify(qs, chirp, cfg, exclude=exclude,
                         max_valve_samples=REIDENTIFY_VALVE_SAMPLES,
                         chirp_friction_factor=friction_factor)
    except (IdentificationError, ParameterError, ValueError):
        return None
    out = {bp.path: config_value(ident.config, bp.path) for bp in BASE_PARAMETERS}
    if friction_factor != 1.0:
        out[QUASI_STATIC_FRICTION_RATIO] = 1.0 / friction_factor
    return out


#: A friction-coupled candidate's re-identification (``Candidate.friction_coupled``) tries
#: the friction at speed at these multiples of the quasi-static fit's: at least that (a
#: friction higher at low speed is the friction family's Stribeck effect), up to twice it
#: (seal friction of dampers rises with speed by tens of percent; the benchmark's smooth
#: friction is 1.5× at speed what it is at the quasi-static 4 mm/s) ...
FRICTION_SEARCH_FACTORS = (1.0, 1.5, 2.0)
#: ... and then once more at the least of the parabola through the three costs (clipped to
#: their range; :func:`search_friction`).  The pre-fit's cost is sharp and smooth in the
#: factor: on the sport damper with a cavity (truth 1.51) 72, 33, 1.7, 20 and 56 at 1,
#: 1.25, 1.5, 1.75 and 2; the parabola through 72, 1.7 and 56 has its least at 1.53.  A
#: grid of five with a refinement either side of its best found the same minimum in
#: seven re-identifications instead of four.
#: The search is made only where the effect pre-fitted on the present model lowers the
#: records' cost by at least this fraction.  On the sport damper (round 1): with a cavity
#: in the data 79 % (the cavity alone) and 62 % (with a valve lag); without one 20 % (air
#: entrainment with LuGre friction: the cavity follows the air's lag at the largest
#: pushes), −0.1 % (LuGre and a lag) and less than nothing (noise only).  Searched on the
#: air case, the diagnosis took 211 s instead of about 180.
FRICTION_SEARCH_MIN_GAIN = 0.4

_Tried = TypeVar("_Tried", bound=tuple[Any, ...])
#: a re-identified start of :func:`joint_fit`: (pre-fit cost, paper's parameters, the
#: candidate's pre-fitted values, simulations, the friction factor it was identified with)
_Restart = tuple[float, dict[str, float], dict[str, float], int, float]


def parabola_least(x: Sequence[float], y: Sequence[float]) -> float | None:
    """Where the parabola through three equally spaced points ``(x[k], y[k])`` is least,
    clipped to ``[x[0], x[2]]``; ``None`` when it is not convex (no least)::

        x* = x₁ + h (y₀ − y₂) / (2 (y₀ − 2 y₁ + y₂)),   h = x₁ − x₀
    """
    curvature = y[0] - 2.0 * y[1] + y[2]
    if not curvature > 0.0:
        return None
    h = x[1] - x[0]
    return min(max(x[1] + h * (y[0] - y[2]) / (2.0 * curvature), x[0]), x[2])


def search_friction(score: Callable[[float], _Tried | None]) -> list[_Tried | None]:
    """``score(factor)`` (a tuple whose first item is a cost to minimise, or ``None`` for a
    failure) at each of :data:`FRICTION_SEARCH_FACTORS`, then, where all three were
    scored, at the least of the parabola through their costs (:func:`parabola_least`;
    where that is not convex, half-way from the best to its better neighbour): every
    result, in the order tried."""
    grid = FRICTION_SEARCH_FACTORS
    tried = {f: score(f) for f in grid}
    done = [t for t in tried.values() if t is not None]
    if len(done) == len(grid):
        y = [float(t[0]) for t in done]
        f = parabola_least(grid, y)
        if f is None:
            k = min(range(3), key=lambda i: y[i])
            near = [i for i in (k - 1, k + 1) if 0 <= i < 3]
            f = 0.5 * (grid[k] + grid[min(near, key=lambda i: y[i])])
        if f not in tried:
            tried[f] = score(f)
    return list(tried.values())


def joint_fit(cfg: ModelConfig, records: Sequence[Record], weights: Sequence[float],
              base_values: Mapping[str, float],
              accepted: Sequence[tuple[Candidate, Mapping[str, float]]],
              candidate: Candidate | None, nfev: int = JOINT_NFEV,
              n_quasi_static: int = 1,
              alternative: tuple[Mapping[str, float], Mapping[str, Mapping[str, float]]]
              | None = None, terms: TermSource | None = None,
              term_parameters: Sequence[Parameter] = (),
              identify_without_term: bool = True) -> JointFit:
    """Fit ``candidate`` (``None``: nothing new) together with the effects ``accepted``
    and the paper's parameters, on ``records`` (the identification files, the first
    ``n_quasi_static`` of them quasi-static tests).

    1. **Pre-fit** the candidate alone on top of the present model (``base_values`` and
       ``accepted`` held), ``SCREEN_NFEV`` evaluations from each of its start vectors, then
       ``PREFIT_NFEV`` from the best (the ``Candidate.prefit_keep`` best, and each of
       its form's own starts unscreened, ``Candidate.form_starts``; the better end
       kept): a start for step 3 that already has the effect.
    2. **Re-identify** when a local effect is in the model (the candidate or an accepted
       one, :func:`active_samples`, or where it says it may act, ``Candidate.may_act``):
       the staged identification again without the samples where those effects act (an
       open cavity corrupts the valve fit, an engaged end stop the gas spring's), or for
       a first effect with the configuration the candidate names
       (``Candidate.identify_as``: an isothermal gas for a gas that exchanges heat), and
       the pre-fit again on it; the start of step 4 is whichever fits the records better
       (a first effect re-identified under its own configuration on a present model
       fitted jointly with the rig's delay: step 4 from both, the better end kept, as the
       re-identification has not been fitted jointly yet: from the present model alone
       the gas's heat exchange was left adiabatic); for a later effect, of that
       configuration's re-identification only what the candidate names
       (``Candidate.identify_keeps``: the charge and volume of an isothermal gas), the
       rest of the present model kept (after a valve lag, the heat exchange gained
       1 % from the present model's adiabatic gas and 77 % from the isothermal one).
       (A second effect needs the re-identification too: a valve lag fitted on top of a
       cavity starts from the valves the cavity's own fit left, which had absorbed the
       lag as well.)
       The valve fits take the quasi-static fit's friction; for a candidate whose force
       trades with the friction at speed (``Candidate.friction_coupled``) the
       re-identification is repeated over :func:`search_friction`'s friction levels and
       the best pre-fit taken.  On the sport damper with a cavity, re-identified with the
       quasi-static friction (29 N, at speed 43.7 N) the compression preload came out 3 %
       high, the pre-fit's cost was 72 (1.7 at the truth's friction), and the joint fit
       went into a valley of its own (p_cav 31 kPa, truth 20; held-out 3 Hz sine 28.8 N;
       with the search 4.3 N).
    3. **The other order** (with ``alternative``: the candidate's own fit of the round
       before, its paper's parameters and the values of its effects by name, i.e. the
       model without the newest accepted effect): that model with the newest accepted
       effect pre-fitted on top of it as in step 1.  Of two effects, forward selection
       takes the one whose fit alone gained more; the other is then fitted on top of it,
       from where the first left the paper's parameters, and a joint fit from there can
       stop in the first one's valley (end stops on a series spring: the gas spring that
       absorbed the stops is only given back by the stops' own re-identification).
       Taken where its pre-fit is lower, with the forward order kept as a further start
       for step 4: a lower pre-fit need not end lower (an air entrainment fitted on top
       of a gas's heat transfer from the order without it lost the heat transfer's part).
    4. **Joint fit** of every free parameter — :func:`base_parameters` of ``cfg`` (bounds
       around the identified values), each accepted effect's and the candidate's — from
       there, ``nfev`` evaluations of the weighted residual ``w_f (F_sim − F_meas)``
       (``weights``: one per record); from the further starts too where steps 2 and 3
       left any, the best end kept.
    5. **Hold what the files do not determine**: an optional form part
       (``Parameter.optional``) with force but a σ at least its value held at its low
       end, the form without it, and the fit repeated from there, kept unless the
       effective BIC says the part is wanted (``_JointFit.without_undetermined``).

    A discovered term's fit (``terms``, no candidate) has a step 2 of its own: the paper's
    model identified again on the records with the term's force taken out, a further
    start for step 4 (:meth:`_JointFit.without_term`; not with ``identify_without_term``
    false, a fit from where one with it ended).

    The cost weights are fixed by the caller for a whole diagnosis, so the costs of
    different candidates compare.
    """
    accepted = [(c.settled(v), v) for c, v in accepted]
    j = _JointFit(cfg, records, weights, n_quasi_static, nfev, terms, term_parameters,
                  [c for c, _ in accepted] + ([candidate] if candidate is not None else []))
    start = _Start(dict(base_values), [dict(v) for _, v in accepted])
    if terms is not None and identify_without_term:
        j.without_term(start)
    if candidate is not None:
        j.prefitted(start, candidate)
        if accepted and alternative is not None and candidate.effect in alternative[1]:
            j.other_order(start, accepted[-1][0], alternative)
        j.reidentified(start, candidate, bool(accepted))
        start.values.append(start.candidate_values)
    return j.result(start)


@dataclass
class _Start:
    """Where a joint fit starts (:func:`joint_fit`'s steps 1–3 move it): the paper's
    parameters, the accepted effects' values and the candidate's pre-fitted values and
    cost, with what the steps cost and found."""

    base_values: dict[str, float]
    values: list[dict[str, float]]
    candidate_values: dict[str, float] = field(default_factory=dict)
    cost: float = math.inf
    evaluations: int = 0
    reidentified: bool = False
    friction_factor: float | None = None
    #: further starts that go to step 4 too (the forward order where the other order
    #: was taken; a re-identification under the candidate's configuration of a present
    #: model fitted jointly with the rig's delay): each its paper's parameters, its
    #: effects' values (the candidate's last), whether it was re-identified
    others: list[tuple[dict[str, float], list[dict[str, float]], bool]] = field(
        default_factory=list)


class _JointFit:
    """The stages of one :func:`joint_fit`: what they share, and each step."""

    def __init__(self, cfg: ModelConfig, records: Sequence[Record],
                 weights: Sequence[float], n_quasi_static: int, nfev: int,
                 terms: TermSource | None, term_parameters: Sequence[Parameter],
                 cands: list[Candidate]):
        self.cfg, self.records, self.weights = cfg, records, weights
        self.n_quasi_static, self.nfev = n_quasi_static, nfev
        self.terms, self.term_parameters = terms, term_parameters
        #: the accepted effects, then the candidate
        self.cands = cands

    def prefit(self, bv: Mapping[str, float], vals: Sequence[Mapping[str, float]],
               free: int, starts_values: Sequence[Mapping[str, float]],
               form_values: Sequence[Mapping[str, float]] = ()
               ) -> tuple[dict[str, float], float, int]:
        """Effect ``free`` of the candidates fitted alone on the model ``bv``, ``vals``
        from each of ``starts_values`` (screened) and of ``form_values`` (not screened:
        ``Candidate.form_starts``): its values, the cost, the simulations."""
        def with_start(sv: Mapping[str, float]) -> list[Mapping[str, float]]:
            return [sv if k == free else v for k, v in enumerate(vals)]

        pre = Space(self.cfg, [], bv, self.cands, with_start(starts_values[0]),
                    [k == free for k in range(len(self.cands))], self.records,
                    self.weights, self.n_quasi_static)
        starts = [pre.encode(bv, with_start(sv)) for sv in starts_values]
        if len(starts) > 1:
            screened = sorted((pre.solve(s0, SCREEN_NFEV) for s0 in starts),
                              key=lambda r: r.cost)
            starts = [r.x for r in screened[:self.cands[free].prefit_keep]]
        starts += [pre.encode(bv, with_start(sv)) for sv in form_values]
        sol = min((pre.solve(s0, PREFIT_NFEV) for s0 in starts), key=lambda r: r.cost)
        return pre.decode(sol.x)[1][free], float(sol.cost), pre.evaluations

    @staticmethod
    def own_starts(c: Candidate, form: bool = False) -> list[dict[str, float]]:
        """The candidate's start vectors (``form``: its form's own), by parameter name."""
        names = [p.name for p in c.parameters]
        return [dict(zip(names, (p.from_internal(u) for p, u in zip(c.parameters, u0))))
                for u0 in c.starts(form)]

    def prefitted(self, start: _Start, candidate: Candidate) -> None:
        """Step 1: the candidate alone on top of the present model, from its own
        starts."""
        starts = self.own_starts(candidate)
        last = len(self.cands) - 1
        values, cost, n = self.prefit(start.base_values, [*start.values, starts[0]], last,
                                      starts, self.own_starts(candidate, form=True))
        start.candidate_values, start.cost = values, cost
        start.evaluations += n

    def other_order(self, start: _Start, newest: Candidate,
                    alternative: tuple[Mapping[str, float], Mapping[str, Mapping[str, float]]]
                    ) -> None:
        """Step 3: the candidate's own fit of the round before with the newest accepted
        effect pre-fitted on top of it, taken where it fits the records better; the
        forward order then goes to step 4 too (``_Start.others``)."""
        alt_base, alt_effects = alternative
        last = len(self.cands) - 1
        alt_vals = [alt_effects.get(c.effect, v)
                    for c, v in zip(self.cands, [*start.values, {}])]
        alt_new, alt_cost, n = self.prefit({**start.base_values, **alt_base}, alt_vals,
                                           last - 1, [*self.own_starts(newest),
                                                      start.values[-1]])
        start.evaluations += n
        if alt_cost < start.cost:
            # a lower pre-fit need not end lower: the forward order goes to step 4 too
            start.others.append((dict(start.base_values),
                                 [*start.values, start.candidate_values],
                                 start.reidentified))
            start.base_values = {**start.base_values, **alt_base}
            start.values = [*(dict(v) for v in alt_vals[:-2]), alt_new]
            start.candidate_values, start.cost = dict(alt_vals[-1]), alt_cost

    def restart(self, start: _Start, candidate: Candidate, factor: float,
                masks: Sequence[np.ndarray] | None, as_cfg: ModelConfig | None = None,
                screen: bool = True, keep: Sequence[str] | None = None) -> _Restart | None:
        """Re-identified base (``friction_factor``; of it only the parameters ``keep``,
        where given, the rest of ``start`` kept), the candidate pre-fitted on it (from
        its own starts and the first pre-fit's values, or with ``screen`` false from the
        latter only): ``(cost, base, candidate's values, simulations, factor)``; ``None``
        if the re-identification failed."""
        cfg = as_cfg or self.cfg
        if OIL_COMPRESSIBILITY in start.base_values:  # the force's scale taken
            cfg = config_with(cfg, {OIL_COMPRESSIBILITY: start.base_values[OIL_COMPRESSIBILITY]})
        nb = reidentify(cfg, self.records, self.n_quasi_static, masks, factor,
                        delay_rig(start.base_values))
        if nb is None:
            return None
        if keep is not None:
            nb = {k: v for k, v in nb.items() if k in keep}
        nb = {**start.base_values, **nb}
        pre = start.candidate_values
        starts = [*self.own_starts(candidate), pre] if screen else [pre]
        vals, cost, n = self.prefit(nb, [*start.values, pre], len(self.cands) - 1, starts,
                                    self.own_starts(candidate, form=True) if screen else ())
        return cost, nb, vals, n, factor

    def masks(self, start: _Start, candidate: Candidate) -> list[np.ndarray] | None:
        """Where the local effects of the model act (the accepted ones and the
        candidate), by record (:func:`acting`)."""
        return acting(self.cfg, self.records, start.base_values,
                      [*zip(self.cands[:-1], start.values),
                       (candidate, start.candidate_values)])

    def reidentified(self, start: _Start, candidate: Candidate, accepted: bool) -> None:
        """Step 2: the staged identification again without the samples where the local
        effects act, or under the candidate's own configuration (for a later effect, of
        it only ``Candidate.identify_keeps``), with the friction at speed searched for a
        friction-coupled candidate; the pre-fit on it taken where it fits the records
        better."""
        tried: list[_Restart | None] = []
        search = False  # the friction at speed searched (search_friction)
        if candidate.identify_as is not None and (not accepted or candidate.identify_keeps):
            # a later effect: only what it names, without where the accepted local ones act
            tried.append(self.restart(
                start, candidate, 1.0, self.masks(start, candidate) if accepted else None,
                candidate.identify_as(self.cfg),
                keep=candidate.identify_keeps if accepted else None))
        else:
            masks = self.masks(start, candidate)
            search = masks is not None and candidate.friction_coupled
            if search:
                # the present model without the candidate
                start.evaluations += 1
                search = start.cost < (1.0 - FRICTION_SEARCH_MIN_GAIN) * Space(
                    self.cfg, [], start.base_values, self.cands[:-1], start.values,
                    [False] * len(start.values), self.records, self.weights,
                    self.n_quasi_static).cost()
            if search:
                # a search of four, the pre-fits from the first one's values only
                tried = search_friction(lambda f: self.restart(start, candidate, f, masks,
                                                               screen=False))
            elif masks is not None:
                tried.append(self.restart(start, candidate, 1.0, masks))
        start.evaluations += sum(t[3] for t in tried if t is not None)
        done = [t for t in tried if t is not None]
        if not done:
            return
        alt_cost, new_base, alt_values, _, factor = min(done, key=lambda t: t[0])
        if alt_cost < start.cost:
            start.base_values, start.candidate_values = new_base, alt_values
            start.reidentified = True
            if search:
                start.friction_factor = factor
        elif (not accepted and candidate.identify_as is not None
              and ACQUISITION_DELAY in start.base_values):
            # the present model was fitted jointly with the rig's delay (no effect
            # accepted yet), its re-identification under the candidate's configuration
            # not: both go to step 4
            start.others.append((new_base, [*start.values, alt_values], True))

    def without_term(self, start: _Start) -> None:
        """Step 2 of a discovered term's fit: the staged identification again on the
        records with the term's force (at its start) taken out, without the samples
        where the accepted local effects act; a further start for step 4.  The paper's
        parameters were identified with the term's force in the data: a damping zone
        over the compression stroke took the compression valve with it (its port 190
        times the truth's, at its bound in the joint fit)."""
        assert self.terms is not None  # (a term's fit)
        bv = start.base_values
        rig = delay_rig(bv)
        effects = list(zip(self.cands, start.values))
        models = record_models(self.cfg, bv, effects, len(self.records), self.n_quasi_static)
        records = []
        for rec, m in zip(self.records, models):
            _, cols = self.terms(m.with_max_substep(fit_substep(m, rec.velocity)), rec)
            coef = [bv[f"{TERM_PREFIX}{k}"] for k in range(cols.shape[1])]
            term = self.terms.at(rec, cols, bv) @ np.asarray(coef)
            data = dataclasses.replace(rec.data,
                                       force=rec.data.force - rec.through_chain(term, rig))
            records.append(dataclasses.replace(rec, data=data))
        masks = acting(self.cfg, records, bv, effects)
        ratio = bv.get(QUASI_STATIC_FRICTION_RATIO, 1.0)
        nb = reidentify(self.cfg, records, self.n_quasi_static, masks,
                        1.0 / ratio if ratio > 0.0 else 1.0, rig)
        start.evaluations += len(self.records)
        if nb is not None:
            start.others.append(({**bv, **nb}, [dict(v) for v in start.values], True))

    def fit_from(self, bv: Mapping[str, float], vals: Sequence[Mapping[str, float]],
                 cands: Sequence[Candidate] | None = None, nfev: int | None = None
                 ) -> tuple[Space, OptimizeResult]:
        """Step 4 from ``bv``, ``vals``: bounds around the start (the identified values,
        or the re-identified ones); ``cands`` in place of the fit's own (some of their
        parameters held), ``nfev`` in place of its evaluations."""
        cands = self.cands if cands is None else cands
        free = [*free_parameters(self.cfg, bv, self.records, cands), *self.term_parameters]
        space = Space(self.cfg, free, bv, cands, vals, [True] * len(cands),
                      self.records, self.weights, self.n_quasi_static, self.terms)
        return space, space.solve(space.encode(bv, vals), nfev or self.nfev,
                                  JOINT_MIN_BIC_STEP)

    def result(self, start: _Start) -> JointFit:
        """Step 4 from the start (and each further start, ``_Start.others``), the best
        end kept, with its σ; then step 5, :meth:`without_undetermined`."""
        ends = [(*self.fit_from(bv, vals), reidentified) for bv, vals, reidentified in
                [(start.base_values, start.values, start.reidentified), *start.others]]
        space, sol, reidentified = min(ends, key=lambda e: float(e[1].cost))
        evaluations = start.evaluations + sum(e[0].evaluations for e in ends)
        space, sol, std, n = self.without_undetermined(space, sol)
        evaluations += n
        base, vals = space.decode(sol.x)
        return JointFit(base_values=base,
                        base_std={p.name: std[(i, p.name)] for i, p in space.slots if i < 0},
                        values=vals,
                        # a held parameter's σ is undetermined
                        std=[{**dict.fromkeys(c.held, math.inf),
                              **{p.name: std.get((k, p.name), 0.0) for p in c.parameters}}
                             for k, c in enumerate(space.cands)],
                        cost=float(sol.cost), evaluations=evaluations,
                        reidentified=reidentified, friction_factor=start.friction_factor)

    def without_undetermined(self, space: Space, sol: OptimizeResult
                             ) -> tuple[Space, OptimizeResult, dict[tuple[int, str], float],
                                        int]:
        """Step 5: the optional parameters (``Parameter.optional``) the fit files do not
        determine (σ at least the value, or undetermined) where they have some force
        (above :data:`OPTIONAL_ON` of their search range) held at their low ends, the
        form without them, and the fit repeated from there (``PREFIT_NFEV``
        evaluations); taken unless the effective BIC of the identification files says
        they are wanted.  A term the files do not determine only extrapolates.  Returns
        the space and solution kept (its candidates hold what was held,
        ``Candidate.held``), their σ and the simulations the step ran."""
        rho = _rho(space, sol)
        std = space.std(sol, rho)
        base, vals = space.decode(sol.x)
        loose = {(i, p.name) for k, (i, p) in enumerate(space.slots)
                 if i >= 0 and p.optional and sol.x[k] > OPTIONAL_ON
                 and not std[(i, p.name)] < abs(vals[i][p.name])}
        if not loose:
            return space, sol, std, 0
        cands = [c.holding({n for i, n in loose if i == k})
                 for k, c in enumerate(space.cands)]
        held_vals = [{**v, **c.held} for c, v in zip(cands, vals)]
        space2, sol2 = self.fit_from(base, held_vals, cands, PREFIT_NFEV)
        # the parts wanted: the fit with them beats the one without by the effective BIC
        if delta_bic([(sol.fun.size, rho, sol.cost, sol2.cost)], len(loose)) < 0.0:
            return space, sol, std, space2.evaluations
        return space2, sol2, space2.std(sol2, _rho(space2, sol2)), space2.evaluations


def free_parameters(cfg: ModelConfig, base_values: Mapping[str, float],
                    records: Sequence[Record], cands: Sequence[Candidate]) -> list[Parameter]:
    """The paper's parameters a joint fit frees at ``base_values`` with the effects
    ``cands`` in the model (:func:`base_parameters`: the rig's delay where it is among
    the values, the oil's compressibility where the force's scale was taken)."""
    return base_parameters(config_with(cfg, base_values), [r.data for r in records],
                           [c.effect for c in cands], ACQUISITION_DELAY in base_values,
                           cfg.damper.oil_compressibility_per_pa
                           if OIL_COMPRESSIBILITY in base_values else None)


def model_jacobians(cfg: ModelConfig, base_values: Mapping[str, float],
                    accepted: Sequence[tuple[Candidate, Mapping[str, float]]],
                    fit: Sequence[Record], held: Sequence[Record], weights: Sequence[float],
                    n_quasi_static: int) -> tuple[np.ndarray, np.ndarray]:
    """The slopes of a fitted model's force with respect to every parameter a joint fit
    frees there (the paper's, the effects', in normalised coordinates): over the
    identification records ``fit`` weighted as the fit weighs them (the weighted
    residual's Jacobian, :meth:`Space.jacobian`), and over the held-out records
    unweighted, each a matrix of the records' counted samples concatenated."""
    cands = [c for c, _ in accepted]
    values = [dict(v) for _, v in accepted]
    free = free_parameters(cfg, base_values, fit, cands)
    on_fit = Space(cfg, free, base_values, cands, values, [True] * len(cands), fit,
                   weights, n_quasi_static)
    on_held = Space(cfg, free, base_values, cands, values, [True] * len(cands), held,
                    [1.0] * len(held), 0)
    s = on_fit.encode(base_values, values)
    return on_fit.jacobian(s), on_held.jacobian(s)


def _rho(space: Space, sol: OptimizeResult) -> float:
    """The largest lag-1 autocorrelation of the residuals a fit minimised, file by file
    (each quasi-static record at its own friction; :func:`lag1` is scale-free: the
    weighted pieces of the solution's residual vector)."""
    return max(lag1(piece) for piece in np.split(np.asarray(sol.fun), space._ends))
