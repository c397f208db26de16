"""The bias network as plain arrays: the one container shared by training, the twin, export and the report.

A model holds up to two networks (TWR and TDoA), each 2 hidden layers x 50 ReLU -> 1 linear output with
min-max input scaling and a clamped, de-scaled output (the maths of firmware_sim/core/bias_nn.c).
A network may carry a second head on the same hidden layer: the log of the standard deviation of the
corrected error, ``std = clamp(exp(h2 . w3s + b3s), std_min, std_max)``, which the firmware uses as the
measurement's standard deviation (train.py fits it; the bounds are stored with the weights).
Files are ``.npz`` written and read with ``allow_pickle=False``: loading never runs code.

The model hash (reported by the firmware in HELLO) is the first 8 bytes, little-endian, of SHA-256 over
:meth:`BiasModel.canonical_bytes`: a fixed byte layout of every float32 table, so the same weights give
the same hash in Python and in the generated C header.
"""

from __future__ import annotations

import hashlib
import json
import struct
import zipfile
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from harness.biasnet.q15 import Q15Network
from harness.twin.features import (LAYOUT_TDOA_POS, LAYOUT_TDOA_POSE, LAYOUT_TWR_POS, LAYOUT_TWR_POSE,
                                   layout_inputs)
from harness.errors import InputError, InputFileNotFound

HIDDEN = 50
QUANTS = ("float32", "q15")
FORMAT_VERSION = 2          # 2: optional std head; version-1 files (no head) still load
_READABLE_VERSIONS = (1, 2)
_MAGIC = b"UWBNN\x01"
_KINDS = ("twr", "tdoa")
_TWR_LAYOUTS = (LAYOUT_TWR_POSE, LAYOUT_TWR_POS)
_TDOA_LAYOUTS = (LAYOUT_TDOA_POSE, LAYOUT_TDOA_POS)


class ModelFormatError(InputError):
    """A model file or array set is not a valid bias network (names the file and the field)."""


@dataclass(frozen=True)
class BiasNetwork:
    """One network. Weight matrices are input-major: ``w1[i, j]`` connects input i to hidden unit j."""

    layout: int
    w1: np.ndarray      # (n_in, 50) float32
    b1: np.ndarray      # (50,)
    w2: np.ndarray      # (50, 50)
    b2: np.ndarray      # (50,)
    w3: np.ndarray      # (50,)
    b3: float
    in_min: np.ndarray  # (n_in,)
    in_max: np.ndarray  # (n_in,)
    out_min: float
    out_max: float
    w3s: np.ndarray | None = None  # (50,) std head (log std), or None: no uncertainty output
    b3s: float = 0.0
    std_min: float = 0.0           # bounds of the predicted std [m] (0 < std_min < std_max with a head)
    std_max: float = 0.0
    #: how the firmware computes it: "float32" or "q15" (q15.py: integers from these float tables,
    #: computed by predict* as the firmware does; part of the hash)
    quant: str = "float32"
    _q15: Any = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        n_in = layout_inputs(self.layout)
        if n_in == 0:
            raise ModelFormatError(f"unknown input layout {self.layout}")
        shapes = {"w1": (n_in, HIDDEN), "b1": (HIDDEN,), "w2": (HIDDEN, HIDDEN), "b2": (HIDDEN,),
                  "w3": (HIDDEN,), "in_min": (n_in,), "in_max": (n_in,)}
        for name, shape in shapes.items():
            arr = np.ascontiguousarray(getattr(self, name), dtype=np.float32)
            if arr.shape != shape:
                raise ModelFormatError(f"{name} must have shape {shape} for layout {self.layout}, got {arr.shape}")
            if not np.all(np.isfinite(arr)):
                raise ModelFormatError(f"{name} holds NaN or Inf")
            object.__setattr__(self, name, arr)
        for name in ("b3", "out_min", "out_max"):
            value = float(np.float32(getattr(self, name)))
            if not np.isfinite(value):
                raise ModelFormatError(f"{name} must be finite")
            object.__setattr__(self, name, value)
        if not np.all(self.in_max > self.in_min):
            raise ModelFormatError("in_max must exceed in_min for every input (widen constant features)")
        if not self.out_max > self.out_min:
            raise ModelFormatError("out_max must exceed out_min")
        self._check_std_head()
        if self.quant not in QUANTS:
            raise ModelFormatError(f"quant must be one of {QUANTS}, got {self.quant!r}")
        if self.quant == "q15":
            object.__setattr__(self, "_q15", Q15Network.from_network(self))

    @property
    def q15(self) -> Any:
        """The :class:`~harness.biasnet.q15.Q15Network` of a q15 network (None for float32)."""
        return self._q15

    def _check_std_head(self) -> None:
        for name in ("b3s", "std_min", "std_max"):
            object.__setattr__(self, name, float(np.float32(getattr(self, name))))
        if self.w3s is None:
            return
        arr = np.ascontiguousarray(self.w3s, dtype=np.float32)
        if arr.shape != (HIDDEN,):
            raise ModelFormatError(f"w3s must have shape ({HIDDEN},), got {arr.shape}")
        if not (np.all(np.isfinite(arr)) and np.isfinite(self.b3s)):
            raise ModelFormatError("the std head holds NaN or Inf")
        if not (np.isfinite(self.std_max) and 0.0 < self.std_min < self.std_max):
            raise ModelFormatError(f"std bounds must satisfy 0 < std_min < std_max, got {self.std_min}, {self.std_max}")
        object.__setattr__(self, "w3s", arr)

    @property
    def has_std(self) -> bool:
        return self.w3s is not None

    @property
    def n_in(self) -> int:
        return int(self.w1.shape[0])

    # ------------------------------------------------------------------------------------ inference
    def hidden(self, features: np.ndarray) -> np.ndarray:
        """Second hidden layer (N, 50) for each row of ``features`` (N, n_in), float64 arithmetic."""
        x = np.asarray(features, dtype=np.float64).reshape(-1, self.n_in)
        lo, hi = self.in_min.astype(np.float64), self.in_max.astype(np.float64)
        xs = (x - lo) / (hi - lo)
        h1 = np.maximum(xs @ self.w1.astype(np.float64) + self.b1, 0.0)
        return np.maximum(h1 @ self.w2.astype(np.float64) + self.b2, 0.0)

    def _bias_from_hidden(self, h2: np.ndarray) -> np.ndarray:
        y = h2 @ self.w3.astype(np.float64) + self.b3
        y = y * (self.out_max - self.out_min) + self.out_min
        return np.clip(y, self.out_min, self.out_max)

    def _std_from_hidden(self, h2: np.ndarray) -> np.ndarray:
        assert self.w3s is not None
        with np.errstate(over="ignore"):
            std = np.exp(h2 @ self.w3s.astype(np.float64) + self.b3s)
        # NaN -> std_max (trust least), as bias_nn.c
        std = np.where(np.isnan(std) | (std > self.std_max), self.std_max, std)
        return np.maximum(std, self.std_min)

    def predict_batch(self, features: np.ndarray) -> np.ndarray:
        """Bias [m] for each row of ``features`` (N, n_in), float64 arithmetic on the float32 tables (a q15
        network: the firmware's integers, q15.py)."""
        if self._q15 is not None:
            return self._q15.predict_batch(features)  # type: ignore[no-any-return]
        return self._bias_from_hidden(self.hidden(features))

    def predict_with_std_batch(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bias and predicted std [m] per row; std 0 when the network has no std head."""
        if self._q15 is not None:
            return self._q15.predict_with_std_batch(features)  # type: ignore[no-any-return]
        h2 = self.hidden(features)
        std = self._std_from_hidden(h2) if self.w3s is not None else np.zeros(len(h2))
        return self._bias_from_hidden(h2), std

    def ood_excess_batch(self, features: np.ndarray) -> np.ndarray:
        """Per row: the largest distance of any input beyond [in_min, in_max], in units of that input's
        range width (0 inside; inf for NaN), as bias_nn_ood_excess() in C."""
        x = np.asarray(features, dtype=np.float64).reshape(-1, self.n_in)
        lo, hi = self.in_min.astype(np.float64), self.in_max.astype(np.float64)
        out = np.max(np.maximum(np.maximum((lo - x) / (hi - lo), (x - hi) / (hi - lo)), 0.0), axis=1)
        return np.where(np.any(np.isnan(x), axis=1), np.inf, out)

    def ood_excess(self, features: np.ndarray) -> float:
        return float(self.ood_excess_batch(features)[0])

    def predict(self, features: np.ndarray) -> float:
        """Bias [m] for one feature vector (the twin's ``BiasNet`` protocol)."""
        return float(self.predict_batch(np.asarray(features).reshape(1, -1))[0])

    def predict_with_std(self, features: np.ndarray) -> tuple[float, float]:
        """Bias and std [m] for one feature vector (std 0 without a std head)."""
        b, s = self.predict_with_std_batch(np.asarray(features).reshape(1, -1))
        return float(b[0]), float(s[0])

    # --------------------------------------------------------------------------------- serialisation
    def canonical_bytes(self) -> bytes:
        parts = [struct.pack("<BB", self.layout, self.n_in)]
        for name in ("w1", "b1", "w2", "b2", "w3"):
            parts.append(getattr(self, name).astype("<f4").tobytes())
        parts.append(struct.pack("<f", self.b3))
        parts.append(self.in_min.astype("<f4").tobytes())
        parts.append(self.in_max.astype("<f4").tobytes())
        parts.append(struct.pack("<ff", self.out_min, self.out_max))
        if self.w3s is not None:  # only with a head: networks without one keep their hash
            parts.append(b"S" + self.w3s.astype("<f4").tobytes())
            parts.append(struct.pack("<fff", self.b3s, self.std_min, self.std_max))
        if self.quant != "float32":  # float32 networks keep their hash
            parts.append(b"Q" + self.quant.encode())
        return b"".join(parts)

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {f"{prefix}_layout": np.array(self.layout, dtype=np.int64)}
        for name in ("w1", "b1", "w2", "b2", "w3", "in_min", "in_max"):
            out[f"{prefix}_{name}"] = getattr(self, name)
        for name in ("b3", "out_min", "out_max"):
            out[f"{prefix}_{name}"] = np.array(getattr(self, name), dtype=np.float32)
        if self.w3s is not None:
            out[f"{prefix}_w3s"] = self.w3s
            for name in ("b3s", "std_min", "std_max"):
                out[f"{prefix}_{name}"] = np.array(getattr(self, name), dtype=np.float32)
        if self.quant != "float32":
            out[f"{prefix}_quant"] = np.array(self.quant)
        return out

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str, source: str = "<arrays>") -> "BiasNetwork":
        names = ("layout", "w1", "b1", "w2", "b2", "w3", "b3", "in_min", "in_max", "out_min", "out_max")
        missing = [f"{prefix}_{n}" for n in names if f"{prefix}_{n}" not in arrays]
        if missing:
            raise ModelFormatError(f"{source}: missing arrays {missing}")
        head = [f"{prefix}_{n}" for n in ("w3s", "b3s", "std_min", "std_max")]
        present = [n for n in head if n in arrays]
        if present and len(present) != len(head):
            raise ModelFormatError(f"{source}: incomplete std head: has {present}, needs {head}")
        std = ({"w3s": arrays[head[0]], "b3s": float(arrays[head[1]]), "std_min": float(arrays[head[2]]),
                "std_max": float(arrays[head[3]])} if present else {})
        try:
            return cls(layout=int(arrays[f"{prefix}_layout"]),
                       **{n: arrays[f"{prefix}_{n}"] for n in ("w1", "b1", "w2", "b2", "w3", "in_min", "in_max")},
                       b3=float(arrays[f"{prefix}_b3"]), out_min=float(arrays[f"{prefix}_out_min"]),
                       out_max=float(arrays[f"{prefix}_out_max"]), **std,
                       quant=str(arrays.get(f"{prefix}_quant", "float32")))
        except ModelFormatError as exc:
            raise ModelFormatError(f"{source}: {prefix} network: {exc}") from None
        except (TypeError, ValueError) as exc:
            raise ModelFormatError(f"{source}: {prefix} network: malformed array ({exc})") from None


@dataclass(frozen=True)
class BiasModel:
    """The networks compiled into one firmware image: TWR and TDoA, either may be absent."""

    twr: BiasNetwork | None = None
    tdoa: BiasNetwork | None = None
    name: str = "unnamed"
    #: Provenance (training data, config, figures): saved with the model, not part of the hash.
    meta: dict[str, object] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        if self.twr is not None and self.twr.layout not in _TWR_LAYOUTS:
            raise ModelFormatError(f"the TWR network has a TDoA layout ({self.twr.layout})")
        if self.tdoa is not None and self.tdoa.layout not in _TDOA_LAYOUTS:
            raise ModelFormatError(f"the TDoA network has a TWR layout ({self.tdoa.layout})")

    def canonical_bytes(self) -> bytes:
        parts = [_MAGIC]
        for net in (self.twr, self.tdoa):
            parts.append(b"\x00" if net is None else b"\x01" + net.canonical_bytes())
        return b"".join(parts)

    @property
    def hash(self) -> int:
        """The u64 the firmware reports in HELLO for this model."""
        return int.from_bytes(hashlib.sha256(self.canonical_bytes()).digest()[:8], "little")

    @property
    def hash_hex(self) -> str:
        return f"{self.hash:016x}"

    def network(self, kind: str) -> BiasNetwork | None:
        if kind not in _KINDS:
            raise ValueError(f"kind must be 'twr' or 'tdoa', got {kind!r}")
        return getattr(self, kind)

    def quantized(self, quant: str = "q15", name: str | None = None) -> "BiasModel":
        """The same networks computed as ``quant`` by the firmware (another hash), named ``name`` or
        ``<name>-<quant>``."""
        nets = {k: None if n is None else replace(n, quant=quant) for k, n in (("twr", self.twr), ("tdoa", self.tdoa))}
        return BiasModel(**nets, name=name or f"{self.name}-{quant}", meta=dict(self.meta) | {"quant": quant})

    def replace(self, kind: str, net: BiasNetwork | None) -> "BiasModel":
        nets = {k: net if k == kind else getattr(self, k) for k in _KINDS}
        return BiasModel(twr=nets["twr"], tdoa=nets["tdoa"], name=self.name, meta=dict(self.meta))

    # ------------------------------------------------------------------------------------------ files
    def save(self, path: Path) -> Path:
        path = Path(path)
        # version 1 when no network has a std head: such files stay readable by older code
        version = FORMAT_VERSION if any(n is not None and n.has_std for n in (self.twr, self.tdoa)) else 1
        arrays: dict[str, np.ndarray] = {"format_version": np.array(version, dtype=np.int64),
                                         "name": np.array(self.name),
                                         "hash": np.array(self.hash_hex),
                                         "meta_json": np.array(json.dumps(self.meta, sort_keys=True, default=str))}
        for kind in _KINDS:
            net = self.network(kind)
            if net is not None:
                arrays.update(net.arrays(kind))
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "wb") as fh:
            np.savez(fh, **arrays)
        return path

    @classmethod
    def load(cls, path: Path) -> "BiasModel":
        path = Path(path)
        if not path.is_file():
            raise InputFileNotFound(f"bias model {path} " + ("is a directory, not a .npz file" if path.is_dir()
                                                             else "does not exist"))
        if not zipfile.is_zipfile(path):      # np.load would try to unpickle it, or fail deep in zipfile
            raise ModelFormatError(f"{path}: not a bias-model .npz (not a zip archive: truncated, or another "
                                   "kind of file)")
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {k: data[k] for k in data.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            raise ModelFormatError(f"{path}: not a bias-model .npz ({exc})") from None
        version = _format_version(arrays, path)
        if version not in _READABLE_VERSIONS:
            raise ModelFormatError(f"{path}: format_version {version}, expected one of {_READABLE_VERSIONS}")
        nets = {kind: BiasNetwork.from_arrays(arrays, kind, str(path)) if f"{kind}_layout" in arrays else None
                for kind in _KINDS}
        try:
            meta = json.loads(str(arrays.get("meta_json", "{}")))
        except json.JSONDecodeError as exc:
            raise ModelFormatError(f"{path}: meta_json is not JSON ({exc})") from None
        model = cls(twr=nets["twr"], tdoa=nets["tdoa"], name=str(arrays.get("name", path.stem)), meta=meta)
        stored = str(arrays.get("hash", ""))
        if stored and stored != model.hash_hex:
            raise ModelFormatError(f"{path}: stored hash {stored} does not match its weights ({model.hash_hex})")
        return model


def _format_version(arrays: dict[str, np.ndarray], path: Path) -> int:
    raw = arrays.get("format_version", np.array(-1))
    try:
        return int(raw)
    except (TypeError, ValueError):
        raise ModelFormatError(f"{path}: format_version {raw!r} is not an integer") from None


def init_network(layout: int, in_min: np.ndarray, in_max: np.ndarray, out_min: float, out_max: float,
                 rng: np.random.Generator, zero_output: bool = False) -> BiasNetwork:
    """Weights drawn like PyTorch's default initialisation; ``zero_output`` makes the network predict a
    bias of exactly 0 m everywhere (a network that has learned nothing yet; needs out_min < 0 < out_max)."""
    n_in = layout_inputs(layout)
    if n_in == 0:
        raise ModelFormatError(f"unknown input layout {layout}")

    def uniform(fan_in: int, shape: tuple[int, ...]) -> np.ndarray:
        bound = 1.0 / np.sqrt(fan_in)
        return rng.uniform(-bound, bound, size=shape).astype(np.float32)

    w3 = np.zeros(HIDDEN, np.float32) if zero_output else uniform(HIDDEN, (HIDDEN,))
    b3 = -out_min / (out_max - out_min) if zero_output else float(uniform(HIDDEN, (1,))[0])
    return BiasNetwork(layout=layout, w1=uniform(n_in, (n_in, HIDDEN)), b1=uniform(n_in, (HIDDEN,)),
                       w2=uniform(HIDDEN, (HIDDEN, HIDDEN)), b2=uniform(HIDDEN, (HIDDEN,)), w3=w3, b3=b3,
                       in_min=np.asarray(in_min, np.float32), in_max=np.asarray(in_max, np.float32),
                       out_min=out_min, out_max=out_max)
