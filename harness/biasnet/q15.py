"""The q15 form of a bias network: the integers the firmware computes (core/bias_nn_q15.c, stm32/nn_m4_q15.S).

A float32 network (network.py) becomes, after training, int16 weights with one power-of-two exponent per
layer, int16 activations and int32 sums that the Cortex-M4's SMLAD (two 16 x 16 multiply-adds per
instruction) computes exactly:

* inputs: the min-max scaled features x' (float32, as bias_nn.c) -> ``round(x' 2^14)`` saturated to int16
  (x' in [-2, 2): the estimator only evaluates the network within 10 % of its training box);
* each hidden layer: ``clamp((b + sum x w) >> shift, 0, 32767)`` (ReLU and requantisation; the rounding
  half is folded into the int32 bias);
* the output head(s): the int32 sum, converted to float32 and scaled by a power of two (exact), then
  de-scaled and clamped as the float network (the std head: exp).

Scales are chosen so nothing can overflow for ANY input: a layer's exponent is the largest for which every
weight fits int16 and ``|b| + sum |w| * 32768 < 2^31`` for every unit (the sum's worst case); an activation's
exponent comes from interval bounds of the layer's output over the input box x' in [-0.1, 1.1] (the
estimator's range of evaluation), so inside it no activation saturates. Integer arithmetic is exact, so
this numpy forward equals the C kernels' to the bit (up to the float32 de-scaling and expf, 1 ulp).
quantize.py measures what it costs; network.py's ``BiasNetwork(quant="q15")`` predicts through it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

Q_IN = 14                  # scaled input x' -> round(x' 2^14)
Q_MAX = 32767
ACC_LIMIT = 2 ** 31 - 1
BOX_LO, BOX_HI = -0.1, 1.1  # x' range the estimator evaluates (bias_nn.h: BIAS_NN_OOD_MARGIN)


@dataclass(frozen=True)
class QLayer:
    """One dense layer in integers: ``acc = b + x @ w`` (int32), scale of acc = 2^(x_exp + w_exp)."""

    w: np.ndarray        # (n_in, n_out) int16 values (held as int64)
    b: np.ndarray        # (n_out,) int32 values (held as int64), rounding half of `shift` included
    w_exp: int           # weights = round(w_float 2^w_exp)
    shift: int           # hidden layers: acc >> shift -> next activation (0 for an output head)


def _weight_exponent(w: np.ndarray, b: np.ndarray, b_scale_exp: int, x_max: int) -> int:
    """Largest exponent s with every round(w 2^s) in int16 and no possible int32 overflow of the sum."""
    s = int(np.floor(np.log2(Q_MAX / max(float(np.max(np.abs(w))), 1e-30))))
    while True:
        wq = np.round(w.astype(np.float64) * 2.0 ** s)
        bq = np.round(b.astype(np.float64) * 2.0 ** (b_scale_exp + s))
        worst = np.max(np.abs(bq) + np.sum(np.abs(wq), axis=0) * x_max + 2.0 ** 16)  # + the rounding half
        if np.max(np.abs(wq)) <= Q_MAX and worst < ACC_LIMIT:
            return s
        s -= 1


def _act_exponent(upper: np.ndarray) -> int:
    """Exponent a of a layer's int16 activations: the largest with max(upper) 2^a <= 32767."""
    return int(np.floor(np.log2(Q_MAX / max(float(np.max(upper)), 1e-12))))


def _layer(w: np.ndarray, b: np.ndarray, x_exp: int, out_exp: int | None, x_max: int) -> QLayer:
    s = _weight_exponent(w, b, x_exp, x_max)
    wq = np.round(w.astype(np.float64) * 2.0 ** s).astype(np.int64)
    bq = np.round(b.astype(np.float64) * 2.0 ** (x_exp + s)).astype(np.int64)
    shift = 0 if out_exp is None else x_exp + s - out_exp
    if out_exp is not None:
        if shift < 1:
            raise ValueError(f"activation exponent {out_exp} needs a left shift: not representable")
        bq = bq + (1 << (shift - 1))       # round to nearest instead of floor
    return QLayer(w=wq, b=bq, w_exp=s, shift=shift)


@dataclass(frozen=True)
class Q15Network:
    """The q15 form of one :class:`BiasNetwork` (see the module docstring)."""

    net: Any                 # the float32 BiasNetwork (network.py) the integers come from
    l1: QLayer
    l2: QLayer
    head: QLayer             # (50, 1) bias head, or (50, 2): bias and std head
    a1: int                  # hidden-1 activations = round(h1 2^a1)
    a2: int

    @classmethod
    def from_network(cls, net: Any) -> "Q15Network":
        w1, b1 = net.w1.astype(np.float64), net.b1.astype(np.float64)
        ub1 = b1 + np.sum(np.maximum(w1 * BOX_LO, w1 * BOX_HI), axis=0)
        a1 = _act_exponent(ub1)
        h1_max = np.clip(ub1, 0.0, Q_MAX / 2.0 ** a1)
        w2, b2 = net.w2.astype(np.float64), net.b2.astype(np.float64)
        a2 = _act_exponent(b2 + np.maximum(w2, 0.0).T @ h1_max)
        hw = net.w3[:, None] if net.w3s is None else np.stack([net.w3, net.w3s], axis=1)
        hb = np.array([net.b3] if net.w3s is None else [net.b3, net.b3s])
        return cls(net=replace(net, quant="float32"), l1=_layer(w1, b1, Q_IN, a1, 2 ** 15), l2=_layer(w2, b2, a1, a2, Q_MAX),
                   head=_layer(hw, hb, a2, None, Q_MAX), a1=a1, a2=a2)

    # ------------------------------------------------------------------------------------ inference
    def input_q(self, features: np.ndarray) -> np.ndarray:
        """int16 inputs (N, n_in): x' in float32 as bias_nn.c, x' 2^14 saturated, rounded half away from 0."""
        net = self.net
        f = np.asarray(features, dtype=np.float32).reshape(-1, net.n_in)
        xs = ((f - net.in_min) / (net.in_max - net.in_min)).astype(np.float32)
        v = np.clip(xs * np.float32(2.0 ** Q_IN), np.float32(-32768.0), np.float32(Q_MAX)).astype(np.float32)
        v = np.where(np.isnan(v), np.float32(0.0), v)
        return np.trunc(v + np.where(v >= 0, np.float32(0.5), np.float32(-0.5)).astype(np.float32)).astype(np.int64)

    def hidden_q(self, features: np.ndarray) -> np.ndarray:
        """int16 second hidden layer (N, 50)."""
        x = self.input_q(features)
        h1 = np.clip((self.l1.b + x @ self.l1.w) >> self.l1.shift, 0, Q_MAX)
        return np.clip((self.l2.b + h1 @ self.l2.w) >> self.l2.shift, 0, Q_MAX)

    def heads(self, features: np.ndarray) -> np.ndarray:
        """The head sums as float32 values of the float network's units (N, 1 or 2)."""
        acc = self.head.b + self.hidden_q(features) @ self.head.w
        return acc.astype(np.float32) * np.float32(2.0 ** -(self.a2 + self.head.w_exp))

    def predict_with_std_batch(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        net, h = self.net, self.heads(features)
        y = h[:, 0] * np.float32(net.out_max - net.out_min) + np.float32(net.out_min)
        bias = np.clip(y.astype(np.float32), np.float32(net.out_min), np.float32(net.out_max)).astype(np.float64)
        if net.w3s is None:
            return bias, np.zeros(len(bias))
        with np.errstate(over="ignore"):
            std = np.exp(h[:, 1].astype(np.float32)).astype(np.float64)
        std = np.where(np.isnan(std) | (std > net.std_max), net.std_max, std)
        return bias, np.maximum(std, net.std_min)

    def predict_batch(self, features: np.ndarray) -> np.ndarray:
        return self.predict_with_std_batch(features)[0]

    def predict(self, features: np.ndarray) -> float:
        return float(self.predict_batch(features)[0])

    def predict_with_std(self, features: np.ndarray) -> tuple[float, float]:
        b, s = self.predict_with_std_batch(features)
        return float(b[0]), float(s[0])

    @property
    def flash_bytes(self) -> int:
        """Weights (int16) and biases (int32) as the firmware would store them."""
        n16 = self.l1.w.size + self.l2.w.size + self.head.w.size
        return 2 * n16 + 4 * (self.l1.b.size + self.l2.b.size + self.head.b.size)


def hidden_pair_order(q: Q15Network, n: int = 4000, seed: int = 0) -> np.ndarray:
    """An order of the first hidden layer's units for the firmware's tables: units (order[2k], order[2k+1])
    share input pair k of the second layer, which the M4 kernel skips when both are 0 after ReLU (nn_m4_q15.S).
    Greedy matching on n uniform inputs of the training box: the pairs least often active (either unit
    nonzero) first, so units active together share a pair and dead units pair with each other. Permuting a
    hidden layer (w1's columns, b1, w2's rows) changes no output; deterministic (integer counts)."""
    net = q.net
    f = net.in_min + (net.in_max - net.in_min) * np.random.default_rng(seed).uniform(0.0, 1.0, (n, net.n_in))
    act = (np.clip((q.l1.b + q.input_q(f) @ q.l1.w) >> q.l1.shift, 0, Q_MAX) != 0).astype(np.int64)
    count, both = act.sum(axis=0), act.T @ act
    either = count[:, None] + count[None, :] - both
    units = either.shape[0]
    candidates = sorted((int(either[a, b]), a, b) for a in range(units) for b in range(a + 1, units))
    free, order = set(range(units)), []
    for _, a, b in candidates:
        if a in free and b in free:
            order += [a, b]
            free -= {a, b}
    return np.array(order + sorted(free), dtype=np.int64)

