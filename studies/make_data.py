"""Generate the shipped synthetic trials in ``data/`` (run: ``python studies/make_data.py``).

Three carbon-fibre beams modelled on the source study's test articles (length 12 in =
0.3048 m, width 5 in = 0.127 m; thickness 0.72 / 1.47 / 1.98 mm; mass 21 / 46 / 71 g),
five release tests each, tip displacement sampled at 256 Hz for 5 s (1280 samples).

Unlike the source, the generating model is physical (physics.md §5) and includes the
real-world effects the source left out (physics.md §3):

* a 4 in × 3 in rectangular cutout over the middle third of the span (x = 4–8 in): the
  width falls from 5 in to 2 in there, so I(x) and rhoA(x) drop to 0.4 of their values
  (piecewise-constant ``Segment``; the element edges lie on the cutout edges);
* reflective tape at the tip for the vibrometer: a 0.4 g tip mass;
* clamp compliance: a rotational root spring (lowers f1 by 2–5 %);
* trial-to-trial initial conditions: each trial is released from a different tip
  deflection (the TOML states it only to the nearest mm, as read off a ruler);
* damping from a mix of laws: viscous (air) plus spatial hysteresis with a broad kernel
  (b = 0.25 L) on the flexible beam, viscous plus Kelvin–Voigt on the two stiffer ones;
* a vibrometer's band: the decoder's low-pass at 100 Hz (256 Hz / 2.56) removes the
  modes above it (the second mode of the stiffest beam);
* vibrometer-like noise: white Gaussian noise (sd 8 µm) plus an AR(1) component (sd 8 µm,
  lag-one correlation 0.6, as from the decoder's output filter): 11 µm in all, lag-one
  autocorrelation 0.3.

Young's moduli are those of a quasi-isotropic CFRP laminate (55–68 GPa), so the first
frequencies are 8–23 Hz (the source's fitted E of 6e7–2e8 Pa would give 0.4–1.7 Hz).

The trial TOMLs describe each beam as its user knows it (geometry, mass, the cutout, the
tape mass, the nominal release deflection) and NOT the hidden truths (E, clamp
compliance, damping laws and values, noise model, exact release deflection); those are
written to ``data/truth.toml`` for studies and tests. The signals come from the
package's own forward model (:class:`bayesbeam.physics.forward.Forward`) on a 32-element mesh
(finer than the 16-element default of the fits, as real data are "infinitely" fine), so
the files are exactly reproducible: values are written in mm with 6 decimals (1 nm,
10⁴ times below the noise), which makes the output independent of last-bit floating
point differences between machines.

The generating values are documented in ``data/README.md`` ("Shipped synthetic
trials"), which this script's ``--table`` option prints.
"""

from __future__ import annotations

import argparse
import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bayesbeam.physics.beam import Beam, Segment
from bayesbeam.physics.fem import assemble
from bayesbeam.physics.forward import Forward, modal_properties
from bayesbeam.stats.likelihood import stationary_ar1

DATA_DIR = Path(__file__).resolve().parents[1] / "data"

#: Base seed of the noise generator; trial (beam k, trial j) uses SeedSequence(BASE_SEED,
#: spawn_key=(k, j)).
BASE_SEED = 20_251_101

LENGTH = 0.3048  # m (12 in)
WIDTH = 0.127  # m (5 in)
TIP_TAPE_MASS = 0.0004  # kg: 1 in x 1 in retro-reflective tape
#: The cutout: 4 in long (x = 4 in to 8 in) and 3 in wide, leaving 2 of the 5 in.
CUTOUT = Segment(start=0.1016, end=0.2032, I=0.4, rhoA=0.4)
FS = 256.0  # Hz
N_SAMPLES = 1280  # 5 s
N_ELEMENTS_TRUTH = 32
#: The vibrometer decoder's output low-pass, Hz: the default sensor band (FS / 2.56, see
#: data/README.md "Sensor band"), written into each trial file. The record is what such a
#: sensor sees: modes above it (the second mode of the stiffest beam) are filtered out.
BANDWIDTH = FS / 2.56
NOISE_WHITE_SD = 8.0e-6  # m
NOISE_AR_SD = 8.0e-6  # m, marginal sd of the AR(1) component
NOISE_AR_RHO = 0.6


@dataclass(frozen=True)
class BeamSpec:
    """Generating values of one beam (SI units)."""

    name: str
    thickness: float  # m
    mass: float  # kg, beam without the tape
    E: float  # Pa
    root_spring: float  # N m/rad
    model: str  # damping laws of the truth
    damping: dict  # their parameters
    tip_deflections: tuple[float, ...]  # m, true release deflection of each trial
    note: str


BEAMS: tuple[BeamSpec, ...] = (
    BeamSpec(
        name="beam1",
        thickness=0.72e-3,
        mass=0.021,
        E=55e9,
        root_spring=40.0,
        model="viscous+sh",
        # zeta1: viscous 0.40 %, spatial hysteresis 0.60 % (kernel sd b = 0.25 L = 3 in)
        damping={"gamma": 0.0355, "a": 0.0189, "b": 0.0762},
        tip_deflections=(0.0118, 0.0094, 0.0141, 0.0104, 0.0127),
        note="flexible beam; broad-kernel spatial hysteresis",
    ),
    BeamSpec(
        name="beam2",
        thickness=1.47e-3,
        mass=0.046,
        E=62e9,
        root_spring=250.0,
        model="viscous+kv",
        # zeta1: viscous 0.30 %, Kelvin-Voigt 0.40 %
        damping={"gamma": 0.118, "c_d": 4.8e6},
        tip_deflections=(0.0082, 0.0066, 0.0091, 0.0074, 0.0098),
        note="intermediate beam; Kelvin-Voigt",
    ),
    BeamSpec(
        name="beam3",
        thickness=1.98e-3,
        mass=0.071,
        E=68e9,
        root_spring=500.0,
        model="viscous+kv",
        # zeta1: viscous 0.20 %, Kelvin-Voigt 0.50 %
        damping={"gamma": 0.157, "c_d": 5.2e6},
        tip_deflections=(0.0061, 0.0049, 0.0072, 0.0056, 0.0064),
        note="stiff beam; Kelvin-Voigt",
    ),
)


def user_beam(spec: BeamSpec) -> Beam:
    """Return the beam as its user describes it (no E, rigid clamp assumed).

    Parameters
    ----------
    spec : BeamSpec

    Returns
    -------
    Beam
    """
    return Beam.rectangular(
        LENGTH, WIDTH, spec.thickness, spec.mass, segments=(CUTOUT,), tip_mass=TIP_TAPE_MASS
    )


def true_beam(spec: BeamSpec) -> Beam:
    """Return the generating beam: the user's beam plus E and the clamp spring."""
    return user_beam(spec).replace(E=spec.E, root_spring=spec.root_spring)


def release_state(beam: Beam, E: float, w0: float, n_elements: int) -> np.ndarray:
    """Return the static shape under a tip load with tip deflection ``w0`` (m).

    Solves ``(E K + k_θ K_root) c = P e_tip`` on the compliant clamp (physics.md §3).

    Returns
    -------
    ndarray, shape (n_dof,)
    """
    fe = assemble(beam, n_elements, root_dof=True)
    K = E * fe.K + beam.root_spring * fe.K_root
    s = np.linalg.solve(K, fe.tip)
    return w0 * s / float(fe.tip @ s)


def noise(rng: np.random.Generator, n: int) -> np.ndarray:
    """Draw white plus AR(1) noise in m, shape (n,) (stationary from the first sample)."""
    white = NOISE_WHITE_SD * rng.standard_normal(n)
    # The package's AR(1) generator computes the loop these files were made with bit for
    # bit, so data/ regenerates unchanged.
    ar = stationary_ar1(rng.standard_normal(n), NOISE_AR_RHO, sd=NOISE_AR_SD)
    return white + ar


def simulate(spec: BeamSpec, trial_index: int) -> tuple[np.ndarray, np.ndarray]:
    """Return times (s) and noisy tip displacement (m) of one trial, shapes (1280,)."""
    beam = true_beam(spec)
    times = np.arange(N_SAMPLES) / FS
    w0 = spec.tip_deflections[trial_index]
    c0 = release_state(beam, spec.E, w0, N_ELEMENTS_TRUTH)
    # initial='state' with the static shape computed here: the release from a static tip
    # load on the compliant clamp, at rest.
    fwd = Forward(beam, spec.model, times, n_elements=N_ELEMENTS_TRUTH, initial="state",
                  initial_state=(c0, np.zeros_like(c0)), bandwidth=BANDWIDTH)
    res = fwd.simulate({"E": spec.E, **spec.damping})
    if not res.valid[0]:
        raise RuntimeError(f"{spec.name}: the generating parameters are not admissible")
    k = BEAMS.index(spec)
    rng = np.random.default_rng(np.random.SeedSequence(BASE_SEED, spawn_key=(k, trial_index)))
    return times, res.y[0] + noise(rng, N_SAMPLES)


def _trial_toml(spec: BeamSpec, j: int, csv_name: str) -> str:
    nominal = round(spec.tip_deflections[j] * 1000) / 1000  # nearest mm
    return f'''# Synthetic trial generated by studies/make_data.py (see data/README.md).
# It describes the beam as its user knows it; the generating values are in truth.toml.
name = "{spec.name}-trial{j + 1}"
format_version = 1

[signal]
file = "{csv_name}"
time_column = "time_s"
value_column = "displacement_mm"
quantity = "displacement"
unit = "mm"
sensor_position = {LENGTH!r}  # laser vibrometer spot on the tip tape
t0 = 0.0
bandwidth = {BANDWIDTH!r}  # Hz, the vibrometer decoder's low-pass

[beam]  # carbon-fibre strip, SI units
length = {LENGTH!r}
width = {WIDTH!r}
thickness = {spec.thickness!r}
mass = {spec.mass!r}  # kg, weighed without the tape
tip_mass = {TIP_TAPE_MASS!r}  # kg, reflective tape at the tip

# 4 in x 3 in cutout over x = 4-8 in: the width falls from 5 in to 2 in there.
[[beam.segments]]
start = {CUTOUT.start!r}
end = {CUTOUT.end!r}
I = {CUTOUT.I!r}
rhoA = {CUTOUT.rhoA!r}

[initial]
tip_deflection = {nominal!r}
note = "released at rest from a static tip deflection read off a ruler (nearest mm)"

[meta]
beam = "{spec.name}"
trial = {j + 1}
origin = "synthetic: studies/make_data.py; generating values in truth.toml"
generator = "studies/make_data.py"
sampling_rate_hz = {FS!r}
clamp = "bench vise (compliance unknown)"
'''


def _csv_text(times: np.ndarray, values_m: np.ndarray) -> str:
    lines = ["time_s,displacement_mm"]
    # k/256 is exact in binary; repr gives the shortest exact form. Values: 1 nm resolution.
    lines += [f"{t!r},{1e3 * v:.6f}" for t, v in zip(times.tolist(), values_m.tolist(),
                                                     strict=True)]
    return "\n".join(lines) + "\n"


def _truth_toml(rows: list[dict]) -> str:
    out = [
        "# Generating values of the synthetic trials (studies/make_data.py). SI units.",
        "# Hidden from the trial TOMLs: E, root_spring, the damping laws and values, the",
        "# noise model and the exact release deflections.",
        f"base_seed = {BASE_SEED}",
        f"n_elements = {N_ELEMENTS_TRUTH}",
        "",
        "[noise]",
        f"white_sd = {NOISE_WHITE_SD!r}",
        f"ar1_sd = {NOISE_AR_SD!r}",
        f"ar1_rho = {NOISE_AR_RHO!r}",
    ]
    for r in rows:
        spec: BeamSpec = r["spec"]
        out += [
            "",
            f"[{spec.name}]",
            f'model = "{spec.model}"',
            f"E = {spec.E!r}",
            f"root_spring = {spec.root_spring!r}",
            f"kappa = {r['kappa']:.6g}  # k_theta L / (E I) at the root",
            f"tip_deflections = [{', '.join(repr(w) for w in spec.tip_deflections)}]",
            f"frequencies_hz = [{', '.join(f'{f:.6g}' for f in r['f'][:3])}]",
            f"damping_ratios = [{', '.join(f'{z:.6g}' for z in r['z'][:3])}]",
            f"f1_shift_from_clamp = {r['f1_shift']:.6g}  # relative, vs a rigid clamp",
            f'note = "{spec.note}"',
            f"[{spec.name}.damping]",
        ]
        out += [f"{k} = {v!r}" for k, v in spec.damping.items()]
    return "\n".join(out) + "\n"


def beam_properties(spec: BeamSpec) -> dict:
    """Return modal properties of the true beam: frequencies, damping ratios, clamp effect."""
    beam = true_beam(spec)
    params = {"E": spec.E, **spec.damping}
    f, z = modal_properties(beam, spec.model, params, n_elements=N_ELEMENTS_TRUTH)
    f_rigid, _ = modal_properties(beam.replace(root_spring=None), spec.model, params,
                                  n_elements=N_ELEMENTS_TRUTH)
    return {
        "spec": spec,
        "f": f,
        "z": z,
        "f1_shift": f[0] / f_rigid[0] - 1.0,
        "kappa": spec.root_spring * LENGTH / (spec.E * beam.I),
    }


def markdown_table(rows: list[dict]) -> str:
    """Return the generating values as the Markdown table of data/README.md."""
    head = ("| beam | t (mm) | m (g) | E (GPa) | k_θ (N m/rad) | f1 shift | truth model | "
            "damping values | f1, f2 (Hz) | ζ1, ζ2 (%) | release w0 (mm) |")
    lines = [head, "|" + " --- |" * 11]
    for r in rows:
        s: BeamSpec = r["spec"]
        damp = ", ".join(f"{k} = {v:g}" for k, v in s.damping.items())
        w0 = ", ".join(f"{1e3 * w:.1f}" for w in s.tip_deflections)
        lines.append(
            f"| {s.name} | {1e3 * s.thickness:g} | {1e3 * s.mass:g} | {s.E / 1e9:g} | "
            f"{s.root_spring:g} | {100 * r['f1_shift']:+.1f} % | {s.model} | {damp} | "
            f"{r['f'][0]:.2f}, {r['f'][1]:.1f} | {100 * r['z'][0]:.2f}, {100 * r['z'][1]:.2f} | "
            f"{w0} |"
        )
    return "\n".join(lines)


def main(outdir: str | Path | None = None, *, verbose: bool = True) -> list[Path]:
    """Write the 15 trials (TOML + CSV) and ``truth.toml`` into ``outdir``.

    Parameters
    ----------
    outdir : path, optional
        Target folder (default: the repository's ``data/``); created if missing.
    verbose : bool
        Print each file written and its SHA-256.

    Returns
    -------
    list of Path
        The files written.
    """
    outdir = DATA_DIR if outdir is None else Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    rows = []
    for spec in BEAMS:
        rows.append(beam_properties(spec))
        for j in range(len(spec.tip_deflections)):
            stem = f"{spec.name}-trial{j + 1}"
            times, y = simulate(spec, j)
            csv = outdir / f"{stem}.csv"
            csv.write_text(_csv_text(times, y), encoding="utf-8", newline="\n")
            toml = outdir / f"{stem}.toml"
            toml.write_text(_trial_toml(spec, j, csv.name), encoding="utf-8", newline="\n")
            written += [toml, csv]
            if verbose:
                digest = hashlib.sha256(csv.read_bytes()).hexdigest()
                print(f"wrote {toml.name} + {csv.name} (sha256 {digest[:16]}...)")
    truth = outdir / "truth.toml"
    truth.write_text(_truth_toml(rows), encoding="utf-8", newline="\n")
    written.append(truth)
    if verbose:
        print(f"wrote {truth.name}")
    return written


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--outdir", type=Path, default=None, help="default: data/")
    parser.add_argument("--table", action="store_true",
                        help="print the generating values as a Markdown table and exit")
    args = parser.parse_args()
    if args.table:
        print(markdown_table([beam_properties(s) for s in BEAMS]))
    else:
        main(args.outdir)
