"""Calibration cases of "a fit that knows when not to trust itself" (issue 12).

A 0.4 m aluminium strip (50.8 x 2 mm, E 70 GPa, 2700 kg/m^3) released from a 5 mm tip
deflection, viscous + Kelvin-Voigt damping (gamma = 0.106 N s/m^2, c_d = 4.33e6 Pa s),
an accelerometer at the tip sampled at 512 Hz (2048 samples from 0.06 s after the
release; noise 0.02 m/s^2). The records come from an independent route
(:func:`bayesbeam.trials.synthetic.simulate_sensor`: 64 elements, every mode, 16x faster
grid, Kaiser FIR anti-alias filter, spline onto the stamps), never from the fit's own
model. Three cases, each fitted with ``viscous+kv`` at the package defaults:

* uniform stamps;
* jittered stamps (each step within ±15 % of 1/512 s);
* a 5 g mass 6.7 cm inboard of the tip that the fit does not know of (the user's beam
  description is the bare strip): the fit must say it is not adequate.

Run: ``python studies/adequacy_cases.py``. Prints, per case, the 90 % intervals against
the truth, the final mesh, the adequacy verdict with its figures, and the fit time.
:func:`record` is also used by ``tests/inference/test_adequacy.py``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bayesbeam.physics.beam import Beam, Segment
from bayesbeam.trials.synthetic import simulate_sensor
from bayesbeam.trials.trial import Trial

L, W, TH, RHO = 0.4, 0.0508, 0.002, 2700.0  # m, m, m, kg/m^3
TRUE = {"E": 70e9, "gamma": 0.106, "c_d": 4.33e6, "w0": 0.005}
NOISE = 0.02  # m/s^2
MASS, MASS_POSITION = 0.005, L - 0.067  # kg, m from the clamp


def beam(quantity: str = "acceleration", added_mass: float = 0.0,
         position: float = MASS_POSITION) -> Beam:
    """Return the strip, optionally with a mass glued over 1 cm around ``position`` (m)."""
    m0 = L * W * TH * RHO
    kw = {}
    if added_mass:
        f = 1 + added_mass / (m0 / L * 0.01)
        kw["segments"] = (Segment(position - 0.005, position + 0.005, rhoA=f),)
    return Beam.rectangular(length=L, width=W, thickness=TH, mass=m0 + added_mass, E=70e9,
                            **kw).replace(quantity=quantity)


def record(*, jitter: bool = False, added_mass: float = 0.0, n: int = 2048,
           seed: int = 0) -> Trial:
    """Return one record as a trial on the user's nominal beam description.

    Parameters
    ----------
    jitter : bool
        Non-uniform stamps (each step within ±15 % of 1/512 s).
    added_mass : float
        Mass in kg at :data:`MASS_POSITION`, in the data only.
    n : int
        Samples.
    seed : int
        Seed of the stamps' jitter and the noise.

    Returns
    -------
    Trial
    """
    rng = np.random.default_rng(seed)
    if jitter:
        steps = (1 + rng.uniform(-0.15, 0.15, n - 1)) / 512.0
        t = 0.06 + np.concatenate([[0.0], np.cumsum(steps)])
    else:
        t = 0.06 + np.arange(n) / 512.0
    y = simulate_sensor(beam(added_mass=added_mass), "viscous+kv", TRUE, t)
    y = y + NOISE * rng.standard_normal(n)
    return Trial(times=t, values=y, quantity="acceleration", beam=beam(), t0=0.0,
                 initial={"tip_deflection": TRUE["w0"]}, name="al-strip")


def main() -> None:
    """Fit the three cases and print the table."""
    from bayesbeam.inference.fit import fit

    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()
    cases = (("uniform stamps", {}), ("jittered stamps", {"jitter": True}),
             ("5 g mass 6.7 cm inboard, not modelled", {"added_mass": MASS}))
    truth = {**{k: TRUE[k] for k in ("E", "gamma", "c_d")}, "sigma": NOISE}
    for label, kw in cases:
        t0 = time.perf_counter()
        res = fit(record(**kw), "viscous+kv", progress=False)
        s = res.summary()
        print(f"\n{label}: {time.perf_counter() - t0:.1f} s, mesh {res.mesh['n_elements']} "
              f"elements ({'converged' if res.mesh['converged'] else 'NOT converged'}), "
              f"chain {'converged' if res.chain.converged else 'NOT converged'}")
        for name, x in truth.items():
            r = s[name]
            inside = "inside" if r["q05"] <= x <= r["q95"] else "OUTSIDE"
            print(f"  {name:6s} 90 % [{r['q05']:.7g}, {r['q95']:.7g}]  truth {x:.7g}  {inside}")
        ad = res.adequacy
        print(f"  adequacy ok={ad['ok']}: noise ratio {ad['noise_ratio']:.3g}, Ljung-Box p "
              f"{ad['ljung_box']['p']:.2g}, line p {ad['spectral_line']['p']:.2g}, "
              f"coverage {ad['coverage_90']:.3f}")
        for reason in ad["reasons"]:
            print(f"    - {reason}")


if __name__ == "__main__":
    main()
