"""The std head: file format and hash, fitting by Gaussian NLL, calibration on unseen samples."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from harness.biasnet.dataset import Samples
from harness.biasnet.network import BiasModel, ModelFormatError, init_network
from harness.biasnet.uncertainty import StdHeadConfig, calibration, fit_std_head
from harness.twin.features import LAYOUT_TWR_POS

LO = np.array([-5.0, -5.0, -3.0])


def base_net(seed: int = 0):  # noqa: ANN201
    return init_network(LAYOUT_TWR_POS, LO, -LO, -0.3, 0.3, np.random.default_rng(seed))


def hetero_samples(net, n: int, seed: int) -> Samples:  # noqa: ANN001
    """Residual std 0.03 m where x < 0 and 0.12 m where x > 0 around the network's own prediction."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(LO, -LO, size=(n, 3))
    std = np.where(x[:, 0] < 0.0, 0.03, 0.12)
    bias = net.predict_batch(x) + std * rng.standard_normal(n)
    return Samples(LAYOUT_TWR_POS, x, bias, np.zeros(n, dtype=np.int64), np.tile([0, -1], (n, 1)), ("syn",))


def test_head_round_trips_and_only_a_head_changes_the_hash(tmp_path: Path) -> None:
    net = base_net()
    plain = BiasModel(twr=net, name="m")
    headed = BiasModel(twr=replace(net, w3s=np.full(50, 0.01, np.float32), b3s=-2.0, std_min=0.02, std_max=0.5),
                       name="m")
    assert plain.hash != headed.hash
    loaded = BiasModel.load(headed.save(tmp_path / "h.npz"))
    assert loaded.hash == headed.hash and loaded.twr is not None and loaded.twr.has_std
    assert loaded.twr.std_min == pytest.approx(0.02) and loaded.twr.b3s == pytest.approx(-2.0)
    # a model without a head is written as version 1 with the hash it always had
    with np.load(plain.save(tmp_path / "p.npz")) as data:
        assert int(data["format_version"]) == 1
    assert BiasModel.load(tmp_path / "p.npz").hash == plain.hash


def test_malformed_heads_are_refused(tmp_path: Path) -> None:
    net = base_net()
    with pytest.raises(ModelFormatError, match="std bounds"):
        replace(net, w3s=np.zeros(50, np.float32), std_min=0.5, std_max=0.1)
    with pytest.raises(ModelFormatError, match="w3s must have shape"):
        replace(net, w3s=np.zeros(49, np.float32), std_min=0.01, std_max=0.1)
    headed = BiasModel(twr=replace(net, w3s=np.zeros(50, np.float32), std_min=0.01, std_max=0.1))
    path = headed.save(tmp_path / "h.npz")
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files if k != "twr_std_max"}
    np.savez(tmp_path / "broken.npz", **arrays)
    with pytest.raises(ModelFormatError, match="incomplete std head"):
        BiasModel.load(tmp_path / "broken.npz")


def test_fitted_head_tracks_the_residual_std_on_unseen_samples() -> None:
    net = base_net(3)
    fitted = fit_std_head(net, hetero_samples(net, 20_000, seed=1), StdHeadConfig(std_min=0.01, std_max=0.5))
    test = hetero_samples(net, 20_000, seed=2)
    _, std = fitted.predict_with_std_batch(test.x)
    left = test.x[:, 0] < -1.0
    right = test.x[:, 0] > 1.0
    # a linear head on a random hidden layer cannot draw a sharp step, but well away from it:
    assert np.median(std[left]) == pytest.approx(0.03, rel=0.35)
    assert np.median(std[right]) == pytest.approx(0.12, rel=0.25)
    cal = calibration(fitted, test)
    assert cal["mean_z2"] == pytest.approx(1.0, abs=0.15)
    assert cal["inside_95"] == pytest.approx(0.95, abs=0.02)
    # same data, same head (deterministic fit)
    again = fit_std_head(net, hetero_samples(net, 20_000, seed=1), StdHeadConfig(std_min=0.01, std_max=0.5))
    assert BiasModel(twr=again).hash == BiasModel(twr=fitted).hash
    # the bias part is untouched
    assert np.array_equal(fitted.predict_batch(test.x), net.predict_batch(test.x))


def test_constant_head_is_the_rms_of_the_residual_and_inflate_scales_it() -> None:
    net = base_net(3)
    s = hetero_samples(net, 20_000, seed=1)
    rms = float(np.sqrt(np.mean((s.bias - net.predict_batch(s.x)) ** 2)))  # about sqrt((0.03^2 + 0.12^2) / 2)
    const = fit_std_head(net, s, StdHeadConfig(std_min=0.01, std_max=0.5, constant=True))
    _, std = const.predict_with_std_batch(s.x)
    assert np.all(const.w3s == 0.0)
    assert np.allclose(std, rms, rtol=1e-5)
    assert calibration(const, s)["mean_z2"] == pytest.approx(1.0, abs=1e-3)
    wide = fit_std_head(net, s, StdHeadConfig(std_min=0.01, std_max=0.5, constant=True, inflate=1.5))
    assert np.allclose(wide.predict_with_std_batch(s.x)[1], 1.5 * rms, rtol=1e-5)
    with pytest.raises(ValueError, match="inflate"):
        fit_std_head(net, s, StdHeadConfig(inflate=0.0))


def test_head_bounds_apply() -> None:
    net = base_net(4)
    s = hetero_samples(net, 2000, seed=5)
    tight = fit_std_head(net, s, StdHeadConfig(std_min=0.05, std_max=0.08))
    _, std = tight.predict_with_std_batch(s.x)
    assert std.min() >= 0.05 - 1e-9 and std.max() <= 0.08 + 1e-9
    with pytest.raises(ValueError, match="std_min"):
        fit_std_head(net, s, StdHeadConfig(std_min=0.1, std_max=0.05))


def test_fit_std_cli_adds_a_head_and_keeps_the_bias(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from harness.biasnet.export import DEFAULT_NPZ
    from harness.cli import main
    out = tmp_path / "with_std.npz"
    rc = main(["fit-std", "--mode", "twr", "--flights", "2", "--duration", "20", "--out", str(out)])
    assert rc == 0 and "mean (r/std)^2" in capsys.readouterr().out
    base, fitted = BiasModel.load(DEFAULT_NPZ), BiasModel.load(out)
    assert fitted.twr is not None and fitted.twr.has_std and base.twr is not None
    assert np.array_equal(fitted.twr.w3, base.twr.w3) and np.array_equal(fitted.twr.w1, base.twr.w1)
    assert BiasModel(tdoa=fitted.tdoa).hash == BiasModel(tdoa=base.tdoa).hash and fitted.hash != base.hash
    info = fitted.meta["twr_std_head"]
    assert info["fitted_on"] and 0.8 < info["calibration"]["mean_z2"] < 1.2  # type: ignore[index]
    # the same flights give the same head
    again = tmp_path / "again.npz"
    assert main(["fit-std", "--mode", "twr", "--flights", "2", "--duration", "20", "--out", str(again)]) == 0
    assert BiasModel.load(again).hash == fitted.hash
