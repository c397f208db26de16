"""Where is the corrupted byte? Locating a single-byte error from a CRC-32 (zlib) mismatch.

CRC-32 is linear: for equal-length messages crc(m ^ e) ^ crc(m) = R(e), the raw register of the error
pattern alone. A one-byte error v at position p of an n-byte message gives R(e) = Z^(n-1-p) T[v], where
Z is the register update for one zero byte and T the byte table. Z is invertible (the top byte of T[b]
determines b), so stepping the syndrome back through Z^-1 k times and finding a T[v] locates the byte.
The n steps are computed vectorised by doubling (Z^-(2^j) applied as four byte tables). A random
32-bit syndrome meets one of the 255 T[v] at ~n * 255 / 2^32 spurious positions (0.2 for a 4 MB log),
so every candidate is returned and the caller names them (when there are few).
"""

from __future__ import annotations

import numpy as np

POLY = 0xEDB88320   # zlib's CRC-32, reflected


def _byte_table() -> np.ndarray:
    t = np.arange(256, dtype=np.uint32)
    for _ in range(8):
        t = np.where(t & 1, (t >> np.uint32(1)) ^ np.uint32(POLY), t >> np.uint32(1)).astype(np.uint32)
    return t


def _inverse_zero_step(y: np.ndarray, table: np.ndarray, top_inv: np.ndarray) -> np.ndarray:
    """Z^-1 on uint32 registers: Z(r) = (r >> 8) ^ T[r & 0xff]; the top byte of Z(r) is the top byte of T[b]."""
    b = top_inv[(y >> np.uint32(24)).astype(np.int64)]
    return (((y ^ table[b]) << np.uint32(8)) | b.astype(np.uint32)).astype(np.uint32)


def _apply(tables: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A GF(2)-linear map on uint32 given as 4 byte tables (tables[i][b] = map(b << 8i))."""
    out = tables[0][(x & np.uint32(0xFF)).astype(np.int64)]
    for i in (1, 2, 3):
        out = out ^ tables[i][((x >> np.uint32(8 * i)) & np.uint32(0xFF)).astype(np.int64)]
    return out


def _tables_of(fn_basis: np.ndarray) -> np.ndarray:
    """Byte tables of a linear map from its images of the 32 basis bits."""
    tables = np.zeros((4, 256), dtype=np.uint32)
    values = np.arange(256)
    for i in range(4):
        acc = np.zeros(256, dtype=np.uint32)
        for bit in range(8):
            acc ^= np.where((values >> bit) & 1, fn_basis[8 * i + bit], 0).astype(np.uint32)
        tables[i] = acc
    return tables


def candidate_offsets(message: bytes, syndrome: int) -> list[int]:
    """Offsets at which one corrupted byte gives this syndrome (stored ^ computed CRC): in the message, or
    in the 4 CRC bytes after it (a syndrome of one non-zero byte: the stored CRC itself was hit)."""
    n = len(message)
    crc_bytes = [n + i for i in range(4) if (syndrome >> (8 * i)) & 0xFF]
    found = crc_bytes if len(crc_bytes) == 1 else []
    if n <= 0 or syndrome == 0:
        return found
    table = _byte_table()
    top_inv = np.zeros(256, dtype=np.int64)
    top_inv[(table >> np.uint32(24)).astype(np.int64)] = np.arange(256)
    basis = np.array([1 << k for k in range(32)], dtype=np.uint32)
    step = _tables_of(_inverse_zero_step(basis, table, top_inv))      # Z^-1
    s = np.empty(n, dtype=np.uint32)
    s[0] = np.uint32(syndrome)
    filled = 1
    while filled < n:                       # s[k] = Z^-k syndrome, by doubling
        take = min(filled, n - filled)
        s[filled:filled + take] = _apply(step, s[:take])
        filled += take
        if filled < n:
            step = _tables_of(_apply(step, _apply(step, basis)))     # Z^-2filled
    k = np.nonzero(np.isin(s, table[1:]))[0]
    return sorted(int(n - 1 - i) for i in k) + found
