"""Model adequacy: whether the fitted model reproduces the data to its noise.

A posterior can be tight, converged and wrong: when the model cannot follow the data,
the noise σ absorbs the misfit and the parameters move to whatever fits best. The checks
here need no truth; each compares the fit with something the data say on their own
(posterior-predictive checking, Gelman, Meng & Stern 1996, Statistica Sinica 6, 733-807):

* **noise level** — the fitted σ against a noise floor estimated from the record alone
  by free damped sinusoids (:func:`bayesbeam.trials.noise.noise_floor`). A ratio above
  :data:`LIMITS` ``noise_ratio`` (1.2) means a systematic misfit whose RMS exceeds
  ``sqrt(1.2² - 1) = 0.66`` of the noise;
* **whiteness** — the Ljung–Box test (Ljung & Box 1978) on the standardised innovations
  (:func:`bayesbeam.stats.likelihood.standardized_innovations`: residuals over σ, or the
  one-step AR(1) prediction errors) at the posterior-median signal, 20 lags, inside the
  sensor band (:func:`in_band`: a decimated record's noise is white only there);
* **spectral lines** — Fisher's (1929) g test on the same innovations: a periodic
  component the model left out (a mode, a harmonic, mains pickup) with its frequency;
* **predictive coverage** — the share of samples inside the central 90 % posterior-
  predictive interval, against 0.9 ± (3 binomial sd + 2 / draws);
* **prior bounds** (:func:`prior_bound_pileup`) — for each prior with finite bounds in
  the sampling space ``u``, the share of posterior draws within 1 % of the prior range
  (:data:`LIMITS` ``bound_edge``) from a bound. A posterior flat up to the bound puts
  1 % there; above 10 % (``bound_share``) the likelihood still rises at the bound: the
  data want values the prior excludes and the interval is the prior's, not the data's.
  A bound that is a physical limit, not a choice, is an answer when the posterior sits
  on it: zero of a prior uniform in linear space (no correlation, no damping term), and
  the span's ends for a position (:data:`PHYSICAL_BOUNDS`);
* **explained variance** — ``R² = 1 - σ² / var(y)`` (σ the posterior median noise sd,
  the residuals' marginal sd also with AR(1) noise). Below 0.5 (``explained_min``) the
  "noise" is as large as the signal: the model follows little of the record (or the
  record holds little beyond noise), whatever the other checks say.

Both tests reject at p < 10⁻³ (:data:`LIMITS` ``p_min``), so an adequate model is
flagged by chance in about 0.2 % of fits. On non-uniform stamps the tests treat the
series as evenly spaced at the mean step (jitter blurs a line, it does not create one);
on a uniform grid with holes, as the whole grid with zeros in the holes.
When any check fails the record says so in one line (``summary``): the intervals are
then conditional on a model the data reject, and ``bayesbeam diagnose`` looks for the
missing effect.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from bayesbeam.inference.predictive import posterior_predictive
from bayesbeam.physics.inputs import grid_with_holes
from bayesbeam.stats.families import Uniform
from bayesbeam.stats.likelihood import standardized_innovations
from bayesbeam.stats.whiteness import fisher_g, ljung_box
from bayesbeam.trials.noise import noise_floor

__all__ = ["LIMITS", "PHYSICAL_BOUNDS", "assess", "in_band", "prior_bound_pileup"]

#: Decision limits of :func:`assess` (see the module docstring for their meaning).
LIMITS = {"noise_ratio": 1.2, "p_min": 1e-3, "coverage": 0.9, "lags": 20,
          "bound_edge": 0.01, "bound_share": 0.10, "explained_min": 0.5}

#: Parameters whose prior bounds (both) are physical limits, not choices: a posterior on
#: them is an answer (an added mass at the clamp or at the free end), not a prior problem.
PHYSICAL_BOUNDS = frozenset({"added_mass_position"})


def in_band(z: np.ndarray, dt: float, band: float) -> tuple[np.ndarray, float]:
    """Return the part of a series inside the sensor band, resampled to twice the band.

    A record decimated by an anti-alias filter (or taken through a sensor's own) has
    noise that is white inside its band and falls off above it: tested as it is, the
    residual of a perfect model fails a whiteness test. Keeping the Fourier
    coefficients up to ``band`` and transforming back on ``2 (m - 1)`` points (m the
    coefficients kept) gives a series sampled at about twice the band whose spectrum
    is the in-band one, white when the in-band noise is; a sinusoid keeps its
    amplitude (the back transform is scaled by the length ratio).

    Parameters
    ----------
    z : ndarray, shape (n,)
        Evenly spaced series (e.g. standardised innovations).
    dt : float
        Its step in s.
    band : float
        Band edge in Hz.

    Returns
    -------
    tuple of (ndarray, float)
        The in-band series and its step in s; ``z`` itself when the band reaches
        90 % of the Nyquist frequency.
    """
    n = z.size
    if not np.isfinite(band) or band >= 0.45 / dt:
        return z, dt
    m = int(np.floor(band * n * dt)) + 1  # Fourier frequencies k / (n dt) <= band
    if m < 8:
        return z, dt
    n_out = 2 * (m - 1)
    zb = np.fft.irfft(np.fft.rfft(z)[:m], n_out) * (n_out / n)
    return zb, dt * n / n_out


def prior_bound_pileup(priors: Any, u: np.ndarray, *, edge: float = LIMITS["bound_edge"],
                       share: float = LIMITS["bound_share"]) -> list[dict[str, Any]]:
    """Prior bounds on which the posterior piles up (see the module docstring).

    Parameters
    ----------
    priors : bayesbeam.stats.priors.PriorSet
        The fit's priors (column order of ``u``).
    u : ndarray, shape (..., ndim)
        Posterior draws in the sampling space.
    edge : float
        Width of the zone at each bound, as a fraction of the prior range in ``u``.
    share : float
        Least share of draws in the zone that counts as a pile-up.

    Returns
    -------
    list of dict
        One per pile-up: ``param``, ``side`` ('lower' or 'upper'), ``bound`` (physical
        units), ``share`` (fraction of draws within ``edge`` of the range from it).
        Priors unbounded in ``u`` and physical limits (zero of a uniform prior,
        :data:`PHYSICAL_BOUNDS`) are not tested.
    """
    u = np.asarray(u, dtype=float).reshape(-1, len(priors))
    out = []
    for j, (name, prior) in enumerate(priors.items()):
        lo, hi = prior.bounds_u
        if not (math.isfinite(lo) and math.isfinite(hi)) or name in PHYSICAL_BOUNDS:
            continue
        width = hi - lo
        for side, at, near in (("lower", 0, u[:, j] <= lo + edge * width),
                               ("upper", 1, u[:, j] >= hi - edge * width)):
            bound = float(prior.bounds[at])
            if isinstance(prior, Uniform) and bound == 0.0:
                continue  # zero in linear space: "none of it" is an answer
            s = float(np.mean(near))
            if s > share:
                out.append({"param": name, "side": side, "bound": bound, "share": s})
    return out


def _fmt_p(p: float) -> str:
    return f"p = {p:.1e}" if p >= 1e-300 else "p < 1e-300"


def assess(problem: Any, result: Any, *, rng: np.random.Generator,
           n_draws: int = 200) -> dict[str, Any]:
    """Posterior-predictive adequacy checks of one fit (no truth needed).

    Parameters
    ----------
    problem : bayesbeam.inference.problem.Problem
        The problem that was fitted.
    result : bayesbeam.inference.results.FitResult
        Its posterior.
    rng : numpy.random.Generator
        Source of the predictive noise draws.
    n_draws : int
        Posterior draws for the predictive band (evenly spaced along the chain).

    Returns
    -------
    dict
        ``ok`` (bool), ``reasons`` (list of str, empty when ok), ``summary`` (one line),
        ``sigma`` (posterior median σ, SI units of the quantity), ``noise_floor`` (σ
        estimated from the record alone), ``noise_ratio``, ``noise_floor_frequencies``
        (Hz), ``residual_rms``, ``ljung_box`` (``{"q", "p", "lags"}``),
        ``spectral_line`` (``{"frequency_hz", "amplitude_sigma", "p"}``),
        ``coverage_90`` and ``coverage_band`` ([lo, hi]), ``n_draws``, ``limits``,
        ``prior_bounds`` (list of ``{"param", "side", "bound", "share"}``, the prior
        bounds the posterior piles on, :func:`prior_bound_pileup`) and
        ``explained_variance`` (``1 - σ² / var(y)``).
    """
    trial = problem.trial
    y = np.asarray(problem.data, dtype=float)
    n = y.size
    _, y_model, y_rep = posterior_predictive(problem, result, n_draws, rng, select="spaced")
    names = list(problem.names)
    X = result.theta_samples().reshape(-1, len(names))
    sigma = float(np.median(X[:, names.index("sigma")]))
    rho = float(np.median(X[:, names.index("rho")])) if "rho" in names else None
    r = y - np.median(y_model, axis=0)
    times = None if trial.is_uniform else trial.times
    z = standardized_innovations(r, sigma, rho, times=times)

    floor = noise_floor(trial.times, y, bandwidth=trial.sensor_band)
    ratio = sigma / floor.sd if floor.sd > 0 else math.inf
    # A uniform grid with holes (resampled around gaps): the tests run on the whole grid
    # with the missing innovations set to 0, which keeps white noise white.
    holes = None if trial.is_uniform else grid_with_holes(trial.times - trial.times[0])
    if holes is None:
        zg, step = z, trial.dt
    else:
        step, index = holes
        zg = np.zeros(int(index[-1]) + 1)
        zg[index] = z
    zb, dtb = in_band(zg, step, trial.sensor_band)
    nb = zb.size
    lags = int(min(LIMITS["lags"], max(1, nb // 5)))
    q, p_lb = ljung_box(zb, lags)
    g, p_line, k = fisher_g(zb)
    f_line = k / (nb * dtb)
    # A sinusoid of amplitude A in white noise of unit variance raises its periodogram
    # ordinate (|FFT|² / n) to about n A² / 4, against a mean of 1 elsewhere.
    zc = zb - zb.mean()
    ordinate = np.abs(np.fft.rfft(zc)[k]) ** 2 / nb
    amp_line = 2.0 * math.sqrt(ordinate / nb)
    lo, hi = np.quantile(y_rep, [0.05, 0.95], axis=0)
    coverage = float(np.mean((y >= lo) & (y <= hi)))
    level = LIMITS["coverage"]
    half = 3.0 * math.sqrt(level * (1 - level) / n) + 2.0 / y_rep.shape[0]
    band = [level - half, level + half]

    unit = {"displacement": "m", "velocity": "m/s", "acceleration": "m/s^2"}[trial.quantity]
    reasons = []
    if ratio > LIMITS["noise_ratio"]:
        reasons.append(
            f"fitted noise σ = {sigma:.3g} {unit} is {ratio:.3g}x the noise floor of the record "
            f"({floor.sd:.3g} {unit}, from free damped sinusoids)"
        )
    if p_lb < LIMITS["p_min"]:
        reasons.append(f"residuals are not white (Ljung-Box, {lags} lags: {_fmt_p(p_lb)})")
    if p_line < LIMITS["p_min"]:
        reasons.append(
            f"residual spectral line at {f_line:.4g} Hz, amplitude {amp_line:.2g} σ "
            f"(Fisher g: {_fmt_p(p_line)})"
        )
    if not band[0] <= coverage <= band[1]:
        reasons.append(
            f"90 % predictive interval covers {100 * coverage:.1f} % of the samples "
            f"(expected {100 * band[0]:.1f}-{100 * band[1]:.1f} %)"
        )
    piles = prior_bound_pileup(problem.priors, result.chain.samples)
    for pile in piles:
        reasons.append(
            f"posterior of {pile['param']} piles on its prior's {pile['side']} bound "
            f"{pile['bound']:.4g} ({100 * pile['share']:.0f} % of draws within "
            f"{100 * LIMITS['bound_edge']:g} % of the prior range): the data want values "
            "outside the prior; widen it (--priors)"
        )
    var_y = float(np.var(y))
    explained = 1.0 - sigma**2 / var_y if var_y > 0 else 0.0
    if explained < LIMITS["explained_min"]:
        reasons.append(
            f"the model explains only {100 * max(explained, 0.0):.0f} % of the signal's "
            f"variance (σ = {sigma:.3g} {unit} vs signal RMS {math.sqrt(var_y):.3g} {unit} "
            "about its mean)"
        )
    ok = not reasons
    if ok:
        summary = (
            f"adequate: reproduces the data to its noise (σ {ratio:.2f}x the noise floor, "
            f"residuals white, no residual line, 90 % band covers {100 * coverage:.1f} %)"
        )
    else:
        summary = (
            "NOT adequate: the model does not reproduce the data to its noise ("
            + "; ".join(reasons)
            + "). The intervals are conditional on a model the data reject; run "
            "`bayesbeam diagnose` on this trial to look for the missing effect."
        )
    return {
        "ok": ok,
        "reasons": reasons,
        "summary": summary,
        "sigma": sigma,
        "noise_floor": float(floor.sd),
        "noise_ratio": float(ratio),
        "noise_floor_frequencies": [float(f) for f in floor.frequencies],
        "residual_rms": float(np.sqrt(np.mean(r**2))),
        "ljung_box": {"q": float(q), "p": float(p_lb), "lags": lags},
        "spectral_line": {"frequency_hz": float(f_line), "amplitude_sigma": float(amp_line),
                          "p": float(p_line)},
        "coverage_90": coverage,
        "coverage_band": band,
        "n_draws": int(y_rep.shape[0]),
        "limits": dict(LIMITS),
        "prior_bounds": piles,
        "explained_variance": float(explained),
    }
