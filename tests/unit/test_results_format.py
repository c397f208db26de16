"""harness/stream/results_file.py owns the results file's format: its columns are the protocol's RESULT fields
plus the host's, what the writer writes the reader reads back with the same dtypes (plain or gzip), and
malformed lines are refused naming the file and line; the campaign store and the resume read through it."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from harness.campaign.store import CampaignDataError, load_results
from harness.errors import ResultsFileError
from harness.stream.resume import ResumeError, read_results
from harness.stream.results_file import (COLUMNS, OUTCOME_RESULT, REC_STATS, RESULT_FIELDS, RESULTS_DTYPE,
                                         ResultsWriter, column_dtype, read_run)
from protocol import messages as m
from protocol.batch import RESULT_DTYPE


def _rows(n: int) -> np.ndarray:
    rows = np.zeros(n, RESULTS_DTYPE)
    rows["t_us"] = np.arange(n) * 5000 + 123
    rows["px"] = np.linspace(-1.5, 2.25, n)
    rows["status"] = 1
    rows["outcome"] = OUTCOME_RESULT
    rows["t_send_ns"] = 10**15 + np.arange(n)
    return rows


def _write(path: Path, rows: np.ndarray, n: int | None = None) -> None:
    w = ResultsWriter(path, {"flight": "f", "config": {}, "pacing": {"mode": "windowed"},
                             "n_measurements": len(rows) if n is None else n})
    w.write_rows(np.arange(len(rows)), rows)
    w.write_record({"type": REC_STATS, "uwb_frames": 7})
    w.close()


def test_the_columns_are_the_protocols_result_fields_then_the_hosts() -> None:
    assert RESULT_FIELDS == tuple(name for name, _ in m.Result.FIELDS)
    assert COLUMNS[0] == "index" and COLUMNS[1:1 + len(RESULT_FIELDS)] == RESULT_FIELDS
    assert COLUMNS[-4:] == ("t_send_ns", "t_recv_ns", "outcome", "error_code")
    for name in RESULT_FIELDS:
        assert RESULTS_DTYPE[name] == RESULT_DTYPE[name]
        assert column_dtype(name) == (np.int64 if RESULT_DTYPE[name].kind in "iu" else np.float64)


@pytest.mark.parametrize("gz", [False, True])
def test_what_the_writer_writes_the_reader_reads_back(tmp_path: Path, gz: bool) -> None:
    rows = _rows(50)
    path = tmp_path / "r.jsonl"
    _write(path, rows)
    if gz:
        gz_path = tmp_path / "r.jsonl.gz"
        gz_path.write_bytes(gzip.compress(path.read_bytes()))
        path = gz_path
    run = read_run(path)
    assert len(run) == 50 and run.header["flight"] == "f" and run.stats == {"type": REC_STATS, "uwb_frames": 7}
    back = run.results_array(60)
    for name in RESULTS_DTYPE.names or ():
        assert np.array_equal(back[name][:50], rows[name]), name
    assert run.columns["t_us"].dtype == np.int64 and run.columns["px"].dtype == np.float64
    assert not back["outcome"][50:].any()
    store = load_results(path)          # the campaign report's reader is the same
    assert np.array_equal(store.columns["t_us"], rows["t_us"])


def test_a_cut_last_line_is_ignored_only_by_the_resume(tmp_path: Path) -> None:
    path = tmp_path / "r.jsonl"
    _write(path, _rows(10), n=20)
    text = path.read_text().splitlines()
    path.write_text("\n".join(text[:8]) + "\n" + text[8][:30])       # killed while writing result 8
    rec = read_results(path)
    assert rec.ignored_partial_line and rec.next_index == 7 and not rec.complete
    with pytest.raises(CampaignDataError, match=r"r\.jsonl:9: not JSON"):
        load_results(path)


def test_malformed_lines_are_named(tmp_path: Path) -> None:
    path = tmp_path / "r.jsonl"
    _write(path, _rows(3))
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0], lines[2], lines[1]]) + "\n")
    with pytest.raises(ResultsFileError, match=r"r\.jsonl:2: result index 1, expected 0"):
        read_run(path)
    path.write_text("\n".join([lines[0], lines[1].replace('"px": -1.5', '"px": "x"')]) + "\n")
    with pytest.raises(ResumeError, match=r"r\.jsonl:2: result field 'px' is 'x', expected a number"):
        read_results(path)
    path.write_text("\n".join([lines[1], lines[0]]) + "\n")
    with pytest.raises(ResultsFileError, match=r"r\.jsonl:1: the first line must be the run header"):
        read_run(path)


def test_binary_or_damaged_gzip_results_are_named_input_errors(tmp_path: Path) -> None:
    """`run --resume` on a binary file, or a cut / fake .jsonl.gz: the resume's own error (exit 2) naming the
    file, never a UnicodeDecodeError or EOFError (exit 4)."""
    binary = tmp_path / "r.jsonl"
    binary.write_bytes(bytes(range(128, 256)) * 40)
    with pytest.raises(ResumeError, match=r"r\.jsonl: not UTF-8 text"):
        read_results(binary)
    _write(tmp_path / "good.jsonl", _rows(400))
    packed = gzip.compress((tmp_path / "good.jsonl").read_bytes())
    cut = tmp_path / "cut.jsonl.gz"
    cut.write_bytes(packed[:len(packed) // 2])
    with pytest.raises(ResumeError, match=r"cut\.jsonl\.gz: cannot be read"):
        read_results(cut)
    fake = tmp_path / "fake.jsonl.gz"
    fake.write_bytes(b"not gzip at all\n")
    with pytest.raises(CampaignDataError, match=r"fake\.jsonl\.gz: cannot be read"):
        load_results(fake)
