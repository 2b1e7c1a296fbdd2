"""Change-of-state test on every public measured record (whole raw records, no options).

Usage::

    python studies/state_changes.py [--root ../shared/data/real] [--out studies/figures]

For each record of ``bayesbeam.trials.realdata.list_real_datasets``: the raw record,
the analysis span chosen as for a fit (``trials.preprocess.plan``), the amplitude
curves on the raw stamps (``trials.amplitude.amplitude_curves``) and the change-of-state
test (``trials.state_change.state_change``). Prints one line per record and writes
``state_changes.md`` and one ``mode1_vs_time_<record>.png`` per record into ``--out``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from bayesbeam._util import progress_bar, write_text_atomic
from bayesbeam.report.amplitude_plots import plot_mode1_in_time
from bayesbeam.trials.amplitude import amplitude_curves, tip_factor
from bayesbeam.trials.preprocess import plan
from bayesbeam.trials.realdata import DEFAULT_ROOT, list_real_datasets
from bayesbeam.trials.state_change import state_change


def main() -> None:
    """Run the test on every record and write the table and figures."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", default=DEFAULT_ROOT, help="the real-data folder")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "figures")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    records = list_real_datasets(args.root)
    rows = ["| record | span (s) | windows | change of state | time (s) | f1 before → after "
            "(Hz) | ζ1 before → after | corrected p | seconds |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    with progress_bar(len(records), "state changes: records", unit="record",
                      log_interval=0.0) as bar:
        for rec in records:
            t0 = time.perf_counter()
            trial = rec.load(args.root, raw=True, duration=None)
            pre = plan(trial)
            trial = trial.window(pre.start, pre.end)
            curves = amplitude_curves(trial.times, trial.values, quantity=trial.quantity,
                                      tip_factor=tip_factor(trial.beam))
            sc = state_change(curves)
            sec = time.perf_counter() - t0
            fig = plot_mode1_in_time(curves, change=sc, title=f"{trial.name}: ")
            fig.savefig(args.out / f"mode1_vs_time_{trial.name}.png", dpi=80)
            lv = sc.levels
            rows.append(
                f"| {trial.name} | {pre.start:.2f}–{pre.end:.2f} | {sc.n_windows} | "
                f"{'**yes**' if sc.found else 'no'} | "
                + (f"{sc.time_s:.1f} ± {sc.time_halfwidth_s:.1f} | "
                   f"{lv['frequency_before_hz']:.4f} → {lv['frequency_after_hz']:.4f} | "
                   f"{lv['zeta_before']:.4f} → {lv['zeta_after']:.4f} | {sc.p_value:.2g}"
                   if sc.tested else "– | – | – | –")
                + f" | {sec:.0f} |")
            bar.set_postfix_str(trial.name)
            bar.update(1)
            print(f"{trial.name}: {sc.reason}", flush=True)
    write_text_atomic(args.out / "state_changes.md", "\n".join(rows) + "\n")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
