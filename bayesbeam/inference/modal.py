"""Modal posteriors: natural frequency and damping ratio of each mode, with uncertainty.

The first quantities a damping study looks at are the natural frequency ``f_k`` (Hz) and
the damping ratio ``ζ_k`` of each mode, and how ``ζ_k`` varies with ``f_k``: the damping
laws differ exactly there (physics.md §2, uniform beam):

======================  ==========================================  ===============
law                     damping ratio of mode k                     trend
======================  ==========================================  ===============
viscous (``gamma``)     ``ζ_k = gamma / (2 rhoA ω_k)``               ``ζ ∝ 1/f``
Kelvin–Voigt (``c_d``)  ``ζ_k = c_d ω_k / (2 E)``                    ``ζ ∝ f``
spatial hysteresis      narrow kernel: as Kelvin–Voigt with          between, by
                        ``c_d I = a b² / 2``; wide: rate ~ linear    ``b``
======================  ==========================================  ===============

:func:`modal_posterior` maps evenly spaced posterior draws ``θ`` through the model's
eigenvalues: with ``λ_k`` the k-th eigenvalue of the modal state matrix with ``Im λ > 0``
(sorted by ``|λ|``; :meth:`bayesbeam.physics.forward.Forward.modes`),

    f_k = |λ_k| / 2π,        ζ_k = −Re λ_k / |λ_k|.                                  (1)

For classical (proportional) damping ``|λ_k| = ω_k``, the undamped frequency, exactly,
and ``ζ_k = C_kk / (2 ω_k)``. The posterior of ``(f_k, ζ_k)`` is the image of the
parameter posterior under (1): its quantiles are those of the transformed draws.

Draws that cannot give K modes are counted, never dropped silently:

* ``n_invalid``: the set is outside its admissible range or its eigenvalues are not
  finite;
* ``n_overdamped``: a mode among the first K is overdamped (two real eigenvalues, no
  frequency). An overdamped mode leaves the list of underdamped ones, so the k-th
  underdamped mode would then be mode k+1 of the beam; such a draw is recognised by
  its underdamped ``|λ_k|`` no longer following the undamped ``ω_k`` of the same set
  (mismatch above :data:`MATCH_RTOL`; neighbouring cantilever modes are at least a
  factor 1.4 apart up to mode 7, physics.md §4). Overdamped modes above the first K
  (the mesh's highest modes under Kelvin–Voigt damping) do not affect the record and
  are only mentioned in :attr:`ModalPosterior.notes`.

Models with a nonlinear part (``drag``, ``friction``, ``amplitude_stiffness``,
``sensor_quadratic``: :mod:`bayesbeam.physics.nonlinear`) have no modes of their own:
the record then holds those of their linear part (``source = "linear part"``), i.e. the
small-amplitude frequencies and the amplitude-independent damping; the notes say what
is left out.

:func:`data_modes` measures the same quantities from the record alone (damped-sinusoid
fit, :func:`bayesbeam.trials.modal_id.damped_sinusoids`), for the overlay of
:func:`bayesbeam.inference.modal_plots.plot_zeta_vs_f`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayesbeam._util import INTERVAL_QUANTILES, finite_json, fmt_interval, one_blas_thread

__all__ = [
    "DEFAULT_DRAWS",
    "DataModes",
    "MATCH_RTOL",
    "ModalError",
    "ModalPosterior",
    "data_modes",
    "modal_posterior",
    "spaced_draws",
]

#: Posterior draws mapped through the eigenvalues by default (evenly spaced).
DEFAULT_DRAWS = 400
#: Fewest and most modes of the default K (modes below the sensor band, clipped).
MIN_MODES, MAX_MODES = 2, 6
#: Relative mismatch of ``|λ_k|`` against the undamped ``ω_k`` that marks a draw whose
#: first K underdamped modes are not the beam's first K modes (an overdamped one among them).
MATCH_RTOL = 0.2
#: Draws per batched call of the undamped modal system.
_CHUNK = 100
#: Standard-normal quantile of 0.95: a normal 90 % interval is ``x ± Z90 se``.
Z90 = 1.6448536269514722
#: Summary statistics per quantity, as in :meth:`bayesbeam.inference.results.FitResult.summary`.
_QUANTILES = INTERVAL_QUANTILES


class ModalError(ValueError):
    """Invalid input to the modal posterior; the message says how to fix it."""


def _frozen(a: Any, dtype: Any = float) -> np.ndarray:
    out = np.array(a, dtype=dtype)
    out.setflags(write=False)
    return out


def _stats(x: np.ndarray) -> dict[str, float]:
    """Mean, sd (ddof 1) and 5/50/95 % quantiles of a 1-D sample."""
    q = np.quantile(x, list(_QUANTILES.values()))
    sd = float(np.std(x, ddof=1)) if x.size > 1 else math.nan
    row = {"mean": float(np.mean(x)), "sd": sd}
    row.update({k: float(q[i]) for i, k in enumerate(_QUANTILES)})
    return row


@dataclass(frozen=True, eq=False)
class DataModes:
    """Frequency and damping ratio of each mode measured from the record alone.

    Attributes
    ----------
    frequency_hz : numpy.ndarray, shape (K,)
        Natural frequency ``|λ| / 2π = sqrt(σ² + ω_d²) / 2π`` in Hz (the quantity of
        :class:`ModalPosterior`, not the damped frequency); NaN where not measured.
    frequency_se_hz : numpy.ndarray, shape (K,)
        Its standard error in Hz.
    damping_ratio : numpy.ndarray, shape (K,)
        ``σ / sqrt(σ² + ω_d²)``, dimensionless; NaN where not measured.
    damping_ratio_se : numpy.ndarray, shape (K,)
        Its standard error.
    method : str
        The estimator.
    notes : tuple of str
        Modes not measured and why.
    """

    frequency_hz: np.ndarray
    frequency_se_hz: np.ndarray
    damping_ratio: np.ndarray
    damping_ratio_se: np.ndarray
    method: str = "damped_sinusoids"
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name in ("frequency_hz", "frequency_se_hz", "damping_ratio", "damping_ratio_se"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))

    @property
    def frequency_90(self) -> np.ndarray:
        """Normal 90 % interval of :attr:`frequency_hz`, shape (K, 2), Hz."""
        d = Z90 * self.frequency_se_hz
        return np.column_stack([self.frequency_hz - d, self.frequency_hz + d])

    @property
    def damping_90(self) -> np.ndarray:
        """Normal 90 % interval of :attr:`damping_ratio`, shape (K, 2)."""
        d = Z90 * self.damping_ratio_se
        return np.column_stack([self.damping_ratio - d, self.damping_ratio + d])

    def to_json_dict(self) -> dict[str, Any]:
        """Strict-JSON record: per mode the estimate and its 90 % interval (or None).

        Returns
        -------
        dict
            ``method``, ``notes`` and ``modes``: a list with, per mode, ``mode``
            (1-based), ``frequency_hz``, ``frequency_hz_90`` ([lo, hi]),
            ``damping_ratio``, ``damping_ratio_90``, or ``None`` for a mode not measured.
        """
        fi, zi = self.frequency_90, self.damping_90
        modes: list[dict[str, Any] | None] = []
        for k in range(self.frequency_hz.size):
            if not (np.isfinite(self.frequency_hz[k]) and np.isfinite(self.damping_ratio[k])):
                modes.append(None)
                continue
            modes.append({
                "mode": k + 1,
                "frequency_hz": float(self.frequency_hz[k]),
                "frequency_hz_90": [float(fi[k, 0]), float(fi[k, 1])],
                "damping_ratio": float(self.damping_ratio[k]),
                "damping_ratio_90": [float(zi[k, 0]), float(zi[k, 1])],
            })
        return finite_json({"method": self.method, "notes": list(self.notes), "modes": modes})


def data_modes(
    times: np.ndarray, values: np.ndarray, f0: Sequence[float],
    zeta0: Sequence[float] | None = None,
) -> DataModes:
    """Measure ``f_k`` and ``ζ_k`` of given modes from a free-decay record.

    One damped-sinusoid least-squares fit of all modes together
    (:func:`bayesbeam.trials.modal_id.damped_sinusoids`: frequencies searched within
    ±20 % of ``f0``, standard errors from the Jacobian inflated for residual
    autocorrelation). From its damped frequency ``f_d`` and decay rate ``σ`` of mode k,
    with ``ω_d = 2π f_d`` and ``r = sqrt(σ² + ω_d²) = |λ|``:

        f = r / 2π,   ζ = σ / r,
        se(f)² = ((σ/r) se(σ))² + ((ω_d/r) se(ω_d))² / (2π)²,
        se(ζ)² = ((ω_d²/r³) se(σ))² + ((σ ω_d/r³) se(ω_d))²

    (delta method; the covariance of ``σ`` and ``ω_d`` is neglected: the fit reports
    their standard errors only). Modes at or above 0.8 times the Nyquist frequency of the
    median step are not fitted (a band-limited record holds no such mode reliably).

    Parameters
    ----------
    times, values : array_like, shape (T,)
        The record: stamps in s and signal in SI units.
    f0 : sequence of float, length K
        Starting frequencies in Hz (e.g. the posterior medians).
    zeta0 : sequence of float, optional
        Starting damping ratios (default 1 %).

    Returns
    -------
    DataModes
        NaN entries (and a note) for modes not measured: above the frequency limit,
        amplitude below 5 standard errors, or a failed fit.
    """
    from bayesbeam.trials.modal_id import SignatureError, damped_sinusoids

    t = np.asarray(times, dtype=float)
    f0 = np.asarray(f0, dtype=float)
    K = f0.size
    z0 = np.full(K, 0.01) if zeta0 is None else np.asarray(zeta0, dtype=float)
    out = np.full((4, K), np.nan)
    notes: list[str] = []
    nyq = 0.5 / float(np.median(np.diff(t))) if t.size > 1 else 0.0
    fit_k = np.flatnonzero(np.isfinite(f0) & (f0 > 0) & (f0 < 0.8 * nyq))
    high = sorted(set(range(K)) - set(fit_k.tolist()))
    if high:
        notes.append(f"modes {[k + 1 for k in high]} not measured: at or above 0.8 x the "
                     f"Nyquist frequency ({nyq:.4g} Hz)")
    est: list[Any] = []
    if fit_k.size:
        sig0 = np.clip(np.nan_to_num(z0[fit_k], nan=0.01), 1e-6, 0.5) * 2 * np.pi * f0[fit_k]
        try:
            est = damped_sinusoids(t, np.asarray(values, dtype=float), f0[fit_k], sig0)
        except (SignatureError, ValueError, np.linalg.LinAlgError) as err:
            notes.append(f"damped-sinusoid fit failed: {err}")
            est = [None] * fit_k.size
    missing = []
    for k, e in zip(fit_k, est, strict=True):
        if e is None:
            missing.append(int(k) + 1)
            continue
        s, wd = e.decay_rate, 2 * np.pi * e.frequency
        s_se, wd_se = e.decay_rate_se, 2 * np.pi * e.frequency_se
        r = math.hypot(s, wd)
        out[0, k] = r / (2 * np.pi)
        out[1, k] = math.hypot(s / r * s_se, wd / r * wd_se) / (2 * np.pi)
        out[2, k] = s / r
        out[3, k] = math.hypot(wd**2 / r**3 * s_se, s * wd / r**3 * wd_se)
    if missing:
        notes.append(f"modes {missing} not measurable in the record (amplitude below 5 "
                     "standard errors)")
    return DataModes(*out, notes=tuple(notes))


@dataclass(frozen=True, eq=False)
class ModalPosterior:
    """Posterior of the natural frequencies and damping ratios of the first K modes.

    Attributes
    ----------
    model : str
        Model name of the fit.
    frequency_hz : numpy.ndarray, shape (draws, K)
        ``f_k = |λ_k| / 2π`` in Hz of each usable draw (eq. 1 of the module docstring).
    damping_ratio : numpy.ndarray, shape (draws, K)
        ``ζ_k = −Re λ_k / |λ_k|`` (dimensionless) of the same draws.
    draw_index : numpy.ndarray of int, shape (draws,)
        Index of each usable draw in the flattened chain
        ``result.chain.samples.reshape(-1, ndim)`` (step-major).
    n_requested : int
        Draws evaluated (evenly spaced over the flattened chain).
    n_invalid : int
        Evaluated draws outside the admissible range or with non-finite eigenvalues.
    n_overdamped : int
        Evaluated draws with an overdamped mode among the first K.
    sensor_band_hz : float
        The record's sensor band (Hz; ``inf``: none) that sets the default K.
    source : str
        ``"model"``, or ``"linear part"`` for a model with a nonlinear part.
    notes : tuple of str
        What was excluded or left out, in words.
    reason : str or None
        Why there is no modal posterior (then the arrays have shape (0, 0)); None when
        there is one.
    data : DataModes or None
        The record's own estimates of the same modes, if made.
    """

    model: str
    frequency_hz: np.ndarray
    damping_ratio: np.ndarray
    draw_index: np.ndarray
    n_requested: int
    n_invalid: int = 0
    n_overdamped: int = 0
    sensor_band_hz: float = math.inf
    source: str = "model"
    notes: tuple[str, ...] = ()
    reason: str | None = None
    data: DataModes | None = field(default=None)

    def __post_init__(self) -> None:
        f, z = _frozen(self.frequency_hz), _frozen(self.damping_ratio)
        idx = _frozen(self.draw_index, dtype=np.int64)
        if f.ndim != 2 or z.shape != f.shape or idx.shape != f.shape[:1]:
            raise ModalError(
                f"frequency_hz {f.shape} and damping_ratio {z.shape} must both be "
                f"(draws, K) and draw_index {idx.shape} (draws,)"
            )
        object.__setattr__(self, "frequency_hz", f)
        object.__setattr__(self, "damping_ratio", z)
        object.__setattr__(self, "draw_index", idx)
        object.__setattr__(self, "notes", tuple(self.notes))

    @property
    def available(self) -> bool:
        """True when there is a modal posterior (:attr:`reason` is None)."""
        return self.reason is None and self.frequency_hz.size > 0

    @property
    def n_modes(self) -> int:
        """K, the number of modes."""
        return int(self.frequency_hz.shape[1])

    @property
    def n_draws(self) -> int:
        """Usable draws (rows of the arrays)."""
        return int(self.frequency_hz.shape[0])

    def summary(self) -> list[dict[str, Any]]:
        """Posterior summary per mode.

        Returns
        -------
        list of dict
            Per mode ``{"mode": k (1-based), "frequency_hz": {...}, "damping_ratio":
            {...}}``, each ``{mean, sd, q05, q50, q95}`` of the usable draws (Hz and
            dimensionless); empty when not :attr:`available`.
        """
        if not self.available:
            return []
        return [
            {"mode": k + 1, "frequency_hz": _stats(self.frequency_hz[:, k]),
             "damping_ratio": _stats(self.damping_ratio[:, k])}
            for k in range(self.n_modes)
        ]

    def to_json_dict(self) -> dict[str, Any]:
        """Strict-JSON record for ``summary.json["modes"]`` and ``comparison.json``.

        Returns
        -------
        dict
            ``available``, ``reason``, ``model``, ``source``, ``n_modes``, ``n_draws``
            (usable), ``n_requested``, ``n_invalid``, ``n_overdamped``,
            ``sensor_band_hz`` (None: no band), ``notes``, ``modes`` (:meth:`summary`)
            and ``data`` (:meth:`DataModes.to_json_dict`, or None).
        """
        return finite_json({
            "available": self.available,
            "reason": self.reason,
            "model": self.model,
            "source": self.source,
            "n_modes": self.n_modes if self.available else 0,
            "n_draws": self.n_draws if self.available else 0,
            "n_requested": int(self.n_requested),
            "n_invalid": int(self.n_invalid),
            "n_overdamped": int(self.n_overdamped),
            "sensor_band_hz": float(self.sensor_band_hz),
            "notes": list(self.notes),
            "modes": self.summary(),
            "data": None if self.data is None else self.data.to_json_dict(),
        })

    def __str__(self) -> str:
        if not self.available:
            return f"modes of {self.model}: none ({self.reason})"
        lines = [f"modes of {self.model} ({self.source}; {self.n_draws} of "
                 f"{self.n_requested} draws): median [5 %, 95 %]"]
        for row in self.summary():
            f, z = row["frequency_hz"], row["damping_ratio"]
            fq = fmt_interval(f["q50"], f["q05"], f["q95"], minimum=4)
            zq = fmt_interval(z["q50"], z["q05"], z["q95"])
            lines.append(f"  mode {row['mode']}: f = {fq[0]} Hz [{fq[1]}, {fq[2]}], "
                         f"zeta = {zq[0]} [{zq[1]}, {zq[2]}]")
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


def _unavailable(model: str, reason: str, *, n_requested: int = 0, n_invalid: int = 0,
                 n_overdamped: int = 0, band: float = math.inf, source: str = "model",
                 notes: Sequence[str] = ()) -> ModalPosterior:
    return ModalPosterior(
        model=model, frequency_hz=np.empty((0, 0)), damping_ratio=np.empty((0, 0)),
        draw_index=np.empty(0, dtype=np.int64), n_requested=n_requested, n_invalid=n_invalid,
        n_overdamped=n_overdamped, sensor_band_hz=band, source=source, notes=tuple(notes),
        reason=reason,
    )


def spaced_draws(n_total: int, n_draws: int) -> np.ndarray:
    """Return the indices of ``n_draws`` evenly spaced draws among ``n_total`` (all if fewer).

    Parameters
    ----------
    n_total : int
        Draws in the flattened chain.
    n_draws : int
        Draws wanted, ≥ 1.

    Returns
    -------
    numpy.ndarray of int, shape (min(n_draws, n_total),)
        Increasing, first and last draw included.
    """
    if n_total <= n_draws:
        return np.arange(n_total)
    return np.unique(np.linspace(0, n_total - 1, n_draws).round().astype(np.int64))


def modal_posterior(
    problem: Any,
    result: Any,
    *,
    n_draws: int = DEFAULT_DRAWS,
    n_modes: int | None = None,
    data: bool = True,
) -> ModalPosterior:
    """Posterior of ``f_k`` (Hz) and ``ζ_k`` of the first K modes of a fitted model.

    Parameters
    ----------
    problem : bayesbeam.inference.problem.Problem
        The fitted problem (its forward model, mesh and parameter map; the CLI passes
        the one on the converged mesh).
    result : bayesbeam.inference.results.FitResult
        The fit; its draws are mapped to physical values with its own priors.
    n_draws : int, default :data:`DEFAULT_DRAWS`
        Evenly spaced draws of the flattened chain to evaluate (all when fewer).
    n_modes : int, optional
        K. Default: the median over the draws of the number of modes with
        ``f_k <= problem.trial.sensor_band``, clipped to [2, 6].
    data : bool, default True
        Also measure the same modes from the record (:func:`data_modes`, started at the
        posterior medians) for the overlay.

    Returns
    -------
    ModalPosterior
        With ``reason`` set (and no draws) when the forward model has no modes or no
        draw gives K underdamped modes; excluded draws are counted (module docstring).

    Raises
    ------
    ModalError
        If the result's parameters are not the problem's, or ``n_draws`` / ``n_modes``
        are not positive integers.
    """
    for name, v in (("n_draws", n_draws), ("n_modes", n_modes)):
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, np.integer))
                              or v < 1):
            raise ModalError(f"{name} must be a positive integer, got {v!r}")
    if tuple(result.names) != tuple(problem.names):
        raise ModalError(
            f"the result's parameters {list(result.names)} are not the problem's "
            f"{list(problem.names)}: pass the Problem of that fit"
        )
    model = str(result.model)
    band = float(problem.trial.sensor_band)
    fwd = problem.forward
    # A nonlinear forward model (bayesbeam.physics.nonlinear) wraps its linear part.
    lin = getattr(fwd, "linear", fwd)
    source = "model" if lin is fwd else "linear part"
    notes: list[str] = []
    if lin is not fwd:
        parts = ", ".join(problem.model.nonlinear)
        notes.append(f"modes of the linear part; the nonlinear part ({parts}) is left out: "
                     "frequencies are the small-amplitude ones, damping ratios exclude the "
                     "amplitude-dependent damping")
    if not callable(getattr(lin, "modes", None)):
        return _unavailable(model, f"the forward model of {model!r} has no modes",
                            band=band, source=source, notes=notes)

    nd = result.chain.ndim
    flat = result.chain.samples.reshape(-1, nd)
    idx = spaced_draws(flat.shape[0], int(n_draws))
    X = result.priors.to_theta(flat[idx])  # physical sampled values, as theta_samples()
    P = problem.forward_params(X)  # forward-model columns (a from eta for SH)
    ok = np.asarray(fwd.check(P), dtype=bool)
    cols = [fwd.param_names.index(n) for n in lin.param_names]
    P_lin = P[:, cols]
    n_invalid = int(np.count_nonzero(~ok))
    errors: list[str] = []
    # Undamped ω of every admissible draw (batched): they set the default K (modes below
    # the band) and tell an overdamped mode among the first K (module docstring).
    omega: dict[int, np.ndarray] = {}
    rows_ok = np.flatnonzero(ok)
    with one_blas_thread():  # many small eigenproblems: BLAS threads cost more (_util)
        for s in range(0, rows_ok.size, _CHUNK):
            rows = rows_ok[s : s + _CHUNK]
            w = lin.modal_system(P_lin[rows])[0]
            for i, wi in zip(rows, w, strict=True):
                if np.all(np.isfinite(wi)):
                    omega[int(i)] = wi
                else:
                    ok[i] = False
                    errors.append(f"draw {int(idx[i])}: non-finite undamped frequencies")
    good = np.flatnonzero(ok)
    if good.size == 0:
        n_invalid += len(errors)
        notes += [f"{len(errors)} draws without finite frequencies (first: {errors[0]})"
                  ] if errors else []
        return _unavailable(model, f"none of the {idx.size} draws is admissible",
                            n_requested=idx.size, n_invalid=n_invalid, band=band,
                            source=source, notes=notes)
    m = omega[int(good[0])].size  # modes of the mesh
    if n_modes is None:
        below = [int(np.count_nonzero(omega[i] <= 2 * np.pi * band)) for i in good]
        K = int(min(np.clip(np.median(below), MIN_MODES, MAX_MODES), m))
    elif n_modes > m:
        raise ModalError(f"n_modes = {n_modes}, but the mesh of {problem.n_elements} elements "
                         f"has {m} modes")
    else:
        K = int(n_modes)

    usable = np.zeros(idx.size, dtype=bool)
    freqs = np.full((idx.size, K), np.nan)
    zetas = np.full((idx.size, K), np.nan)
    n_overdamped = n_od_above = 0
    with one_blas_thread():
        for i in good:
            try:
                f, z, n_od = lin.modes(P_lin[i], return_overdamped=True)
            except (ValueError, np.linalg.LinAlgError) as err:  # Forward/PropagationError
                errors.append(str(err))
                continue
            # An overdamped mode below the K-th leaves the list of underdamped ones and
            # shifts it: |λ_k| then no longer follows the undamped ω_k of the same set.
            if n_od > 0 and (f.size < K or np.any(
                    np.abs(2 * np.pi * f[:K] / omega[int(i)][:K] - 1) > MATCH_RTOL)):
                n_overdamped += 1
                continue
            if not (np.all(np.isfinite(f[:K])) and np.all(np.isfinite(z[:K]))):
                errors.append(f"draw {int(idx[i])}: non-finite eigenvalues")
                continue
            n_od_above += int(n_od > 0)
            freqs[i], zetas[i] = f[:K], z[:K]
            usable[i] = True
    n_invalid += len(errors)
    if errors:
        notes.append(f"{len(errors)} draws without finite eigenvalues (first: {errors[0]})")
    if n_overdamped:
        notes.append(f"{n_overdamped} of {idx.size} draws left out: an overdamped mode "
                     f"(no frequency) among the first {K}")
    if n_invalid:
        notes.append(f"{n_invalid} of {idx.size} draws left out: outside the admissible "
                     "range or without finite eigenvalues")
    if n_od_above:
        notes.append(f"{n_od_above} draws have overdamped modes above mode {K} (kept: "
                     "they do not change the first modes)")
    keep = np.flatnonzero(usable)
    if keep.size == 0:
        return _unavailable(model, f"no draw gives {K} underdamped modes",
                            n_requested=idx.size, n_invalid=n_invalid,
                            n_overdamped=n_overdamped, band=band, source=source, notes=notes)
    F, Z = freqs[keep], zetas[keep]
    above = np.flatnonzero(np.median(F, axis=0) > band)
    if above.size:
        notes.append(f"modes {[int(k) + 1 for k in above]} lie above the sensor band "
                     f"({band:.4g} Hz): the record does not constrain them")
    dm = None
    if data:
        tr = problem.trial
        dm = data_modes(tr.times, tr.values, np.median(F, axis=0), np.median(Z, axis=0))
    return ModalPosterior(
        model=model, frequency_hz=F, damping_ratio=Z, draw_index=idx[keep],
        n_requested=int(idx.size), n_invalid=n_invalid, n_overdamped=n_overdamped,
        sensor_band_hz=band, source=source, notes=tuple(notes), data=dm,
    )
