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
