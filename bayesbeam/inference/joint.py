"""The posterior of one model on several trials: shared, pooled and per-trial parameters.

Measurements come in sets (one beam released five times; one strip clamped at several
free lengths). :class:`JointProblem` fits them together. Every trial keeps its own
:class:`~bayesbeam.inference.problem.Problem` (beam, sensor, sampling, quantity, default
priors); the joint sampling space holds

* **shared** parameters (``shared``, e.g. ``E``): one value for every trial, under
  their own name; the prior is the trials' common default prior, or, where the
  trials' defaults differ (records of different length centre the E prior on their
  own first peak), the smallest prior of the same family that holds all of them;
* **pooled** parameters (``pooled``, e.g. ``c_d``): one value per trial drawn from a
  log-normal population (the standard hierarchical model, Gelman et al., *Bayesian
  Data Analysis*, 3rd ed., ch. 5),

      log x_i = log m + s z_i,   z_i ~ N(0, 1),

  with the population median ``m`` (sampled as ``NAME_median``, prior: the trials'
  default prior of ``NAME``) and the spread ``s`` of ``log x`` (``NAME_spread``,
  HalfNormal(1): a factor e between trials at one sd is far beyond the spread of
  repeated releases of one beam, and ``s = 0``, one value for all trials, is inside).
  The sampled coordinates are the non-centred ``z_i`` (``NAME_z[TRIAL]``), so the
  priors stay independent and the evidence integral is over a proper density; the
  sampler itself moves in the centred ``log x_i`` (:class:`PoolCoordinates`), which
  suits trials that each identify their damping well;
* **per-trial** parameters, named ``NAME[TRIAL]`` (every other physical parameter,
  the initial condition and the noise).

An attachment that sits at one distance from the *free end* whatever the clamped length
(a sensor board on a strip clamped at several free lengths) is shared as
``added_mass_tip_distance`` (:data:`TIP_DISTANCE`, m from the tip): trial i's
``added_mass_position`` (from the clamp) is ``L_i - d``, and the prior of ``d`` is
uniform over the distances every trial's position prior allows.

Marginalised nuisance parameters (by default wherever the closed form is exact; always
with ``marginalise=True``, never with False): the noise scale
``sigma`` and the amplitudes the signal is linear in (``w0``, ``p0`` or ``A_k, B_k``)
are integrated out of each trial's likelihood in closed form under their own default
priors (LogUniform on sigma, Uniform on the amplitudes;
:func:`bayesbeam.stats.marginal.marginal_loglik`). The evidence is the same integral as
with them sampled, the sampler has 2-3 fewer dimensions per trial, and exact draws of
them given each posterior sample (:func:`~bayesbeam.stats.marginal.draw_conditional`)
complete the posterior for reporting, predictive checks and LOO. AR(1) noise keeps
``rho`` sampled; given rho the likelihood is whitened (a linear map) and then
marginalised the same way. A sensor offset stays sampled (its prior is Normal, not flat).

Names in ``shared`` and ``pooled`` are those of the sampling space: spatial hysteresis
is sampled as ``eta`` (:mod:`bayesbeam.inference.problem`), so sharing ``eta`` shares the
first-mode hysteresis damping per unit ``c_d I``, not the kernel strength ``a``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from bayesbeam.inference.problem import Problem, amplitude_names
from bayesbeam.physics.models import Model, parse_model
from bayesbeam.stats.families import HalfNormal, LogNormal, LogUniform, Normal, Prior, Uniform
from bayesbeam.stats.marginal import ar1_whiten, draw_conditional, marginal_loglik
from bayesbeam.stats.priors import PriorSet
from bayesbeam.trials.trial import Trial

__all__ = ["TIP_DISTANCE", "JointError", "JointProblem", "PoolCoordinates", "trial_labels"]

#: Scale of the HalfNormal prior of a pooled parameter's spread (sd of its log).
SPREAD_SCALE = 1.0


class JointError(ValueError):
    """A joint fit cannot be set up as asked; the message says how to fix it."""


def trial_labels(trials: Sequence[Trial]) -> tuple[str, ...]:
    """Short unique labels of trials (their names; ``NAME#2``, ... for repeats).

    Parameters
    ----------
    trials : sequence of Trial

    Returns
    -------
    tuple of str
    """
    out: list[str] = []
    for t in trials:
        name = str(t.name) or "trial"
        label, k = name, 1
        while label in out:
            k += 1
            label = f"{name}#{k}"
        out.append(label)
    return tuple(out)


def _envelope(priors: Sequence[Prior], name: str) -> Prior:
    """Return the trials' common prior of a shared parameter (see the module docstring)."""
    first = priors[0]
    if all(p == first for p in priors):
        return first
    if all(isinstance(p, LogUniform) for p in priors):
        return LogUniform(min(p.lo for p in priors), max(p.hi for p in priors))
    if all(isinstance(p, Uniform) for p in priors):
        return Uniform(min(p.lo for p in priors), max(p.hi for p in priors))
    raise JointError(
        f"the trials' priors of the shared parameter {name!r} differ and are not all "
        f"LogUniform or all Uniform ({[p.to_dict() for p in priors]}); give one prior for it"
    )


#: The shared distance of an added mass from the free end (m), for trials of different
#: free length (see the module docstring).
TIP_DISTANCE = "added_mass_tip_distance"


def _tip_distance_prior(problems: Sequence[Problem]) -> Prior:
    """Uniform prior of ``d = L_i - x_i`` that every trial's Uniform prior on ``x_i`` allows."""
    lo, hi = 0.0, math.inf
    for pb in problems:
        p = pb.priors["added_mass_position"]
        if not isinstance(p, Uniform):
            raise JointError(
                f"{TIP_DISTANCE} needs a Uniform prior on added_mass_position; trial "
                f"{pb.trial.name!r} has {p.to_dict()}")
        length = float(pb.trial.beam.length)
        lo, hi = max(lo, length - p.hi), min(hi, length - p.lo)
    if not hi > lo:
        raise JointError(f"the trials' added_mass_position priors allow no common distance "
                         f"from the tip ({TIP_DISTANCE}); widen them")
    return Uniform(lo, hi)


class JointProblem:
    """Log posterior of one model on several trials, vectorised over parameter sets.

    Parameters
    ----------
    trials : sequence of Trial
        The records (SI units); they may differ in beam, sensor, sampling and quantity.
    model : str or Model
        The same model for every trial.
    shared : iterable of str
        Sampled names with one value for all trials (e.g. ``("E",)``); with an added
        mass, :data:`TIP_DISTANCE` shares its distance from the free end instead of
        ``added_mass_position`` (trials of different length).
    pooled : iterable of str
        Sampled names drawn per trial from a log-normal population; their default
        prior must be on ``log x`` (LogUniform: damping, masses, root spring, b).
    marginalise : bool or None
        Integrate sigma and the initial-condition amplitudes out (module docstring).
        None (the default) does so wherever the closed form is exact and samples them
        otherwise (an amplitude-dependent model, sigma or an amplitude shared or pooled,
        a prior on them other than LogUniform / Uniform); :attr:`marginal_note` says
        which and why. True insists (a :class:`JointError` where it cannot be exact).
    n_elements : int
        Hermite elements of every trial's forward model.
    initial : str or sequence of str
        Initial-condition kind (:class:`bayesbeam.physics.forward.Forward`), one for all
        trials or one per trial (records of different length resolve different numbers
        of modes: ``modes:k`` each; their amplitude names then differ between trials).
    priors : mapping of name -> Prior or dict, optional
        Overrides of the default priors (:func:`~bayesbeam.inference.problem.default_priors`),
        by a single trial's parameter names, applied to every trial. A shared name's
        prior is then this one; a pooled name's sets its population median's prior.

    Raises
    ------
    JointError
        On no trials, unknown, overlapping or unpoolable names, or a prior that cannot
        be marginalised in closed form.
    ValueError
        On an override of a name the model does not have, or an invalid prior.
    """

    def __init__(
        self,
        trials: Sequence[Trial],
        model: str | Model,
        *,
        shared: Iterable[str] = ("E",),
        pooled: Iterable[str] = (),
        marginalise: bool | None = None,
        n_elements: int = 16,
        initial: str | Sequence[str] = "release",
        priors: Mapping[str, Any] | None = None,
    ) -> None:
        trials = list(trials)
        if not trials:
            raise JointError("a joint fit needs at least one trial")
        self.trials = tuple(trials)
        self.model = parse_model(model)
        self.labels = trial_labels(trials)
        self.n_elements = int(n_elements)
        initials = [initial] * len(trials) if isinstance(initial, str) else list(initial)
        if len(initials) != len(trials):
            raise JointError(f"{len(initials)} initial conditions for {len(trials)} trials; "
                             "give one for all or one per trial")
        #: One kind for all trials (str), or the kinds per trial (tuple) where they differ.
        self.initial: str | tuple[str, ...] = (
            initials[0] if len(set(initials)) == 1 else tuple(initials))
        self.overrides = dict(priors or {})
        self.problems = tuple(Problem(t, self.model, self.overrides or None,
                                      n_elements=self.n_elements, initial=ini)
                              for t, ini in zip(trials, initials, strict=True))
        # The names every trial has (the amplitudes differ where the initial kinds do).
        base = [n for n in self.problems[0].names
                if all(n in pb.names for pb in self.problems[1:])]
        self.shared = tuple(dict.fromkeys(shared))
        self.pooled = tuple(dict.fromkeys(pooled))
        margs = [("sigma", *amplitude_names(pb.names)) for pb in self.problems]
        marg = tuple(dict.fromkeys(n for m in margs for n in m))
        obstacle = self._marginal_obstacle(marg)
        if marginalise and obstacle is not None:
            raise JointError(f"{obstacle}; fit with marginalise=False (--no-marginalise) to "
                             "sample them")
        #: Whether sigma and the amplitudes are integrated out.
        self.marginalise = obstacle is None if marginalise is None else bool(marginalise)
        #: One line on how sigma and the amplitudes are handled, and why.
        self.marginal_note = (
            "sigma and the amplitudes integrated out in closed form" if self.marginalise
            else "sigma and the amplitudes sampled (marginalise=False)" if marginalise is False
            else f"sigma and the amplitudes sampled: {obstacle}")
        if not self.marginalise:
            margs, marg = [() for _ in self.problems], ()
        self._check_names(base)
        self.marginalised = marg
        entries: list[tuple[str, Prior]] = []
        for n in self.shared:
            entries.append((n, _tip_distance_prior(self.problems) if n == TIP_DISTANCE
                            else _envelope([pb.priors[n] for pb in self.problems], n)))
        for n in self.pooled:
            entries.append((f"{n}_median", _envelope([pb.priors[n] for pb in self.problems], n)))
            entries.append((f"{n}_spread", HalfNormal(SPREAD_SCALE)))
        for label, pb, m in zip(self.labels, self.problems, margs, strict=True):
            for n in pb.names:
                if n in self.pooled:
                    entries.append((f"{n}_z[{label}]", Normal(0.0, 1.0)))
                elif n not in self.shared and n not in m and not self._from_tip(n):
                    entries.append((f"{n}[{label}]", pb.priors[n]))
        self.priors = PriorSet(entries)
        self.names = self.priors.names
        col = {n: j for j, n in enumerate(self.names)}
        # Per trial and per column of its Problem: where the value comes from.
        self._src: list[list[tuple[Any, ...]]] = []
        for label, pb, m in zip(self.labels, self.problems, margs, strict=True):
            src: list[tuple[Any, ...]] = []
            for n in pb.names:
                if self._from_tip(n):
                    src.append(("tip", col[TIP_DISTANCE], float(pb.trial.beam.length)))
                elif n in self.shared:
                    src.append(("col", col[n]))
                elif n in self.pooled:
                    src.append(("pool", col[f"{n}_median"], col[f"{n}_spread"],
                                col[f"{n}_z[{label}]"]))
                elif n in m:
                    src.append(("marg",))
                else:
                    src.append(("col", col[f"{n}[{label}]"]))
            self._src.append(src)
        # Per trial: columns of its Problem (they differ where the initial kinds do).
        self._lin = [[pb.names.index(n) for n in amplitude_names(pb.names)]
                     for pb in self.problems]
        self._marg_mask = [np.array([n in m for n in pb.names])
                           for pb, m in zip(self.problems, margs, strict=True)]
        self._sigma = [pb.names.index("sigma") for pb in self.problems]
        self._offset = [pb.names.index("offset") if "offset" in pb.names else None
                        for pb in self.problems]
        self._rho = [pb.names.index("rho") if "rho" in pb.names else None
                     for pb in self.problems]

    def _from_tip(self, name: str) -> bool:
        """Whether ``name`` (a trial's column) comes from the shared :data:`TIP_DISTANCE`."""
        return name == "added_mass_position" and TIP_DISTANCE in self.shared

    def _marginal_obstacle(self, marg: Sequence[str]) -> str | None:
        """Why sigma and the amplitudes cannot be integrated out exactly (None: they can)."""
        for kind, names in (("shared", self.shared), ("pooled", self.pooled)):
            clash = [n for n in names if n in marg]
            if clash:
                return f"{clash} are {kind}, so they cannot be integrated out of each trial"
        if self.model.nonlinear:
            # Drag, friction and an amplitude-dependent frequency make the signal depend
            # on the amplitudes nonlinearly (physics.md §3): the Gaussian integral over
            # them is no longer exact, and a unit-amplitude basis would be nonsense.
            return (f"model {self.model.name!r} has amplitude-dependent parts "
                    f"{list(self.model.nonlinear)}: its signal is not linear in the modal "
                    "amplitudes, so they cannot be integrated out in closed form")
        for pb in self.problems:
            if not isinstance(pb.priors["sigma"], LogUniform):
                return (f"sigma of {pb.trial.name!r} has prior "
                        f"{pb.priors['sigma'].to_dict()}, and the closed-form marginal needs "
                        "LogUniform")
            for n in amplitude_names(pb.names):
                if not isinstance(pb.priors[n], Uniform):
                    return (f"{n} of {pb.trial.name!r} has prior {pb.priors[n].to_dict()}, "
                            "and the closed-form marginal needs a Uniform prior on the "
                            "amplitudes")
        return None

    def record(self) -> dict[str, Any]:
        """How the trials are joined, for the summary and the posterior's attributes.

        Returns
        -------
        dict
            ``labels``, ``shared``, ``pooled``, ``marginalised`` (lists of str) and
            ``marginal_note`` (str).
        """
        return {"labels": list(self.labels), "shared": list(self.shared),
                "pooled": list(self.pooled), "marginalised": list(self.marginalised),
                "marginal_note": self.marginal_note}

    def _check_names(self, base: Sequence[str]) -> None:
        if TIP_DISTANCE in self.shared:
            if "added_mass_position" not in base:
                raise JointError(f"{TIP_DISTANCE} needs a model with added_mass; model "
                                 f"{self.model.name!r} has none")
            if "added_mass_position" in (*self.shared, *self.pooled):
                raise JointError(f"share either added_mass_position (from the clamp) or "
                                 f"{TIP_DISTANCE} (from the tip), not both; pool neither")
            base = [*base, TIP_DISTANCE]
        both = sorted(set(self.shared) & set(self.pooled))
        if both:
            raise JointError(f"{both} are both shared and pooled; name each in one list only")
        for kind, names in (("shared", self.shared), ("pooled", self.pooled)):
            bad = [n for n in names if n not in base]
            if bad:
                raise JointError(
                    f"{kind} parameters {bad} are not parameters of model "
                    f"{self.model.name!r}; its parameters are {list(base)} "
                    "(spatial hysteresis is sampled as 'eta')"
                )
        for n in self.pooled:
            pri = [pb.priors[n] for pb in self.problems]
            if not all(isinstance(p, (LogUniform, LogNormal, HalfNormal)) for p in pri):
                raise JointError(
                    f"pooled parameter {n!r} needs a prior on log {n} (positive values, "
                    f"e.g. LogUniform), got {pri[0].to_dict()}; pool a damping, mass or "
                    "spring parameter"
                )

    # -- parameter maps ---------------------------------------------------------------
    @property
    def ndim(self) -> int:
        """Number of sampled parameters."""
        return len(self.names)

    @property
    def n_calls(self) -> int:
        """Forward-model parameter sets evaluated, summed over the trials."""
        return sum(pb.n_calls for pb in self.problems)

    def theta(self, U: np.ndarray) -> np.ndarray:
        """Physical values of the sampled parameters, shape (k, ndim)."""
        return self.priors.to_theta(np.atleast_2d(U))

    def trial_theta(self, X: np.ndarray, i: int) -> np.ndarray:
        """Trial ``i``'s values in the column order of its own :class:`Problem`.

        Parameters
        ----------
        X : ndarray, shape (k, ndim)
            Output of :meth:`theta`.
        i : int
            Trial index.

        Returns
        -------
        ndarray, shape (k, problems[i].ndim)
            Marginalised columns hold NaN (see :meth:`complete`).
        """
        X = np.atleast_2d(X)
        out = np.full((X.shape[0], self.problems[i].ndim), np.nan)
        for j, s in enumerate(self._src[i]):
            if s[0] == "col":
                out[:, j] = X[:, s[1]]
            elif s[0] == "tip":
                out[:, j] = s[2] - X[:, s[1]]
            elif s[0] == "pool":
                with np.errstate(over="ignore"):  # inf: an invalid set, masked by the caller
                    out[:, j] = X[:, s[1]] * np.exp(X[:, s[2]] * X[:, s[3]])
        return out

    def joint_theta(self, Xs: Sequence[np.ndarray]) -> np.ndarray:
        """Joint sampled values from per-trial ones (the inverse of :meth:`trial_theta`).

        A shared parameter takes the median of the trials' values; a pooled one's median
        is the geometric mean, its spread the sd of the logs (at least 0.05), and
        ``z_i`` follow. Used to start the joint MAP from single-trial MAPs.

        Parameters
        ----------
        Xs : sequence of ndarray, shape (problems[i].ndim,)
            One point per trial in its Problem's physical values.

        Returns
        -------
        ndarray, shape (ndim,)
        """
        pbs = self.problems
        x = np.full(self.ndim, np.nan)
        for n in self.shared:
            if n == TIP_DISTANCE:
                x[self.names.index(n)] = np.median([
                    float(pb.trial.beam.length) - X[pb.names.index("added_mass_position")]
                    for pb, X in zip(pbs, Xs, strict=True)])
                continue
            x[self.names.index(n)] = np.median([X[pb.names.index(n)]
                                                for pb, X in zip(pbs, Xs, strict=True)])
        for n in self.pooled:
            logs = np.log([X[pb.names.index(n)] for pb, X in zip(pbs, Xs, strict=True)])
            m, s = float(np.mean(logs)), max(float(np.std(logs)), 0.05)
            x[self.names.index(f"{n}_median")] = np.exp(m)
            x[self.names.index(f"{n}_spread")] = s
            for label, v in zip(self.labels, logs, strict=True):
                x[self.names.index(f"{n}_z[{label}]")] = (v - m) / s
        for label, pb, X in zip(self.labels, pbs, Xs, strict=True):
            for j, n in enumerate(pb.names):
                key = f"{n}[{label}]"
                if key in self.names:
                    x[self.names.index(key)] = X[j]
        return x

    # -- densities ---------------------------------------------------------------------
    def _linear_system(self, i: int, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return data, basis responses and validity of trial ``i`` at sets ``X`` (its columns).

        Returns ``y`` (k, T) (data minus the offset, minus the fixed response when the
        model has no linear amplitudes), ``B`` (k, T, p) and ``valid`` (k,).
        """
        pb, lin, j_off = self.problems[i], self._lin[i], self._offset[i]
        k = X.shape[0]
        Xb = X.copy()
        Xb[:, self._sigma[i]] = 1.0  # not used by the signal; keeps the row finite
        Xb[:, lin] = 0.0
        off = None
        if j_off is not None:
            off = Xb[:, j_off].copy()
            Xb[:, j_off] = 0.0
        # The data themselves (finite, checked on reading) as a read-only view unless an
        # offset or a fixed response is taken off.
        y = np.broadcast_to(pb.data, (k, pb.data.size))
        y_changed = off is not None or not lin
        if off is not None:
            y = y - off[:, None]
        valid = np.ones(k, dtype=bool)
        if not lin:
            res = pb.predict(Xb)
            valid &= res.valid
            y = y - np.where(res.valid[:, None], res.y, 0.0)
        if lin:
            # One modal system and band reduction per set for all p responses.
            res = pb.predict_basis(Xb, lin)
            valid &= res.valid
            B = res.y  # rows of invalid sets are zero
        else:
            B = np.zeros((k, pb.data.size, 0))
        # A response beyond 1e100 (SI) is no beam's; its squares would overflow.
        valid &= np.all(np.abs(B) < 1e100, axis=(1, 2))
        if y_changed:
            valid &= np.all(np.abs(y) < 1e100, axis=1)
        pb.n_calls += k
        return y, B, valid

    def _whiten(self, i: int, X: np.ndarray, y: np.ndarray,
                B: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | float]:
        """AR(1) whitening of trial ``i`` at the sets' rho (identity for i.i.d. noise)."""
        if self._rho[i] is None:
            return y, B, 0.0
        pb = self.problems[i]
        times = None if pb.trial.is_uniform else pb.trial.times
        rho = X[:, self._rho[i]]
        yw, log_det = ar1_whiten(y, rho, times=times)
        Bw = np.moveaxis(ar1_whiten(np.moveaxis(B, -1, 0), rho, times=times)[0], 0, -1)
        return yw, Bw, log_det

    def _bounds(self, i: int) -> tuple[float, float, float]:
        """Return the sigma prior bounds and the log volume of trial ``i``'s amplitude box."""
        pri = self.problems[i].priors
        sig = pri["sigma"]
        base = self.problems[i].names
        log_volume = float(sum(np.log(pri[base[j]].hi - pri[base[j]].lo) for j in self._lin[i]))
        return float(sig.lo), float(sig.hi), log_volume

    def trial_log_likelihood(self, X: np.ndarray, i: int) -> np.ndarray:
        """Log likelihood of trial ``i`` (marginal when marginalising), shape (k,).

        Parameters
        ----------
        X : ndarray, shape (k, ndim)
            Joint physical values (output of :meth:`theta`).
        i : int

        Returns
        -------
        ndarray, shape (k,)
            ``-inf`` for sets the forward model marks invalid.
        """
        Xi = self.trial_theta(X, i)
        out = np.full(Xi.shape[0], -np.inf)
        # A pooled value overflowed (z far out in the tails): density zero, not NaN.
        fin = np.all(np.isfinite(Xi) | self._marg_mask[i], axis=1)
        if not np.any(fin):
            return out
        if not np.all(fin):
            out[fin] = self.trial_log_likelihood(X[fin], i)
            return out
        if not self.marginalise:
            return self.problems[i].log_likelihood_theta(Xi)
        y, B, valid = self._linear_system(i, Xi)
        if np.any(valid):
            v = slice(None) if valid.all() else valid  # no copies in the usual case
            yw, Bw, log_det = self._whiten(i, Xi[v], y[v], B[v])
            lo, hi, vol = self._bounds(i)
            out[v] = marginal_loglik(yw, Bw, lo, hi, vol, log_det=log_det)
        return out

    def log_likelihood(self, U: np.ndarray) -> np.ndarray:
        """Joint log likelihood, the sum over trials, shape (k,)."""
        X = self.theta(np.atleast_2d(U))
        total = np.zeros(X.shape[0])
        for i in range(len(self.problems)):
            ok = np.isfinite(total)
            if not np.any(ok):
                break
            part = np.full(X.shape[0], -np.inf)
            part[ok] = self.trial_log_likelihood(X[ok], i)
            total = total + part
        return total

    def log_prob(self, U: np.ndarray) -> np.ndarray:
        """Unnormalised log posterior in the sampling space, shape (k,).

        ``log_prior_u(U) + log_likelihood(U)``; its integral over u is the evidence
        (with sigma and the amplitudes marginalised: the same evidence as with them
        sampled, their priors included).
        """
        return self.priors.log_posterior_u(U, self.log_likelihood)

    __call__ = log_prob

    def complete(self, U: np.ndarray, rng: np.random.Generator) -> list[np.ndarray]:
        """Every trial's full parameter sets, marginalised columns drawn exactly.

        Given each point, sigma and the amplitudes of each trial are drawn from their
        conditional posterior (:func:`bayesbeam.stats.marginal.draw_conditional`), so
        the output are draws from the joint posterior of all parameters when ``U``
        are posterior draws.

        Parameters
        ----------
        U : ndarray, shape (k, ndim)
        rng : numpy.random.Generator

        Returns
        -------
        list of ndarray, shape (k, problems[i].ndim)
            Trial ``i``'s values in its Problem's columns (physical units); rows of
            invalid sets hold NaN in the marginalised columns.
        """
        X = self.theta(np.atleast_2d(U))
        out = []
        for i in range(len(self.problems)):
            Xi = self.trial_theta(X, i)
            if self.marginalise:
                y, B, valid = self._linear_system(i, Xi)
                if np.any(valid):
                    yw, Bw, _ = self._whiten(i, Xi[valid], y[valid], B[valid])
                    lo, hi, _ = self._bounds(i)
                    sigma, alpha = draw_conditional(yw, Bw, lo, hi, rng)
                    rows = np.flatnonzero(valid)
                    Xi[rows, self._sigma[i]] = sigma
                    for c, j in enumerate(self._lin[i]):
                        Xi[rows, j] = alpha[:, c]
            out.append(Xi)
        return out

    def log_likelihood_pointwise(self, U: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Pointwise log likelihood of completed draws, trials concatenated, shape (k, ΣT).

        Each trial's terms are :meth:`Problem.log_likelihood_pointwise` at the completed
        parameters (:meth:`complete`), in trial order.

        Parameters
        ----------
        U : ndarray, shape (k, ndim)
        rng : numpy.random.Generator
            For the draws of the marginalised parameters.

        Returns
        -------
        ndarray, shape (k, sum of the trials' T)
        """
        Xs = self.complete(U, rng)
        parts = []
        for pb, Xi in zip(self.problems, Xs, strict=True):
            part = np.full((Xi.shape[0], pb.data.size), -np.inf)
            ok = np.all(np.isfinite(Xi), axis=1)
            if np.any(ok):
                part[ok] = pb.log_likelihood_pointwise(pb.priors.to_u(Xi[ok]))
            parts.append(part)
        return np.concatenate(parts, axis=1)


class PoolCoordinates:
    """Centred sampler coordinates of the pooled parameters.

    The priors hold the non-centred ``z_i`` (module docstring); the ensemble moves in
    ``v_i = u_median + exp(u_spread) z_i = log x_i`` instead, where a trial that
    identifies its own value makes a straight ridge (fixed ``v_i``) rather than the
    curved ``z_i ∝ 1/s`` of the non-centred form. The map's Jacobian is
    ``|∂v/∂u| = s^n`` (n trials), so ``log p_v(v) = log p_u(u(v)) - n u_spread``.

    Parameters
    ----------
    problem : JointProblem
    """

    def __init__(self, problem: JointProblem) -> None:
        names = problem.names
        self.groups = [
            (names.index(f"{n}_median"), names.index(f"{n}_spread"),
             np.array([names.index(f"{n}_z[{lb}]") for lb in problem.labels]))
            for n in problem.pooled
        ]

    @property
    def identity(self) -> bool:
        """True when nothing is pooled (the sampler works in ``u`` itself)."""
        return not self.groups

    def to_v(self, U: np.ndarray) -> np.ndarray:
        """Map sampling-space points to sampler coordinates, shape kept."""
        V = np.array(U, dtype=float)
        for m, s, z in self.groups:
            V[..., z] = U[..., m, None] + np.exp(U[..., s, None]) * U[..., z]
        return V

    def to_u(self, V: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`to_v`."""
        U = np.array(V, dtype=float)
        for m, s, z in self.groups:
            U[..., z] = (V[..., z] - V[..., m, None]) * np.exp(-V[..., s, None])
        return U

    def log_jacobian(self, V: np.ndarray) -> np.ndarray:
        """``log |∂u/∂v|`` at sampler points, shape V.shape[:-1]."""
        V = np.asarray(V, dtype=float)
        out = np.zeros(V.shape[:-1])
        for _, s, z in self.groups:
            out -= z.size * V[..., s]
        return out
