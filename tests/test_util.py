"""Private helpers below every layer: strict JSON, file digests, TOML reading."""

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from bayesbeam._util import file_sha256, finite_json, finite_or_none, read_toml


@pytest.mark.parametrize(("x", "expected"), [
    (1.5, 1.5), (3, 3.0), (np.float32(0.25), 0.25), (np.int64(7), 7.0),
    (math.nan, None), (math.inf, None), (-np.inf, None), (None, None),
])
def test_finite_or_none(x, expected):
    out = finite_or_none(x)
    assert out == expected and (out is None or type(out) is float)


def test_finite_json_makes_a_strict_json_record():
    @dataclass
    class Rec:
        a: float
        b: tuple

    rec = {1: np.array([1.0, np.nan]), "x": (math.inf, np.float32(2.0), np.int64(3)),
           "d": Rec(math.nan, (1, 2)), "p": Path("a/b"), "s": "t", "flag": True, "n": None}
    out = finite_json(rec)
    assert out == {"1": [1.0, None], "x": [None, 2.0, 3], "d": {"a": None, "b": [1, 2]},
                   "p": "a/b", "s": "t", "flag": True, "n": None}
    json.dumps(out, allow_nan=False)  # strict JSON: no numpy types, no NaN


def test_file_sha256(tmp_path):
    f = tmp_path / "data.bin"
    f.write_bytes(b"beam\x00data")
    assert file_sha256(f) == file_sha256(str(f)) == hashlib.sha256(b"beam\x00data").hexdigest()


class _MyError(ValueError):
    pass


def test_read_toml_reads_and_raises_the_callers_error(tmp_path):
    good = tmp_path / "good.toml"
    good.write_text('[beam]\nlength = 0.3\nname = "b"\n', encoding="utf-8")
    assert read_toml(good) == {"beam": {"length": 0.3, "name": "b"}}
    with pytest.raises(_MyError, match=r"cannot read trial file .*none\.toml: not found"):
        read_toml(tmp_path / "none.toml", what="trial file", error=_MyError)
    bad = tmp_path / "bad.toml"
    bad.write_text("[beam\nlength = 1\n", encoding="utf-8")
    with pytest.raises(_MyError, match=r"beam file .*bad\.toml is not valid TOML \(.*line 1"):
        read_toml(bad, what="beam file", error=_MyError)
    with pytest.raises(ValueError, match=r"cannot read TOML file .*: "):
        read_toml(tmp_path)  # a folder: an OSError other than not-found


def test_read_toml_names_a_file_that_is_not_utf8(tmp_path):
    from bayesbeam._util import read_toml

    path = tmp_path / "p.toml"
    path.write_bytes(b'x = "caf\xe9"\n')  # Latin-1, as an old editor saves it
    with pytest.raises(ValueError, match=r"prior file .*p\.toml is not UTF-8 text .*position 8"):
        read_toml(path, what="prior file")


def test_atomic_path_keeps_the_old_file_when_a_write_fails(tmp_path):
    from bayesbeam._util import atomic_path, write_text_atomic

    path = tmp_path / "summary.json"
    write_text_atomic(path, "old\n")
    with pytest.raises(OSError, match="summary.json"):
        with atomic_path(path) as tmp:
            tmp.write_text("half")
            raise OSError(28, "No space left on device")  # as a full disk's write
    assert path.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["summary.json"]  # no temporary left


# --------------------------------------------------------------------------- intervals


@pytest.mark.parametrize(
    ("value", "lo", "hi"),
    [
        (70.0e9, 69.98e9, 70.02e9),  # four digits print 7.000e+10 three times
        (0.012345, 0.012301, 0.012399),
        (1.0, 0.5, 2.0),
        (-3.2e-7, -3.3e-7, -3.1e-7),
        (123456.0, 123455.9, 123456.2),
    ],
)
def test_interval_prints_three_different_numbers(value, lo, hi):
    from bayesbeam._util import fmt_interval

    texts = fmt_interval(value, lo, hi)
    assert len(set(texts)) == 3, texts
    # and each printed number is within its last shown digit of the true one
    for t, x in zip(texts, (value, lo, hi), strict=True):
        digits = len(t.split("e")[0].replace("-", "").replace(".", "").lstrip("0"))
        assert abs(float(t) - x) <= 0.5 * 10 ** (np.floor(np.log10(abs(x))) - digits + 1) * 1.0001


def test_interval_digits_bounds():
    from bayesbeam._util import interval_digits

    assert interval_digits(1.0, 1.0, 1.0) == 3  # no width: the minimum
    assert interval_digits(float("nan"), 0.0, 1.0) == 3
    assert interval_digits(1.0, 1.0 - 1e-15, 1.0 + 1e-15) == 12  # capped


# --------------------------------------------------------------------------- progress


def test_progress_bar_in_a_log_is_whole_lines(capsys):
    from bayesbeam._util import progress_bar

    with progress_bar(4, "stage model", unit="step", log_interval=0.0) as bar:
        for _ in range(4):
            bar.update(1)
    err = capsys.readouterr().err
    assert "\r" not in err and "\x1b" not in err  # no terminal control in a log
    lines = err.strip().splitlines()
    assert lines[-1].startswith("stage model: 100%") and "4/4" in lines[-1]
    with progress_bar(4, "off", enabled=False) as bar:
        bar.update(4)
    assert capsys.readouterr().err == ""
