"""The numpy bulk codec produces exactly the bytes of the scalar reference codec."""

from __future__ import annotations

import numpy as np

from protocol.batch import cobs_decode_rows, cobs_encode_rows, decode_rows, encode_rows
from protocol import FrameDecoder, encode_frame
from protocol import messages as m
from protocol.cobs import cobs_encode


def _f32(x: float) -> float:
    return float(np.float32(x))


def test_bulk_encode_matches_scalar_codec() -> None:
    rng = np.random.default_rng(7)
    n = 500
    cols = {"t_us": rng.integers(0, 2**40, n), "anchor_a": rng.integers(0, 8, n),
            "anchor_b": rng.integers(0, 8, n), "diff": rng.normal(size=n)}
    cols["diff"][:50] = 0.0  # zero bytes exercise COBS
    seqs = np.arange(65500, 65500 + n)  # wraps at 16 bits
    rows = encode_rows(m.Tdoa, cols, seqs)
    for i in range(n):
        ref = encode_frame(m.Tdoa(t_us=int(cols["t_us"][i]), anchor_a=int(cols["anchor_a"][i]),
                                  anchor_b=int(cols["anchor_b"][i]), diff=_f32(cols["diff"][i])),
                           int(seqs[i]) & 0xFFFF)
        assert rows[i].tobytes() == ref
    frames = FrameDecoder().feed(rows.tobytes())
    assert len(frames) == n


def test_row_cobs_matches_scalar_and_roundtrips() -> None:
    rng = np.random.default_rng(3)
    body = rng.integers(0, 256, size=(300, 40), dtype=np.uint8)
    body[::3, ::2] = 0
    body[5] = 0
    enc = cobs_encode_rows(body)
    for i in range(len(body)):
        assert enc[i].tobytes() == cobs_encode(body[i].tobytes())
    dec, valid = cobs_decode_rows(enc)
    assert valid.all() and np.array_equal(dec, body)


def test_bulk_decode_flags_corruption() -> None:
    rows = encode_rows(m.Imu, {"t_us": np.arange(10), "ax": np.ones(10), "ay": np.zeros(10), "az": np.ones(10),
                               "gx": np.zeros(10), "gy": np.zeros(10), "gz": np.zeros(10)}, np.arange(10))
    enc = rows[:, :-1].copy()
    enc[2, 10] ^= 0x10     # payload bit: CRC catches it
    enc[4, 0] = 0x7F       # code byte: COBS chain breaks
    arr, valid = decode_rows(m.Imu, enc)
    assert list(np.nonzero(~valid)[0]) == [2, 4]
    assert list(arr["t_us"][valid]) == [0, 1, 3, 5, 6, 7, 8, 9]


def test_small_and_large_batch_paths_agree() -> None:
    """Reads of a few RESULTs take the per-row path (crcmod, scalar COBS), big batches the column-wise one:
    same bodies, same verdicts, on clean and corrupted rows alike."""
    from protocol import batch
    rng = np.random.default_rng(11)
    n = 3 * batch.SMALL_BATCH
    rows = encode_rows(m.Tdoa, {"t_us": rng.integers(0, 2**40, n), "anchor_a": rng.integers(0, 8, n),
                                "anchor_b": rng.integers(0, 8, n), "diff": np.where(rng.random(n) < 0.3, 0.0,
                                                                                    rng.normal(size=n))},
                       np.arange(n))
    enc = rows[:, :-1].copy()
    hit = rng.random(n) < 0.3
    cols = rng.integers(0, enc.shape[1], n)
    enc[hit, cols[hit]] ^= rng.integers(1, 256, n, dtype=np.uint8)[hit]       # payload, code bytes, zeros
    big_arr, big_valid = decode_rows(m.Tdoa, enc)
    assert len(enc) >= batch.SMALL_BATCH
    small = [decode_rows(m.Tdoa, enc[i:i + 50]) for i in range(0, n, 50)]
    small_valid = np.concatenate([v for _, v in small])
    small_arr = np.concatenate([a for a, _ in small])
    assert np.array_equal(small_valid, big_valid)
    assert 0 < int(np.count_nonzero(~big_valid)) <= int(np.count_nonzero(hit))
    assert np.array_equal(small_arr[small_valid], big_arr[big_valid])
    body = enc[:20]
    assert np.array_equal(batch.crc32c_rows(body), np.concatenate([batch.crc32c_rows(np.repeat(body, 20, axis=0))[::20]]))
