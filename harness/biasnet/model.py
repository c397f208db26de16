"""The bias network as plain arrays: the one container shared by training, the twin, export and the report.

A model holds up to two networks (TWR and TDoA), each 2 hidden layers x 50 ReLU -> 1 linear output with
min-max input scaling and a clamped, de-scaled output (the maths of firmware_sim/core/bias_nn.c).
Files are ``.npz`` written and read with ``allow_pickle=False``: loading never runs code.

The model hash (reported by the firmware in HELLO) is the first 8 bytes, little-endian, of SHA-256 over
:meth:`BiasModel.canonical_bytes`: a fixed byte layout of every float32 table, so the same weights give
the same hash in Python and in the generated C header.
"""

from __future__ import annotations

import hashlib
import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from harness.twin.features import (LAYOUT_TDOA_POS, LAYOUT_TDOA_POSE, LAYOUT_TWR_POS, LAYOUT_TWR_POSE,
                                   layout_inputs)

HIDDEN = 50
FORMAT_VERSION = 1
_MAGIC = b"UWBNN\x01"
_KINDS = ("twr", "tdoa")
_TWR_LAYOUTS = (LAYOUT_TWR_POSE, LAYOUT_TWR_POS)
_TDOA_LAYOUTS = (LAYOUT_TDOA_POSE, LAYOUT_TDOA_POS)


class ModelFormatError(ValueError):
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

    @property
    def n_in(self) -> int:
        return int(self.w1.shape[0])

    # ------------------------------------------------------------------------------------ inference
    def predict_batch(self, features: np.ndarray) -> np.ndarray:
        """Bias [m] for each row of ``features`` (N, n_in), float64 arithmetic on the float32 tables."""
        x = np.asarray(features, dtype=np.float64).reshape(-1, self.n_in)
        lo, hi = self.in_min.astype(np.float64), self.in_max.astype(np.float64)
        xs = (x - lo) / (hi - lo)
        h1 = np.maximum(xs @ self.w1.astype(np.float64) + self.b1, 0.0)
        h2 = np.maximum(h1 @ self.w2.astype(np.float64) + self.b2, 0.0)
        y = h2 @ self.w3.astype(np.float64) + self.b3
        y = y * (self.out_max - self.out_min) + self.out_min
        return np.clip(y, self.out_min, self.out_max)

    def predict(self, features: np.ndarray) -> float:
        """Bias [m] for one feature vector (the twin's ``BiasNet`` protocol)."""
        return float(self.predict_batch(np.asarray(features).reshape(1, -1))[0])

    # --------------------------------------------------------------------------------- serialisation
    def canonical_bytes(self) -> bytes:
        parts = [struct.pack("<BB", self.layout, self.n_in)]
        for name in ("w1", "b1", "w2", "b2", "w3"):
            parts.append(getattr(self, name).astype("<f4").tobytes())
        parts.append(struct.pack("<f", self.b3))
        parts.append(self.in_min.astype("<f4").tobytes())
        parts.append(self.in_max.astype("<f4").tobytes())
        parts.append(struct.pack("<ff", self.out_min, self.out_max))
        return b"".join(parts)

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {f"{prefix}_layout": np.array(self.layout, dtype=np.int64)}
        for name in ("w1", "b1", "w2", "b2", "w3", "in_min", "in_max"):
            out[f"{prefix}_{name}"] = getattr(self, name)
        for name in ("b3", "out_min", "out_max"):
            out[f"{prefix}_{name}"] = np.array(getattr(self, name), dtype=np.float32)
        return out

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str, source: str = "<arrays>") -> "BiasNetwork":
        names = ("layout", "w1", "b1", "w2", "b2", "w3", "b3", "in_min", "in_max", "out_min", "out_max")
        missing = [f"{prefix}_{n}" for n in names if f"{prefix}_{n}" not in arrays]
        if missing:
            raise ModelFormatError(f"{source}: missing arrays {missing}")
        try:
            return cls(layout=int(arrays[f"{prefix}_layout"]),
                       **{n: arrays[f"{prefix}_{n}"] for n in ("w1", "b1", "w2", "b2", "w3", "in_min", "in_max")},
                       b3=float(arrays[f"{prefix}_b3"]), out_min=float(arrays[f"{prefix}_out_min"]),
                       out_max=float(arrays[f"{prefix}_out_max"]))
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
        return self.twr if kind == "twr" else self.tdoa

    def replace(self, kind: str, net: BiasNetwork | None) -> "BiasModel":
        return BiasModel(twr=net if kind == "twr" else self.twr, tdoa=net if kind == "tdoa" else self.tdoa,
                         name=self.name, meta=dict(self.meta))

    # ------------------------------------------------------------------------------------------ files
    def save(self, path: Path) -> Path:
        path = Path(path)
        arrays: dict[str, np.ndarray] = {"format_version": np.array(FORMAT_VERSION, dtype=np.int64),
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
            raise FileNotFoundError(f"bias model {path} does not exist")
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {k: data[k] for k in data.files}
        except (OSError, ValueError, EOFError) as exc:
            raise ModelFormatError(f"{path}: not a bias-model .npz ({exc})") from None
        version = int(arrays.get("format_version", -1))
        if version != FORMAT_VERSION:
            raise ModelFormatError(f"{path}: format_version {version}, expected {FORMAT_VERSION}")
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
