"""Joint fits of the shipped trials, and what marginalising sigma and the amplitudes buys.

Two parts (``--part``):

``shipped``
    For each shipped beam (``data/``: five release trials per beam; generating values in
    ``data/truth.toml``), with the generating damping model plus the clamp compliance
    (``root_spring``, hidden in the data) and the AR(1) noise of the generator: one joint
    fit with E and the root spring shared and the damping parameters pooled (log-normal
    population; ``--no-pool``: each trial's own), then five single-trial fits. Reports per
    beam the single-trial and joint 90 % intervals of E, their width ratio (√5 ≈ 2.24
    expected for five equally informative trials), whether the joint interval covers the
    generating E, the population spread of each damping parameter, each trial's adequacy,
    and the same joint fit without ``root_spring``
    (which must report the trials it cannot reproduce).
``bench``
    Five 1280-sample synthetic releases of the source's uniform beam (24-element
    generator), ``--model`` with E shared, to ESS ``--target-ess``: steps, ESS and wall
    time (the issue's benchmark: ESS >= 1000 within 5 minutes on 2 cores).
``real``
    The records of one or more free lengths of the public aluminium strip (``--length``,
    cm, e.g. ``60`` or ``30,40,50,60``;
    ``../shared/data/real``, read in place): 2 s windows from 0.1 s after the release
    peak, resampled to 512 Hz, ``--model`` (default the uniform beam with a point mass
    anywhere on the span, ``viscous+kv+added_mass+ar1_noise``) with free amplitudes of
    each record's own modes below 0.8 Nyquist (``--per-length N``: the first N records
    of each length). One joint fit with the attachment (mass, and its position: from
    the clamp at one length, from the free end over several; the same strip and sensor
    board in every record) shared, and E, the damping and the noise per record
    (``--shared`` to change), then each record alone. Reports the 90 % intervals of E
    (GPa), the mass (g) and its distance from the tip (cm), single and joint, their
    width ratios, each record's adequacy, and the bridge-sampling log evidence of the
    joint fit minus the sum of the single records' (does one mass at one place serve
    them all?).
``marginal``
    One trial (``--trial``; default: the first of ``bench``'s releases, with a narrow
    spatial-hysteresis kernel for an ``sh`` model), one model:
    the single fit (sigma and w0 sampled) against the
    joint fit of that one trial (sigma and w0 integrated out in closed form), a few
    seeds each: bulk ESS per second of E and the damping parameters, and their means
    in units of the combined Monte Carlo standard error.

Run from the repository root, e.g.::

    python studies/joint_fits.py --part shipped --beams beam2 --out studies/figures
    python studies/joint_fits.py --part real --length 30,40,50,60 --per-length 1
    python studies/joint_fits.py --part marginal --seeds 5
    python studies/joint_fits.py --part marginal --model viscous+sh --seeds 3
    python studies/joint_fits.py --part bench --model viscous+kv

Prints a markdown table and writes ``joint_<part>.json`` into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import tomllib
import warnings
from pathlib import Path

import numpy as np

from bayesbeam.inference.fit import fit
from bayesbeam.inference.joint import TIP_DISTANCE
from bayesbeam.inference.joint_fit import fit_joint
from bayesbeam.jobs.demo import find_data
from bayesbeam.physics.models import parse_model
from bayesbeam.stats.sampling import NotConvergedWarning
from bayesbeam.trials.io import read_trial

DAMPING = ("gamma", "c_d", "eta")


def _interval(x: np.ndarray) -> tuple[float, float, float]:
    q05, q50, q95 = np.quantile(x, [0.05, 0.5, 0.95])
    return float(q05), float(q50), float(q95)


def shipped(beams: list[str], settings: dict, say, save, pool: bool = True) -> list[dict]:
    """Joint fits first (the result that matters), then the single fits; saved as it goes.

    The model holds every generating effect: the damping laws, the clamp compliance and,
    where ``truth.toml`` has AR(1) noise, ``ar1_noise``. ``pool``: the damping parameters
    pooled (log-normal population), else each trial's own.
    """
    data = find_data(None)
    truth = tomllib.loads((data / "truth.toml").read_text())
    ar1 = float(truth.get("noise", {}).get("ar1_sd", 0.0)) > 0
    rows: list[dict] = []
    for b in beams:
        gen = truth[b]
        model = parse_model(gen["model"] + "+root_spring" + ("+ar1_noise" if ar1 else "")).name
        trials = [read_trial(data / f"{b}-trial{i}.toml") for i in range(1, 6)]
        pooled = tuple(n for n in DAMPING if pool and (
            n in parse_model(model).physical_params or (n == "eta" and "sh" in model.split("+"))))
        t0 = time.perf_counter()
        say(f"{b}: joint fit (shared E, root_spring; pooled {pooled})")
        jf = fit_joint(trials, model, shared=("E", "root_spring"), pooled=pooled, seed=0,
                       **settings)
        post = jf.to_json_dict()["posterior"]
        q05, q50, q95 = _interval(jf.result.theta_samples()[..., jf.result.names.index("E")]
                                  .ravel())
        row = {
            "beam": b, "model": model, "E_true": gen["E"], "joint_E": [q05, q50, q95],
            "joint_covers_truth": bool(q05 <= gen["E"] <= q95),
            "root_spring": post.get("root_spring"), "root_spring_true": gen["root_spring"],
            "spread": {n: post.get(f"{n}_spread") for n in pooled},
            "adequate": {lb: bool(v.adequacy.get("ok")) for lb, v in zip(jf.labels, jf.trials,
                                                                         strict=True)},
            "converged": bool(jf.result.chain.converged), "ess_min": jf.result.chain.ess_min,
            "tau_max": jf.result.chain.tau_max, "seconds_joint": time.perf_counter() - t0,
            "single_E": [],
        }
        rows.append(row)
        save(rows)
        for i, tr in enumerate(trials):
            say(f"{b}: single fit {i + 1}/5 ({model})")
            r = fit(tr, model, seed=i, **settings)
            row["single_E"].append(_interval(r.theta_samples()[..., r.names.index("E")].ravel()))
            w_single = [hi - lo for lo, _, hi in row["single_E"]]
            row["width_ratio_median"] = float(np.median(w_single) / (q95 - q05))
            save(rows)
        say(f"{b}: joint fit without root_spring")
        bare = parse_model(gen["model"] + ("+ar1_noise" if ar1 else "")).name
        jb = fit_joint(trials, bare, shared=("E",), pooled=pooled, seed=0, **settings)
        row["without_root_spring"] = {"model": bare, "adequate": {
            lb: bool(v.adequacy.get("ok")) for lb, v in zip(jb.labels, jb.trials, strict=True)}}
        save(rows)
    return rows


#: What the real part reports: parameter, scale to the unit shown, unit.
REAL_SHOWN = (("E", 1e-9, "GPa"), ("added_mass", 1e3, "g"), ("tip_distance", 1e2, "cm"))


def _real_intervals(view, length: float) -> dict:
    """90 % intervals of E, the added mass and its distance from the tip (shown units).

    ``view`` is one record's posterior in its own parameters (a :class:`JointFit`'s
    ``trials`` entry), so single and joint fits are read the same way.
    """
    X = view.theta_samples().reshape(-1, view.chain.ndim)
    cols = {n: X[:, view.names.index(n)] for n in ("E", "added_mass", "added_mass_position")
            if n in view.names}
    if "added_mass_position" in cols:
        cols["tip_distance"] = length - cols.pop("added_mass_position")
    return {n: [v * scale for v in _interval(cols[n])] for n, scale, _ in REAL_SHOWN
            if n in cols}


#: Uniform-cantilever frequency ratios f_n/f1 (physics.md §4: (β_n L / β_1 L)²).
RATIOS = (1.0, 6.2669, 17.5475, 34.3861)


def _window(length_cm: int, index: int, duration: float = 2.0, dt: float = 1 / 512):
    """One aluminium record: ``duration`` s from 0.1 s after the release, resampled to ``dt``."""
    from bayesbeam.trials.realdata import load_enes

    trial = load_enes(length_cm, index, duration=duration + 0.2).resample(dt)
    t0 = float(trial.times[0])
    return trial.window(t0, t0 + duration)


def _n_modes(trial) -> int:
    """Modes of a uniform cantilever (ratios from the first spectral peak) below 0.8 Nyquist."""
    from bayesbeam.inference.problem import first_frequency

    f1 = first_frequency(trial.times, trial.values)
    nyq = 0.5 / trial.dt
    return max(1, sum(1 for r in RATIOS if r * f1 < 0.8 * nyq))


def _scored(trials, model, shared, initial, common, seed):
    """Fit jointly, score by bridge sampling, and return what the study reports of it."""
    from bayesbeam.comparison.joint import score_joint

    t0 = time.perf_counter()
    jf = fit_joint(trials, model, shared=shared, initial=initial, seed=seed, **common)
    sc = score_joint(jf, seed=seed)
    c = jf.result.chain
    return {
        "records": [t.name for t in trials], "labels": list(jf.labels),
        "intervals": {lb: _real_intervals(v, float(t.beam.length))
                      for lb, v, t in zip(jf.labels, jf.trials, trials, strict=True)},
        "adequate": {lb: bool(v.adequacy.get("ok")) for lb, v in zip(jf.labels, jf.trials,
                                                                     strict=True)},
        "log_z": sc.evidence.log_z, "log_z_err": sc.evidence.log_z_err,
        "log_prob_map": float(jf.result.settings["log_prob_map"]),
        "elpd": sc.loo.elpd_loo if sc.loo is not None else None,
        "elpd_se": sc.loo.se if sc.loo is not None else None,
        "notes": list(sc.notes), "converged": bool(c.converged), "ess_min": c.ess_min,
        "tau_max": c.tau_max, "ndim": c.ndim, "steps": c.n_steps_total,
        "seconds": time.perf_counter() - t0,
    }


def real(lengths: list[int], model: str, settings: dict, say, save, *,
         per_length: int | None = None, first: int = 0,
         shared: tuple[str, ...] | None = None) -> dict:
    """Joint fit of the aluminium records at ``lengths`` (cm), then each record alone.

    Records ``first`` to ``first + per_length - 1`` of each length are used (all from
    ``first`` when ``per_length`` is None), so the repeats can be fitted apart from the
    first records.

    One length: the attachment's position from the clamp is shared; several: its
    distance from the free end (``added_mass_tip_distance``). ``shared`` (default: the
    mass and its place) names the shared parameters; E stays per record by default
    because at each free length it also absorbs that length's clamp compliance (a
    shared E would make f1, known to 1e-4, pull on the mass). Every record keeps its
    own initial condition: free amplitudes of its modes below 0.8 Nyquist. The
    evidence of the joint fit against the sum of the single records' says whether one
    mass at one place serves them all (bridge sampling, errors in quadrature).
    """
    from bayesbeam.trials.realdata import list_real_datasets

    trials = []
    for length_cm in lengths:
        count = sum(1 for r in list_real_datasets() if r.kwargs.get("length_cm") == length_cm)
        stop = count if per_length is None else min(count, first + per_length)
        if first >= stop:
            raise SystemExit(f"no record {first} at {length_cm} cm: it has {count} "
                             f"(numbered from 0); lower --first-record")
        trials += [_window(length_cm, i) for i in range(first, stop)]
    initial = [f"modes:{_n_modes(t)}" for t in trials]
    where = "added_mass_position" if len(set(lengths)) == 1 else TIP_DISTANCE
    physical = parse_model(model).physical_params
    if shared is None:
        shared = ("added_mass",) if "added_mass" in physical else ()
        shared += (where,) if "added_mass_position" in physical else ()
    # fit_joint integrates sigma and the amplitudes out where that is exact and samples
    # them for an amplitude-dependent model (drag, friction).
    common = {"n_elements": 10, **settings}
    out: dict = {"lengths_cm": lengths, "model": model, "records": [t.name for t in trials],
                 "initial": initial, "shared": list(shared)}
    say(f"real: joint fit of {len(trials)} records at {lengths} cm ({model}, shared {shared})")
    out["joint"] = _scored(trials, model, shared, initial, common, seed=0)
    out["single"] = []
    save(out)
    for i, (tr, ini) in enumerate(zip(trials, initial, strict=True)):
        say(f"real: single fit {i + 1}/{len(trials)} ({tr.name})")
        out["single"].append(_scored([tr], model, (), ini, common, seed=i + 1))
        save(out)
    sep = sum(s["log_z"] for s in out["single"])
    sep_err = math.sqrt(sum(s["log_z_err"] ** 2 for s in out["single"]))
    j = out["joint"]
    out["delta_log_z_joint_minus_separate"] = j["log_z"] - sep
    out["delta_log_z_err"] = math.hypot(j["log_z_err"], sep_err)
    # The same question at the best points (no sampling error; no Occam factor).
    out["delta_log_prob_map"] = j["log_prob_map"] - sum(s["log_prob_map"]
                                                        for s in out["single"])
    widths = {}
    for n, _, _ in REAL_SHOWN:
        ratios = []
        for s, lb in zip(out["single"], j["labels"], strict=True):
            one = s["intervals"][s["labels"][0]]
            if n in one:
                ratios.append((one[n][2] - one[n][0])
                              / (j["intervals"][lb][n][2] - j["intervals"][lb][n][0]))
        if ratios:
            widths[n] = float(np.median(ratios))
    out["width_ratio_median"] = widths
    return out


def _bench_trials(model: str, n: int) -> list:
    """``n`` 1280-sample releases of the source's uniform beam (24-element generator)."""
    from bayesbeam.physics.beam import Beam
    from bayesbeam.trials.synthetic import simulate_trial

    beam = Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=6.2e10)
    params = {"gamma": 0.2}
    if "kv" in model:
        params["c_d"] = 2e6
    if "sh" in model:
        # A narrow kernel: ζ1 ≈ a b² ω1 / (4 E I) = 1 % (physics.md §2, bench_params).
        w1 = 1.875104069**2 * np.sqrt(beam.E * beam.I / (beam.rhoA * beam.length**4))
        params["b"] = 0.01
        params["a"] = 4 * beam.E * beam.I * 0.01 / (w1 * params["b"] ** 2)
    return [simulate_trial(beam, model, params, duration=5.0, dt=0.003906,
                           tip_deflection=0.004 + 0.001 * i, noise_sd=2e-5, seed=i,
                           n_elements=24, name=f"rel{i + 1}") for i in range(n)]


def marginal(trial_path: str | None, model: str, seeds: int, settings: dict, say) -> dict:
    tr = read_trial(trial_path) if trial_path else _bench_trials(model, 1)[0]
    out: dict = {"trial": tr.name, "model": model, "runs": []}
    for s in range(seeds):
        say(f"marginal: seed {s}: sampled sigma, w0")
        a = fit(tr, model, seed=s, **settings)
        say(f"marginal: seed {s}: integrated out")
        j = fit_joint([tr], model, shared=(), seed=s, **settings).result
        run = {"seed": s}
        for tag, r, rename in (("sampled", a, lambda n: n), ("marginal", j,
                                                            lambda n: f"{n}[{tr.name}]")):
            names = [n for n in a.names if n == "E" or n in DAMPING]
            idx = [r.names.index(rename(n)) for n in names]
            X = r.theta_samples().reshape(-1, r.chain.ndim)[:, idx]
            ess = r.chain.ess[idx]
            run[tag] = {"seconds": r.chain.seconds, "ndim": r.chain.ndim,
                        "ess_min": float(np.min(ess)),
                        "ess_per_s": float(np.min(ess) / r.chain.seconds),
                        "mean": dict(zip(names, X.mean(0).tolist(), strict=True)),
                        "mcse": dict(zip(names, (X.std(0) / np.sqrt(ess)).tolist(),
                                         strict=True))}
        run["ratio_ess_per_s"] = run["marginal"]["ess_per_s"] / run["sampled"]["ess_per_s"]
        run["mean_diff_in_mcse"] = {
            n: (run["marginal"]["mean"][n] - run["sampled"]["mean"][n])
            / math.hypot(run["marginal"]["mcse"][n], run["sampled"]["mcse"][n])
            for n in run["sampled"]["mean"]}
        out["runs"].append(run)
    out["median_ratio_ess_per_s"] = float(np.median([r["ratio_ess_per_s"] for r in out["runs"]]))
    return out


def bench(model: str, settings: dict, say) -> dict:
    """Five 1280-sample release trials of the source's uniform beam, E shared: wall time."""
    trials = _bench_trials(model, 5)
    t0 = time.perf_counter()
    say(f"bench: joint {model} of five 1280-sample trials, E shared")
    jf = fit_joint(trials, model, shared=("E",), seed=0, **settings)
    total = time.perf_counter() - t0
    c = jf.result.chain
    return {"model": model, "n_trials": 5, "n_samples": 1280, "ndim": c.ndim,
            "nwalkers": c.nwalkers, "steps": c.n_steps_total, "ess_min": c.ess_min,
            "converged": bool(c.converged), "sampling_seconds": c.seconds,
            "total_seconds": total, "ess_per_s": c.ess_min / c.seconds}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--part", choices=("shipped", "real", "marginal", "bench"), required=True)
    ap.add_argument("--length", default="60",
                    help="aluminium length(s) of --part real, cm, comma-separated")
    ap.add_argument("--per-length", type=int, default=None,
                    help="--part real: N records of each length (default all)")
    ap.add_argument("--first-record", type=int, default=0,
                    help="--part real: the first record of each length to use (0-based; "
                         "1 for the repeats); written to joint_real_from<K>.json")
    ap.add_argument("--shared", default=None,
                    help="--part real: shared parameters, comma-separated (default the "
                         "added mass and its place; E per record)")
    ap.add_argument("--beams", default="beam1,beam2,beam3")
    ap.add_argument("--no-pool", action="store_true",
                    help="--part shipped: each trial's own damping instead of a population")
    ap.add_argument("--trial", default=None, help="trial of --part marginal")
    ap.add_argument("--model", default=None,
                    help="model of --part marginal/bench (default viscous+kv) and real "
                         "(default viscous+kv+added_mass+ar1_noise)")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--target-ess", type=float, default=1000.0)
    ap.add_argument("--max-steps", type=int, default=20000)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "figures")
    args = ap.parse_args()
    # One output file per part (the repeats of --part real apart from the first records).
    result_path = args.out / (f"joint_real_from{args.first_record}.json"
                              if args.part == "real" and args.first_record
                              else f"joint_{args.part}.json")

    def say(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    # Progress lines with time estimates on stderr (these runs take minutes to hours).
    settings = {"target_ess": args.target_ess, "max_steps": args.max_steps, "progress": True}
    args.out.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings():
        warnings.simplefilter("default", NotConvergedWarning)  # report, do not stop
        if args.part == "shipped":
            def save(rows: list[dict]) -> None:
                result_path.write_text(json.dumps(rows, indent=2, default=str) + "\n")

            res = shipped([b.strip() for b in args.beams.split(",")], settings, say, save,
                          pool=not args.no_pool)
            print("| beam | single E 90 % widths (GPa) | joint E [q05, q95] (GPa) | width "
                  "ratio | covers | root spring | spreads q95 | adequate | w/o root_spring |")
            print("|---|---|---|---|---|---|---|---|---|")
            for r in res:
                ws = ", ".join(f"{(hi - lo) / 1e9:.3f}" for lo, _, hi in r["single_E"])
                lo, _, hi = r["joint_E"]
                sp = ", ".join(f"{n} {v['q95']:.3g}" for n, v in r["spread"].items() if v)
                print(f"| {r['beam']} | {ws} | [{lo / 1e9:.3f}, {hi / 1e9:.3f}] | "
                      f"{r['width_ratio_median']:.2f} | {r['joint_covers_truth']} | "
                      f"{r['root_spring']['q50']:.3g} (true {r['root_spring_true']:g}) | {sp} | "
                      f"{sum(r['adequate'].values())}/5 | "
                      f"{sum(r['without_root_spring']['adequate'].values())}/5 |")
        elif args.part == "real":
            def save_real(out: dict) -> None:
                result_path.write_text(json.dumps(out, indent=2, default=str) + "\n")

            shared = (None if args.shared is None
                      else tuple(v.strip() for v in args.shared.split(",") if v.strip()))
            res = real([int(v) for v in args.length.split(",")],
                       args.model or "viscous+kv+added_mass+ar1_noise", settings, say, save_real,
                       per_length=args.per_length, first=args.first_record, shared=shared)
            print(f"{res['lengths_cm']} cm, {len(res['records'])} records, {res['model']}, "
                  f"shared {res['shared']}")
            print("| record | initial | fit | " + " | ".join(
                f"{n} [q05, q95] ({u})" for n, _, u in REAL_SHOWN) + " | adequate | "
                "converged (ESS, s) |")
            print("|---" * (len(REAL_SHOWN) + 5) + "|")
            j = res["joint"]
            for k, (s1, lb) in enumerate(zip(res["single"], j["labels"], strict=True)):
                for tag, f, key in (("single", s1, s1["labels"][0]), ("joint", j, lb)):
                    iv = f["intervals"][key]
                    cells = " | ".join(f"{iv[n][1]:.4g} [{iv[n][0]:.4g}, {iv[n][2]:.4g}]"
                                       if n in iv else "-" for n, _, _ in REAL_SHOWN)
                    print(f"| {lb} | {res['initial'][k]} | {tag} | {cells} | "
                          f"{f['adequate'][key]} | {f['converged']} ({f['ess_min']:.0f}, "
                          f"{f['seconds']:.0f}) |")
            print(f"log Z joint - sum of single: {res['delta_log_z_joint_minus_separate']:.1f} "
                  f"± {res['delta_log_z_err']:.1f} nats (at the MAPs: "
                  f"{res['delta_log_prob_map']:.1f})")
            print("median single/joint width ratio: " + ", ".join(
                f"{n} {v:.2f}" for n, v in res["width_ratio_median"].items()))
        elif args.part == "bench":
            res = bench(args.model or "viscous+kv", settings, say)
            print("| model | trials x samples | ndim | walkers | steps | ESS min | converged "
                  "| sampling s | total s |")
            print("|---|---|---|---|---|---|---|---|---|")
            print(f"| {res['model']} | 5 x 1280 | {res['ndim']} | {res['nwalkers']} | "
                  f"{res['steps']} | {res['ess_min']:.0f} | {res['converged']} | "
                  f"{res['sampling_seconds']:.0f} | {res['total_seconds']:.0f} |")
        else:
            res = marginal(args.trial, args.model or "viscous+kv", args.seeds, settings, say)
            print("| seed | ESS/s sampled | ESS/s marginal | ratio | mean diffs (MCSE) |")
            print("|---|---|---|---|---|")
            for r in res["runs"]:
                d = ", ".join(f"{n} {v:+.1f}" for n, v in r["mean_diff_in_mcse"].items())
                print(f"| {r['seed']} | {r['sampled']['ess_per_s']:.1f} | "
                      f"{r['marginal']['ess_per_s']:.1f} | {r['ratio_ess_per_s']:.2f} | {d} |")
            print(f"median ratio {res['median_ratio_ess_per_s']:.2f}")
    result_path.write_text(json.dumps(res, indent=2, default=str) + "\n")


if __name__ == "__main__":
    main()
