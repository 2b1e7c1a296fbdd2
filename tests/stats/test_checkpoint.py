"""Checkpoints under faults: Ctrl-C, a full disk and a damaged file lose no finished step.

The reference is the uninterrupted toy chain of ``tests/stats/test_sampling.py``
(linear-Gaussian posterior, seed 42): every interrupted run, resumed, must reproduce it
bit for bit.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import emcee
import pytest

from bayesbeam.stats.checkpoint import SamplingError
from bayesbeam.stats.sampling import run_emcee
from tests.stats.test_sampling import PRIORS, _same_chain, log_prob, start

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def toy_chain():
    """The uninterrupted reference chain (the same run as test_sampling's fixture)."""
    return run_emcee(log_prob, start(), seed=42, names=PRIORS.names, progress=False)


def _run_script(body: str) -> subprocess.CompletedProcess:
    script = textwrap.dedent(
        f"""
        import os, signal, sys
        sys.path.insert(0, {str(ROOT)!r})
        from tests.stats.test_sampling import NWALKERS, PRIORS, log_prob, start
        from bayesbeam.stats.sampling import run_emcee
        """
    ) + textwrap.dedent(body)
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=300)


def test_ctrl_c_finishes_the_step_keeps_it_and_stays_quiet(toy_chain, tmp_path):
    """SIGINT arrives inside a log-probability call (where emcee would print ~50 lines
    of its own report on stdout): the run stops after that step, with it saved."""
    path = tmp_path / "chain.h5"
    proc = _run_script(
        f"""
        signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal
        class CtrlC:
            calls = 0
            def __call__(self, U):
                before, self.calls = self.calls, self.calls + len(U)
                if before == NWALKERS * 400:  # the first half-ensemble call of step 400
                    os.kill(os.getpid(), signal.SIGINT)
                return log_prob(U)
        try:
            run_emcee(CtrlC(), start(), seed=42, names=PRIORS.names,
                      backend_path={str(path)!r}, progress=False)
        except KeyboardInterrupt as err:
            print("interrupted:", err, file=sys.stderr)
            sys.exit(130)
        """
    )
    assert proc.returncode == 130, proc.stderr
    assert proc.stdout == ""  # nothing from emcee's exception report
    assert "Traceback" not in proc.stderr
    # the call that received the signal belonged to step 400 (the initial evaluation
    # came first): that step was finished and saved, nothing after it was started
    assert emcee.backends.HDFBackend(str(path), read_only=True).iteration == 400
    kw = dict(seed=42, names=PRIORS.names, progress=False, backend_path=path)
    _same_chain(run_emcee(log_prob, start(), resume=True, **kw), toy_chain)


def test_full_disk_keeps_the_last_checkpoint_whole(toy_chain, tmp_path):
    """A write that fails (RLIMIT_FSIZE makes the kernel refuse it with EFBIG, as a full
    disk refuses with ENOSPC) leaves the previous file readable; resuming it gives the
    uninterrupted chain."""
    resource = pytest.importorskip("resource")  # POSIX only
    path = tmp_path / "chain.h5"
    proc = _run_script(
        f"""
        import resource
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # an error, not a kill
        resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))
        try:
            run_emcee(log_prob, start(), seed=42, names=PRIORS.names,
                      backend_path={str(path)!r}, progress=False, checkpoint_seconds=0)
        except OSError as err:
            print("write failed:", err.errno, file=sys.stderr)
            sys.exit(3)
        """
    )
    del resource
    assert proc.returncode == 3, proc.stderr
    assert "write failed: 27" in proc.stderr  # EFBIG
    saved = emcee.backends.HDFBackend(str(path), read_only=True).iteration
    # 200 kB hold about 240 steps of this chain (24 walkers x (3 + 1) doubles a step)
    assert 100 < saved < 300
    assert not list(tmp_path.glob(".chain.*"))  # the failed temporary file is gone
    kw = dict(seed=42, names=PRIORS.names, progress=False, backend_path=path)
    _same_chain(run_emcee(log_prob, start(), resume=True, **kw), toy_chain)


@pytest.mark.parametrize("damage", ["truncated", "not hdf5"])
def test_damaged_checkpoint_is_named_on_resume(toy_chain, tmp_path, damage):
    path = tmp_path / "chain.h5"
    kw = dict(seed=42, names=PRIORS.names, progress=False, backend_path=path)
    if damage == "truncated":
        with pytest.warns(Warning):
            run_emcee(log_prob, start(), max_steps=120, **kw)
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    else:
        path.write_text("time_s,value\n0,1\n", encoding="utf-8")
    with pytest.raises(SamplingError, match="cannot be read.*without --resume"):
        run_emcee(log_prob, start(), resume=True, **kw)
    # without resume the damaged file is replaced and the run is the reference run
    _same_chain(run_emcee(log_prob, start(), **kw), toy_chain)
