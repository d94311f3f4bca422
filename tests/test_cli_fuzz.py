"""Every user error of the command line exits 2 with one line that names the file or flag
and what was expected, and no traceback: random bytes as a cell or frames file, random
edits of a valid cell file, bad flag values. In-process through ``polyhull.cli.main``.

``run CELL --frames MISSING.npz`` reads the cell and then stops at the missing frames file
before any monitor is built, so a cell edit that leaves a valid cell shows as the
``--frames`` error and a broken one as the cell's error.
"""

from __future__ import annotations

import pickle
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from polyhull import cli

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "fixtures"
CELL = FIXTURES / "cells" / "small_cell.toml"
FRAMES = FIXTURES / "frames" / "small_walk_000.npz"
# the cell's relative paths (intrinsics files, URDF) made absolute, so copies load anywhere
CELL_TEXT = CELL.read_text().replace('"../', f'"{FIXTURES.as_posix()}/')

_SETTINGS = settings(
    max_examples=25,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("cli_fuzz")


def _one_line_error(capsys: pytest.CaptureFixture[str], rc: int, *names: str) -> str:
    """The run exited 2 with one line on stderr naming every ``names``, and no traceback."""
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert rc == 2, (rc, err)
    assert "Traceback" not in captured.err and "Traceback" not in captured.out
    assert err.count("\n") == 0, err
    assert err.startswith("polyhull run: error: "), err
    for name in names:
        assert name in err, (name, err)
    return err


def _run(cell: Path, frames: Path) -> int:
    return cli.main(["run", str(cell), "--frames", str(frames)])


# -- random bytes ----------------------------------------------------------------------------
_junk = st.one_of(
    st.binary(max_size=400),
    st.binary(max_size=200).map(lambda b: b"PK\x03\x04" + b),  # a zip's magic, then junk
    st.binary(max_size=200).map(lambda b: b"\x93NUMPY" + b),  # an .npy's magic, then junk
    st.text(max_size=200).map(lambda t: t.encode("utf-8")),
    st.text(max_size=200).map(lambda t: t.encode("utf-16")),  # not UTF-8
)


@_SETTINGS
@given(data=st.one_of(_junk, st.binary(max_size=120).map(lambda b: CELL_TEXT[:300].encode() + b)))
def test_random_bytes_as_a_cell_file(work: Path, capsys: pytest.CaptureFixture[str], data: bytes) -> None:
    cell = work / "junk_cell.toml"
    cell.write_bytes(data)
    _one_line_error(capsys, _run(cell, work / "never.npz"), str(cell))


@_SETTINGS
@given(data=st.one_of(_junk, st.integers(0, FRAMES.stat().st_size - 1).map(lambda n: FRAMES.read_bytes()[:n])))
def test_random_bytes_as_a_frames_file(work: Path, capsys: pytest.CaptureFixture[str], data: bytes) -> None:
    """Junk, and every truncation of a valid frames file (a zip's directory is at its end)."""
    frames = work / "junk_frames.npz"
    frames.write_bytes(data)
    err = _one_line_error(capsys, _run(CELL, frames), str(frames))
    assert "allow_pickle" not in err  # numpy's advice to load the file unsafely


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b'name = "a cell"\n', "not a zip archive of named arrays"),
        (b"", "not a zip archive of named arrays"),
        (pickle.dumps({"q": [0.0]}), "pickled objects, which polyhull never loads"),
    ],
    ids=["toml", "empty", "pickle"],
)
def test_a_frames_file_that_is_not_an_npz(work: Path, capsys: pytest.CaptureFixture[str], data: bytes, reason: str) -> None:
    frames = work / "not_frames.toml"
    frames.write_bytes(data)
    err = _one_line_error(capsys, _run(CELL, frames), str(frames), reason)
    assert "allow_pickle" not in err and "pickle.load" not in err


@pytest.mark.parametrize(
    ("fields", "words"),
    [
        ({"sw": np.zeros((4, 4), np.float32), "stamp": 1.0}, "missing field 'q'"),
        ({"sw": np.zeros((4, 4), np.float32), "q": np.zeros(6)}, "missing field 'stamp'"),
        ({"q": np.array(["a", "b"]), "stamp": 1.0}, "field 'q'"),
        ({"q": np.zeros(6) + 1j, "stamp": 1.0}, "field 'q' must be real numbers"),
        ({"q": np.zeros(6), "stamp": np.array("soon")}, "stamp"),
        ({"q": np.zeros(6), "stamp": np.nan}, "stamp"),
        ({"sw": np.zeros((4, 4), np.int8), "q": np.zeros(6), "stamp": 1.0}, "dtype"),
        ({"sw": np.zeros(4, np.float32), "q": np.zeros(6), "stamp": 1.0}, "2-D"),
    ],
    ids=["no-q", "no-stamp", "q-strings", "q-complex", "stamp-string", "stamp-nan", "depth-int8", "depth-1d"],
)
def test_frames_files_with_bad_fields(work: Path, capsys: pytest.CaptureFixture[str], fields: dict, words: str) -> None:  # type: ignore[type-arg]
    frames = work / "bad_fields.npz"
    np.savez(frames, **fields)
    _one_line_error(capsys, _run(CELL, frames), str(frames), words)


# -- random edits of a valid cell file ---------------------------------------------------------
_ASSIGN = re.compile(r"^(\s*)([A-Za-z_]\w*)(\s*=\s*)(.+?)(\s*#.*)?$")
_LINES = CELL_TEXT.splitlines()
_KEYS = [i for i, line in enumerate(_LINES) if _ASSIGN.match(line)]
_SECTIONS = [i for i, line in enumerate(_LINES) if line.startswith("[")]


def _other_type(value: str) -> str:
    """A TOML value of another type than ``value``."""
    if value.startswith('"'):
        return "1.5"
    if value.startswith("{"):
        return "7"
    if value in ("true", "false"):
        return '"yes"'
    if value.startswith("["):
        return '"a list"'
    return '"a number"'


def _write(work: Path, lines: list[str]) -> Path:
    cell = work / "edited_cell.toml"
    cell.write_text("\n".join(lines) + "\n")
    return cell


@_SETTINGS
@given(line=st.sampled_from(_KEYS))
def test_a_value_of_the_wrong_type_names_its_key(work: Path, capsys: pytest.CaptureFixture[str], line: int) -> None:
    m = _ASSIGN.match(_LINES[line])
    assert m is not None
    lines = list(_LINES)
    lines[line] = f"{m[1]}{m[2]}{m[3]}{_other_type(m[4])}"
    cell = _write(work, lines)
    _one_line_error(capsys, _run(cell, work / "never.npz"), str(cell), m[2])


@_SETTINGS
@given(section=st.sampled_from([-1, *_SECTIONS]), key=st.sampled_from(["bogus_key", "Name", "camera_typo"]))
def test_an_unknown_key_is_named(work: Path, capsys: pytest.CaptureFixture[str], section: int, key: str) -> None:
    lines = list(_LINES)
    lines.insert(section + 1, f"{key} = 1")  # -1: at the top level
    cell = _write(work, lines)
    err = _one_line_error(capsys, _run(cell, work / "never.npz"), str(cell), key)
    assert "unknown key" in err


@_SETTINGS
@given(line=st.sampled_from(_KEYS))
def test_a_dropped_key_is_named_or_takes_its_default(work: Path, capsys: pytest.CaptureFixture[str], line: int) -> None:
    m = _ASSIGN.match(_LINES[line])
    assert m is not None
    cell = _write(work, _LINES[:line] + _LINES[line + 1 :])
    err = _one_line_error(capsys, _run(cell, work / "never.npz"))
    if "--frames" not in err:  # the cell no longer loads: the error says which entry
        assert str(cell) in err and m[2] in err, (m[2], err)


# -- bad flag values -------------------------------------------------------------------------
_C = str(CELL)
_F = str(FRAMES)


@pytest.mark.parametrize(
    ("argv", "flag"),
    [
        (["bench", "--cycles", "0"], "--cycles"),
        (["bench", "--warmup", "-1"], "--warmup"),
        (["demo", "--cycles", "0"], "--cycles"),
        (["demo", "--dt", "nan"], "--dt"),
        (["demo", "--seed", "-1", "--cycles", "1", "--no-html", "--no-plot"], "--seed"),
        (["bench", "--peers-resolution", "0", "--cycles", "1"], "--peers-resolution"),
        (["bench", "--peers-full-rays"], "--peers-full-rays"),
        (["render", _C, "--out", "x.npz", "--target", "person:walking:-1"], "--target 'person:walking:-1': person height"),
        (["render", _C, "--out", "x.npz", "--dropout", "1.5"], "--dropout"),
        (["render", _C, "--out", "x.npz", "--stamp", "inf"], "--stamp"),
        (["render", _C, "--out", "x.npz", "--target", "no-such-mesh@1,2"], "--target"),
        (["place", _C, "--budget-seconds", "0"], "--budget-seconds"),
        (["place", _C, "--seed", "-1"], "--seed"),
        (["place", _C, "--workers", "0"], "--workers"),
        (["place", _C, "--workers", "-2"], "--workers"),
        (["place", _C, "--budget-evals", "0"], "--budget-evals"),
        (["place", _C, "--scenes", "0"], "--scenes"),
        (["place", _C, "--k-of-n", "0"], "--k-of-n"),
        (["place", _C, "--eps", "-1"], "--eps"),
        (["place", _C, "--w1", "nan"], "--w1"),
        (["place", _C, "--w2", "-2"], "--w2"),
        (["place", _C, "--sigma0", "0"], "--sigma0"),
        (["place", _C, "--pixel-step", "0"], "--pixel-step"),
        (["place", _C, "--importance", "1,2:3"], "--importance"),
        (["teach", _C, str(FIXTURES), "--seconds", "-1"], "--seconds"),
        (["replay", _C, str(FIXTURES), "--seconds", "0"], "--seconds"),
        (["view", _C, "--serve-seconds", "-1"], "--serve-seconds"),
        (["run", _C, "--frames", _F, "--plot", "timeline.svg"], "--plot"),
        (["run", _C, "--frames", "no-such.npz"], "--frames"),
    ],
    ids=lambda a: " ".join(a) if isinstance(a, list) else a,
)
def test_bad_flag_values(capsys: pytest.CaptureFixture[str], argv: list[str], flag: str) -> None:
    rc = cli.main(argv)
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert rc == 2, (rc, err)
    assert "Traceback" not in captured.err
    assert err.count("\n") == 0 and err.startswith(f"polyhull {argv[0]}: error: {flag}"), err
    assert captured.out == ""  # rejected before anything ran (no header line)


@pytest.mark.parametrize(
    ("argv", "flag"),
    [
        (["bench", "--cycles", "many"], "--cycles"),
        (["place", _C, "--grid", "0,0,0"], "--grid"),
        (["place", _C, "--cameras", "x"], "--cameras"),
        (["place", _C, "--cameras", "5-2"], "--cameras: expected a range A-B with A <= B, got '5-2'"),
        (["place", _C, "--grid", "1,2"], "--grid: expected three positive integers"),
        (["place", _C, "--objective", "f9"], "--objective"),
        (["render", _C, "--out", "x.npz", "--seed", "1.5"], "--seed"),
        (["run", _C], "--frames"),
        (["demo", "--bogus"], "unrecognized arguments: --bogus"),
        (["run", _C, "--frames", _F, "--bogus", "x"], "unrecognized arguments: --bogus x"),
    ],
    ids=lambda a: " ".join(a) if isinstance(a, list) else a,
)
def test_unparseable_flag_values(capsys: pytest.CaptureFixture[str], argv: list[str], flag: str) -> None:
    """argparse's own errors: exit 2, and the one error line (after its usage lines) names
    the flag and what was expected."""
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err and captured.out == ""
    errors = [line for line in captured.err.splitlines() if "error:" in line]
    assert len(errors) == 1 and errors[0].startswith(f"polyhull {argv[0]}: error:") and flag in errors[0], captured.err
    assert captured.err.rstrip().endswith(errors[0])
    assert captured.err.startswith(f"usage: polyhull {argv[0]} ")  # the sub-command's usage
    assert re.search(r"(--[\w-]+): \1\b", errors[0]) is None, errors[0]  # no flag named twice over
