"""harness/biasnet/quantize.py: the q15 form of a bias network (issue 24) - integer ranges, no overflow for
any input, agreement with the float network, NaN and out-of-range inputs."""

from __future__ import annotations

import numpy as np
import pytest

from harness.biasnet.export import DEFAULT_NPZ
from harness.biasnet.network import BiasModel, init_network
from harness.biasnet.q15 import ACC_LIMIT, Q_MAX, Q15Network
from harness.biasnet.quantize import agreement, box_inputs
from harness.twin.features import LAYOUT_TDOA_POSE


@pytest.fixture(scope="module")
def shipped() -> BiasModel:
    return BiasModel.load(DEFAULT_NPZ)


@pytest.mark.parametrize("kind", ["twr", "tdoa"])
def test_tables_fit_int16_and_no_sum_can_overflow(shipped: BiasModel, kind: str) -> None:
    net = shipped.network(kind)
    assert net is not None
    q = Q15Network.from_network(net)
    for layer, x_max in ((q.l1, 2 ** 15), (q.l2, Q_MAX), (q.head, Q_MAX)):
        assert np.max(np.abs(layer.w)) <= Q_MAX
        worst = np.abs(layer.b) + np.sum(np.abs(layer.w), axis=0) * x_max
        assert np.max(worst) < ACC_LIMIT          # int32 sums are exact for every input
    assert q.l1.shift >= 1 and q.l2.shift >= 1
    assert q.flash_bytes < 0.55 * 4 * (net.w1.size + net.w2.size + 2 * 50)   # about half the float32 tables


@pytest.mark.parametrize("kind", ["twr", "tdoa"])
def test_q15_agrees_with_the_float_network_within_a_millimetre(shipped: BiasModel, kind: str) -> None:
    net = shipped.network(kind)
    assert net is not None
    q = Q15Network.from_network(net)
    a = agreement(q, box_inputs(net, 4000, seed=1))
    # measured on the shipped model (python -m harness.biasnet.quantize): max 0.10 / 0.36 mm, RMS 0.02 / 0.10 mm
    assert a["bias_max_m"] < 1e-3 and a["bias_rms_m"] < 3e-4
    assert a["bias_max_m"] > 0.0                  # it is a different computation, not the float one again
    if net.w3s is not None:
        assert a["std_max_m"] < 1e-5


def test_random_network_with_a_std_head_and_hostile_inputs() -> None:
    rng = np.random.default_rng(7)
    net = init_network(LAYOUT_TDOA_POSE, np.full(9, -3.0), np.full(9, 3.0), -0.5, 0.5, rng)
    from dataclasses import replace
    net = replace(net, w3s=rng.normal(0, 0.1, 50).astype(np.float32), b3s=-2.5, std_min=0.02, std_max=0.5)
    q = Q15Network.from_network(net)
    a = agreement(q, box_inputs(net, 2000, seed=2))
    assert a["bias_rms_m"] < 1e-3 * (net.out_max - net.out_min)
    x = np.array([[np.nan] * 9, [1e30] * 9, [-1e30] * 9])
    xq = q.input_q(x)
    assert list(xq[0]) == [0] * 9 and list(xq[1]) == [Q_MAX] * 9 and list(xq[2]) == [-32768] * 9
    b, s = q.predict_with_std_batch(x)
    assert np.all(np.isfinite(b)) and np.all((b >= net.out_min) & (b <= net.out_max))
    assert np.all((s >= net.std_min) & (s <= net.std_max))


def test_c_q15_kernel_equals_the_numpy_integers(tmp_path) -> None:  # noqa: ANN001
    """bias_nn_q15.c (built by `make nn_eval` against the exported q15 header) and Q15Network, on the same
    float32 inputs: the same integer sums, so the same bias to float32 rounding, including inputs beyond
    the training range (saturation) and both heads."""
    import subprocess
    from harness.biasnet.export import export_c
    from nn_eval_build import build_nn_eval
    model = BiasModel.load(DEFAULT_NPZ).quantized("q15")
    exe = build_nn_eval(export_c(model, tmp_path / "q15.h"), tmp_path / "nn_eval_q15")
    rng = np.random.default_rng(5)
    for kind in ("twr", "tdoa"):
        net = model.network(kind)
        assert net is not None and net.quant == "q15"
        span = net.in_max - net.in_min
        x = rng.uniform(net.in_min - 0.5 * span, net.in_max + 0.5 * span, size=(3000, net.n_in)).astype(np.float32)
        text = "".join(f"{kind} " + " ".join(repr(float(v)) for v in row) + "\n" for row in x)
        out = subprocess.run([str(exe)], input=text, capture_output=True, text=True, check=True, timeout=120).stdout
        vals = np.array([[float(v) for v in ln.split()] for ln in out.splitlines()[1:]]).reshape(-1, 2)
        bias, std = net.predict_with_std_batch(x)
        assert np.max(np.abs(vals[:, 0] - bias)) < 1e-7
        assert np.max(np.abs(vals[:, 1] - std) / std) < 1e-6


def test_q15_model_has_its_own_hash_and_round_trips(tmp_path) -> None:  # noqa: ANN001
    q = BiasModel.load(DEFAULT_NPZ)          # the shipped model is q15 (the default since issue 24)
    assert q.twr is not None and q.twr.quant == "q15"
    model = q.quantized("float32", name=q.name)
    assert q.hash != model.hash and q.twr is not None and q.twr.quant == "q15"
    back = BiasModel.load(q.save(tmp_path / "q.npz"))
    assert back.hash == q.hash and back.tdoa is not None and back.tdoa.quant == "q15"
    x = box_inputs(model.tdoa, 50, seed=4)  # type: ignore[arg-type]
    assert np.array_equal(back.tdoa.predict_batch(x), q.tdoa.predict_batch(x))  # type: ignore[union-attr]


@pytest.mark.parametrize("kind", ["twr", "tdoa"])
def test_hidden_pair_order_is_a_permutation_that_leaves_fewer_active_pairs(shipped: BiasModel, kind: str) -> None:
    """export-c's order of the first hidden layer (the M4 kernel skips input pairs of two zeros): the same
    second layer for any input, and fewer pairs with a nonzero unit than the trained order."""
    from harness.biasnet.q15 import hidden_pair_order
    net = shipped.network(kind)
    assert net is not None
    q = Q15Network.from_network(net)
    order = hidden_pair_order(q)
    assert sorted(order.tolist()) == list(range(50))
    assert np.array_equal(order, hidden_pair_order(q))                       # deterministic
    x = q.input_q(box_inputs(net, 3000, seed=9))                             # other inputs than the order's
    h1 = np.clip((q.l1.b + x @ q.l1.w) >> q.l1.shift, 0, Q_MAX)
    h1p = np.clip((q.l1.b[order] + x @ q.l1.w[:, order]) >> q.l1.shift, 0, Q_MAX)
    assert np.array_equal(h1p @ q.l2.w[order, :], h1 @ q.l2.w)                # exact: a permutation

    def active_pairs(h: np.ndarray) -> float:
        return float(np.mean(np.sum((h[:, 0::2] != 0) | (h[:, 1::2] != 0), axis=1)))
    assert active_pairs(h1p) < 0.9 * active_pairs(h1)
