"""Inputs can't hurt (issue 27): an output path that is an input of the run, pacing speed, ... Every case
asserts the exit code, the one-line message and that the input file is intact."""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import pytest

from harness import cli

ROOT = Path(__file__).resolve().parents[2]
FIX = ROOT / "tests" / "fixtures" / "recordings"
REDUCED = FIX / "const1-fixture-tdoa2.csv"


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _one_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("how", ["same path", "hard link", "anchors"])
def test_results_over_an_input_is_refused_even_with_overwrite(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                              how: str) -> None:
    rec, anchors = tmp_path / "rec.csv", tmp_path / "anchors.csv"
    shutil.copy(REDUCED, rec)
    shutil.copy(FIX / "anchors.csv", anchors)
    target = {"same path": rec, "anchors": anchors, "hard link": tmp_path / "link.jsonl"}[how]
    if how == "hard link":
        os.link(rec, target)
    before = {p: _digest(p) for p in (rec, anchors)}
    code = cli.main(["run", "--recording", str(rec), "--anchors", str(anchors), "--results", str(target), "--overwrite"])
    assert code == 2
    err = _one_error(capsys)
    assert err.startswith(f"uwb-hil: error: results file {target} is an input of this run"), err
    assert {p: _digest(p) for p in (rec, anchors)} == before


def test_results_inside_a_recording_folder_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    seq = tmp_path / "sequence9"
    seq.mkdir()
    victim = seq / "uwb_range.csv"
    victim.write_text("t,range\n")
    assert cli.main(["run", "--recording", str(seq), "--results", str(victim), "--overwrite"]) == 2
    assert "is an input of this run" in _one_error(capsys) and victim.read_text() == "t,range\n"


# ------------------------------------------------------------------------------ recordings
def test_a_2gb_file_without_newline_fails_fast_in_small_memory(tmp_path: Path) -> None:
    """It took 28 s, 8.4 GB and printed a 2 GB error message (the first line was read whole and echoed).
    A sparse file: no disk space used."""
    import subprocess
    import sys
    big = tmp_path / "big.csv"
    with open(big, "wb") as f:
        f.truncate(2 << 30)
    probe = ("import resource, subprocess, sys, time; t = time.monotonic(); "
             "p = subprocess.run([sys.executable, '-m', 'harness.cli', 'run', '--recording', sys.argv[1], '--anchors', "
             "sys.argv[2]], capture_output=True, text=True); "
             "print(p.returncode, time.monotonic() - t, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); "
             "sys.stdout.write(p.stderr)")
    out = subprocess.run([sys.executable, "-c", probe, str(big), str(FIX / "anchors.csv")], capture_output=True,
                         text=True, timeout=120, cwd=ROOT)
    first, _, err = out.stdout.partition("\n")
    code, seconds, rss_kb = first.split()
    assert int(code) == 2, out.stdout + out.stderr
    assert float(seconds) < 20 and int(rss_kb) < 400_000, first
    assert len(err.strip().splitlines()) == 1 and len(err) < 800, err     # 100 characters quoted (NULs: \x00)
    assert "line 1: line longer than 65536 characters (not a text recording?)" in err
    assert err.count("\\x00") == 100 and err.rstrip().endswith("... (65537 characters)"), err


def _fixture_lines() -> list[str]:
    return REDUCED.read_text().splitlines(keepends=True)


def test_a_last_line_cut_inside_its_last_field_is_dropped_with_a_warning(tmp_path: Path,
                                                                         capsys: pytest.CaptureFixture[str]) -> None:
    from harness.flight.formats.common import RecordingWarning
    from harness.flight.loaders import load_recording
    lines = _fixture_lines()
    cut, whole = tmp_path / "const1-cut.csv", tmp_path / "const1-whole.csv"
    cut.write_text("".join(lines[:-1]) + lines[-1].rstrip("\n")[:-3])        # the file ends inside a field
    whole.write_text("".join(lines[:-1]))
    with pytest.warns(RecordingWarning, match=r"const1-cut.csv, line 41: the last line has no newline .*dropped"):
        got = load_recording(cut, anchors=FIX / "anchors.csv", check=False)
    want = load_recording(whole, anchors=FIX / "anchors.csv", check=False)
    assert len(got.uwb) == len(want.uwb) and (got.uwb.value == want.uwb.value).all()
    code = cli.main(["run", "--recording", str(cut), "--anchors", str(FIX / "anchors.csv"), "--duration", "1",
                     "--stages", "outlier", "--force", "--firmware", "/nonexistent/uwb-fw"])
    err = capsys.readouterr().err
    assert "uwb-hil: warning: " in err and "the last line has no newline" in err, err
    assert code == 2     # the firmware path is refused after the load: no device needed here


def test_a_value_outside_float32_is_refused_at_load(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A TDoA of 1e39 (finite in float64, inf in float32) reached the device ("device refused", exit 1)."""
    lines = _fixture_lines()
    cells = lines[5].split(",")
    cells[2] = "1e39"
    bad = tmp_path / "const1-bad.csv"
    bad.write_text("".join(lines[:5]) + ",".join(cells) + "".join(lines[6:]))
    before = _digest(bad)
    assert cli.main(["run", "--recording", str(bad), "--anchors", str(FIX / "anchors.csv"), "--force"]) == 2
    err = _one_error(capsys)
    assert "uwb value 1e+39 (index 4) is outside the device's 32-bit float range" in err, err
    assert _digest(bad) == before


def test_float_anchor_ids_in_a_native_file_must_be_integral(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Float ids in a .npz were truncated (5.9 -> 5): another anchor."""
    import numpy as np
    from harness.flight.native import save_flight
    from harness.flight.scenarios import scenario_flight
    path = save_flight(scenario_flight("circle", mode="twr", duration_s=2.0, seed=1), tmp_path / "f.npz")
    with np.load(path, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    ids = data["uwb_anchor_a"].astype(np.float64)
    exact = tmp_path / "exact.npz"
    np.savez(exact, **{**data, "uwb_anchor_a": ids})                      # integral floats: accepted
    ids[3] += 0.9
    bad = tmp_path / "bad.npz"
    np.savez(bad, **{**data, "uwb_anchor_a": ids})
    from harness.flight.loaders import load_recording
    assert load_recording(exact).uwb.anchor_a.dtype.kind == "i"
    assert cli.main(["run", "--recording", str(bad)]) == 2
    err = _one_error(capsys)
    assert "field 'uwb_anchor_a': expected integer anchor ids, got " in err and "at index 3" in err, err


@pytest.mark.parametrize("suffix", [".yaml", ".txt", ".csv"])
def test_a_huge_anchor_file_is_refused_before_it_is_read(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                         suffix: str) -> None:
    big = tmp_path / f"anchors{suffix}"
    with open(big, "wb") as f:
        f.truncate(2 << 30)
    assert cli.main(["run", "--recording", str(REDUCED), "--anchors", str(big)]) == 2
    assert "too large for an anchor file" in _one_error(capsys)


def test_results_target_without_newlines_is_judged_in_small_memory(tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """--results naming a 2 GB file without newline: refused as not a results file, without reading it whole."""
    import resource
    big = tmp_path / "big.jsonl"
    with open(big, "wb") as f:
        f.truncate(2 << 30)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    assert cli.main(["run", "--duration", "2", "--results", str(big)]) == 2
    assert "it is not a uwb-hil results file" in _one_error(capsys)
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 200_000      # kB


def test_a_results_header_source_is_checked_with_the_options_own_types() -> None:
    """What `run --resume` applies to a header before building anything (a tuple option included)."""
    from harness.cli import build_parser
    from harness.cli_run import check_header_source as check, subparser
    from harness.errors import ResultsFileError
    from harness.run.source import RunSource

    def check_header_source(src: dict, where: str) -> None:  # type: ignore[type-arg]
        check(subparser(build_parser(), "run"), RunSource.keys(), src, where)

    good = RunSource(recording="x.bin", lever_arm=(0.01, 0.0, 0.09), set=["std_twr=0.2"]).as_header()
    check_header_source(good, "f:1: header source")
    for key, value, phrase in (("lever_arm", [5.0, 0.0, 0.0], "--lever-arm must be >= -1 and <= 1 m"),
                               ("lever_arm", {"x": 1}, "not a value --lever-arm takes"),
                               ("seed", -1, "--seed must be >= 0"), ("radio", "tdoa9", "--radio must be one of"),
                               ("uwb_only", 1, "--uwb-only is a switch")):
        with pytest.raises(ResultsFileError, match=phrase):
            check_header_source({**good, key: value}, "f:1: header source")


def test_a_damaged_model_file_is_exit_2_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A cut, zip-looking or bit-flipped .npz, a text format_version, a directory given as --model: a
    ModelFormatError naming the file (exit 2), never zipfile's BadZipFile or int()'s ValueError (exit 4)."""
    import numpy as np
    from harness.biasnet.network import BiasModel, ModelFormatError
    data = (ROOT / "firmware_sim" / "models" / "bias_model_default.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[:len(data) // 2])
    (tmp_path / "pk.npz").write_bytes(b"PK\x03\x04garbage" * 10)
    k = len(data) // 3
    (tmp_path / "flipped.npz").write_bytes(data[:k] + bytes(b ^ 0x55 for b in data[k:k + 64]) + data[k + 64:])
    np.savez(tmp_path / "version.npz", format_version=np.array("abc"))
    for name in ("cut.npz", "pk.npz", "flipped.npz", "version.npz"):
        with pytest.raises(ModelFormatError, match=name):
            BiasModel.load(tmp_path / name)
    with pytest.raises(FileNotFoundError, match="is a directory"):
        BiasModel.load(tmp_path)
    assert cli.main(["export-c", str(tmp_path / "cut.npz"), "--out", str(tmp_path / "m.h")]) == 2
    assert "cut.npz: not a bias-model .npz (not a zip archive" in _one_error(capsys)
