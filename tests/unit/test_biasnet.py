"""The bias network: container and hash, export to C, C = PyTorch = numpy, training, baselines, refusals."""

from __future__ import annotations

import json
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from harness.biasnet.baselines import PairConstant, VoxelTable
from harness.firmware_build import firmware_for
from harness.biasnet.dataset import Samples, build_samples, flight_samples, split_by_flight
from harness.biasnet.evaluate import evaluate
from harness.biasnet.export import DEFAULT_NPZ, export_c, header_text
from harness.biasnet.network import BiasModel, BiasNetwork, ModelFormatError, init_network
from harness.biasnet.recipes import FIRST_EVAL_SEED, STD_HEAD_RECIPE, SimRecipe
from harness.biasnet.train import TrainConfig, to_torch, train_network
from harness.errors import ModelMismatch
from harness.flight.data import KIND_TDOA, Anchors, Flight, Truth, UwbStream
from harness.paths import shared_data_dir
from harness.twin.features import LAYOUT_TDOA_POSE, LAYOUT_TWR_POS, LAYOUT_TWR_POSE
from nn_eval_build import build_nn_eval

LO6 = np.array([-8.0, -8.0, -3.5, -0.6, -0.6, -np.pi])
LO9 = np.concatenate([LO6[:3], LO6])


def random_model(seed: int = 1) -> BiasModel:
    """Non-trivial weights with a wide output range, so clamping rarely hides differences."""
    rng = np.random.default_rng(seed)
    twr = init_network(LAYOUT_TWR_POSE, LO6, -LO6, -1.0, 1.0, rng)
    tdoa = init_network(LAYOUT_TDOA_POSE, LO9, -LO9, -1.0, 1.0, rng)
    # Centre the scaled output in (0, 1) so most inputs land between out_min and out_max.
    return BiasModel(twr=replace(twr, b3=twr.b3 + 0.5), tdoa=replace(tdoa, b3=tdoa.b3 + 0.5), name=f"random-{seed}")


# ------------------------------------------------------------------------------ container, hash, files
def test_save_load_round_trip_keeps_weights_hash_and_meta(tmp_path: Path) -> None:
    m = replace(random_model(), meta={"twr_trained_on": ["a.csv"]})
    path = m.save(tmp_path / "m.npz")
    back = BiasModel.load(path)
    assert back.hash == m.hash and back.meta == m.meta and back.name == m.name
    for kind in ("twr", "tdoa"):
        a, b = m.network(kind), back.network(kind)
        assert a is not None and b is not None
        for name in ("w1", "b1", "w2", "b2", "w3", "in_min", "in_max"):
            assert np.array_equal(getattr(a, name), getattr(b, name))


def test_hash_changes_with_any_weight_and_not_with_meta() -> None:
    m = random_model()
    assert replace(m, meta={"x": 1}).hash == m.hash
    assert m.twr is not None
    w2 = m.twr.w2.copy()
    w2[17, 3] = np.nextafter(w2[17, 3], np.float32(1.0))
    assert replace(m, twr=replace(m.twr, w2=w2)).hash != m.hash
    assert BiasModel(twr=m.twr).hash != BiasModel(tdoa=m.tdoa).hash != m.hash


def test_load_refuses_malformed_files_with_clear_messages(tmp_path: Path) -> None:
    good = random_model().save(tmp_path / "good.npz")
    with np.load(good) as data:
        arrays = {k: data[k] for k in data.files}

    def write(name: str, **changes: object) -> Path:
        a = {k: v for k, v in arrays.items() if changes.get(k, 0) is not None}
        a.update({k: v for k, v in changes.items() if v is not None})
        p = tmp_path / name
        np.savez(p, **a)  # type: ignore[arg-type]
        return p

    with pytest.raises(ModelFormatError, match=r"missing arrays \['twr_w2'\]"):
        BiasModel.load(write("missing.npz", twr_w2=None))
    with pytest.raises(ModelFormatError, match="w1 must have shape"):
        BiasModel.load(write("shape.npz", twr_w1=np.zeros((5, 50), np.float32)))
    bad = arrays["tdoa_b2"].copy()
    bad[0] = np.nan
    with pytest.raises(ModelFormatError, match="b2 holds NaN"):
        BiasModel.load(write("nan.npz", tdoa_b2=bad))
    tampered = arrays["twr_b1"].copy()
    tampered[0] += 1.0
    with pytest.raises(ModelFormatError, match="does not match its weights"):
        BiasModel.load(write("tampered.npz", twr_b1=tampered))
    pickled = tmp_path / "pickle.npz"
    np.savez(pickled, format_version=np.array(1), twr_layout=np.array([{"evil": 1}], dtype=object))
    with pytest.raises(ModelFormatError, match="not a bias-model"):
        BiasModel.load(pickled)
    (tmp_path / "garbage.npz").write_bytes(b"not a zip file")
    with pytest.raises(ModelFormatError, match="garbage.npz"):
        BiasModel.load(tmp_path / "garbage.npz")
    with pytest.raises(FileNotFoundError, match="nope.npz"):
        BiasModel.load(tmp_path / "nope.npz")


def test_network_refuses_inconsistent_tables() -> None:
    rng = np.random.default_rng(0)
    net = init_network(LAYOUT_TWR_POSE, LO6, -LO6, -0.7, 0.7, rng)
    with pytest.raises(ModelFormatError, match="in_max must exceed in_min"):
        replace(net, in_max=net.in_min.copy())
    with pytest.raises(ModelFormatError, match="TDoA layout"):
        BiasModel(twr=init_network(LAYOUT_TDOA_POSE, LO9, -LO9, -0.7, 0.7, rng))


# ------------------------------------------------------------------------------ C = PyTorch = numpy
@pytest.fixture(scope="module")
def nn_eval_for(tmp_path_factory: pytest.TempPathFactory):  # noqa: ANN201
    root = tmp_path_factory.mktemp("nn_eval")

    def build(model: BiasModel) -> Path:
        header = export_c(model, root / f"{model.hash_hex}.h")
        return build_nn_eval(header, root / f"nn_eval_{model.hash_hex}")
    return build


def c_predict(exe: Path, kind: str, x: np.ndarray) -> tuple[str, np.ndarray, np.ndarray]:
    """(header line, bias, std) as the C code computes them."""
    text = "".join(f"{kind} " + " ".join(repr(float(v)) for v in row) + "\n" for row in x.astype(np.float32))
    out = subprocess.run([str(exe)], input=text, capture_output=True, text=True, check=True, timeout=120).stdout
    lines = out.splitlines()
    assert not [ln for ln in lines[1:] if ln.startswith("E")]
    vals = np.array([[float(v) for v in ln.split()] for ln in lines[1:]]).reshape(-1, 2)
    return lines[0], vals[:, 0], vals[:, 1]


def with_std_heads(model: BiasModel, seed: int) -> BiasModel:
    """A std head whose output spans [std_min, std_max] and beyond (clamping is exercised too)."""
    rng = np.random.default_rng(seed)
    nets = {}
    for kind in ("twr", "tdoa"):
        net = model.network(kind)
        assert net is not None
        w3s = rng.normal(0.0, 6.0, 50).astype(np.float32)  # log std spread ~ +-1.8 over the input box
        x = rng.uniform(net.in_min, net.in_max, size=(500, net.n_in))
        b3s = float(np.log(0.1) - np.mean(net.hidden(x) @ w3s))    # centred on 0.1 m
        nets[kind] = replace(net, w3s=w3s, b3s=b3s, std_min=0.03, std_max=0.4)
    return BiasModel(twr=nets["twr"], tdoa=nets["tdoa"], name=model.name + "-std")


@pytest.mark.parametrize("which", ["random", "random-std", "shipped"])
def test_c_torch_numpy_agree_on_10000_inputs(nn_eval_for, which: str) -> None:  # noqa: ANN001
    import torch
    model = {"random": lambda: random_model(7), "random-std": lambda: with_std_heads(random_model(8), 9),
             "shipped": lambda: BiasModel.load(DEFAULT_NPZ)}[which]()
    exe = nn_eval_for(model)
    rng = np.random.default_rng(3)
    for kind in ("twr", "tdoa"):
        net = model.network(kind)
        assert net is not None
        # Inputs spread a little beyond the training ranges, where clamping and extrapolation happen too.
        span = net.in_max - net.in_min
        x = rng.uniform(net.in_min - 0.1 * span, net.in_max + 0.1 * span, size=(10_000, net.n_in)).astype(np.float32)
        header, c, c_std = c_predict(exe, kind, x)
        assert header.split()[1] == model.hash_hex
        _, n_std = net.predict_with_std_batch(x)
        if which == "shipped":  # the compiled-in network carries its std head (stage NN_STD)
            assert net.has_std, f"{kind}: `make models` fits the default network's std head"
        if net.has_std:  # float32 expf vs float64 exp: relative agreement
            assert np.max(np.abs(c_std - n_std) / n_std) <= 1e-5, kind
            at_min, at_max = np.isclose(c_std, net.std_min, rtol=1e-7), np.isclose(c_std, net.std_max, rtol=1e-7)
            assert np.all(((c_std >= net.std_min) & (c_std <= net.std_max)) | at_min | at_max)
            if which == "random-std":  # not vacuous: varied, and partly clamped at each bound
                assert np.mean(at_min) > 0.01 and np.mean(at_max) > 0.01
                assert np.mean(~at_min & ~at_max) > 0.3
        else:
            assert np.all(c_std == 0.0) and np.all(n_std == 0.0)
        with torch.no_grad():
            t = to_torch(net)(torch.from_numpy(x)).numpy().astype(np.float64)  # type: ignore[operator]
        n = net.predict_batch(x)
        assert c.shape == t.shape == n.shape == (10_000,)
        # C = numpy always (a q15 network: the same integers); PyTorch is the float network, which a q15 one
        # (the shipped default since issue 24) follows within its quantisation error (max 0.37 mm measured,
        # docs/bias-network.md); a float network within float32 rounding
        torch_tol = 1e-3 if net.quant == "q15" else 1e-5
        assert np.max(np.abs(c - t)) <= torch_tol, kind
        assert np.max(np.abs(c - n)) <= 1e-5, kind
        assert np.max(np.abs(t - n)) <= torch_tol, kind
        if which == "random":  # the comparison must not be vacuous: most outputs are unclamped and varied
            inside = (n > net.out_min) & (n < net.out_max)
            assert inside.mean() > 0.5 and np.std(n[inside]) > 0.01


def test_shipped_std_head_was_fitted_on_flights_neither_trained_nor_evaluated_on() -> None:
    """The default network's head is the RMS of its corrected residual on STD_HEAD_RECIPE's simulated flights
    (recipes.py): seeds below the evaluation seeds and outside the training recipe's."""
    model = BiasModel.load(DEFAULT_NPZ)
    train_seeds = set(SimRecipe().seeds())
    for kind in ("twr", "tdoa"):
        head = model.meta[f"{kind}_std_head"]
        seeds = {int(name.rsplit("-s", 1)[1]) for name in head["fitted_on"]}
        assert seeds == set(STD_HEAD_RECIPE.seeds()) and not seeds & train_seeds
        assert max(seeds) < FIRST_EVAL_SEED
        net = model.network(kind)
        assert net is not None and net.w3s is not None and head["constant"] and not np.any(net.w3s)
        # calibrated there: mean (r/std)^2 = 1 for the maximum-likelihood constant
        assert abs(head["calibration"]["mean_z2"] - 1.0) < 1e-3
        assert 0.02 < head["calibration"]["std_rms"] < 0.1


def test_header_is_deterministic_and_names_the_hash() -> None:
    m = random_model(2)
    text = header_text(m)
    assert text == header_text(BiasModel(twr=m.twr, tdoa=m.tdoa, name=m.name))
    assert f"#define BIAS_MODEL_HASH 0x{m.hash_hex}ull" in text
    assert "static const float bias_net_twr_w1[300]" in text and "static const float bias_net_tdoa_w1[450]" in text


def test_shipped_header_matches_shipped_npz() -> None:
    model = BiasModel.load(DEFAULT_NPZ)
    header = DEFAULT_NPZ.with_suffix(".h").read_text()
    assert header == header_text(model), "firmware_sim/models: run `uwb-hil export-c` after changing the .npz"


# ------------------------------------------------------------------------------ training
def synthetic_flights(n: int, seed: int, noise: float = 0.02) -> list[Flight]:
    """TDoA flights whose bias is a smooth function of the features plus white noise."""
    rng = np.random.default_rng(seed)
    anchors = Anchors(ids=np.arange(4), positions=np.array([[-3, -3, 0.2], [3, -3, 2.8], [3, 3, 0.2], [-3, 3, 2.8]], dtype=float))
    flights = []
    for f in range(n):
        m = 3000
        t = np.arange(m, dtype=np.int64) * 5000 + 1000
        pos = np.stack([2 * np.sin(t * 1e-6 * (0.3 + 0.05 * f)), 2 * np.cos(t * 1e-6 * 0.4), 1 + 0.5 * np.sin(t * 1e-6)], 1)
        a = rng.integers(0, 4, m)
        b = (a + 1 + rng.integers(0, 3, m)) % 4
        pa, pb = anchors.positions[a], anchors.positions[b]
        true = np.linalg.norm(pb - pos, axis=1) - np.linalg.norm(pa - pos, axis=1)
        dpa, dpb = pa - pos, pb - pos
        bias = 0.1 * np.sin(dpa[:, 0]) + 0.08 * np.tanh(dpb[:, 1] - dpb[:, 2]) + 0.03 * (a - b)
        q = np.tile([1.0, 0.0, 0.0, 0.0], (m, 1))
        uwb = UwbStream(kind=KIND_TDOA, t_us=t, anchor_a=a, anchor_b=b, value=true + bias + noise * rng.standard_normal(m),
                        true_value=true)
        flights.append(Flight(name=f"syn{seed}-{f}", anchors=anchors, uwb=uwb, truth=Truth(t_us=t, pos=pos, quat=q)))
    return flights


def test_samples_follow_the_firmware_features_and_xi() -> None:
    (f,) = synthetic_flights(1, 5)
    f.uwb.value[10] += 5.0  # an outlier: |bias| >= 0.7 is left to the gates
    s = flight_samples(f, LAYOUT_TDOA_POSE)
    assert len(s) == len(f.uwb) - 1 and 10 not in s.row  # type: ignore[operator]
    k = 3
    i = int(s.row[k])  # type: ignore[index]
    pa = f.anchors.position(int(f.uwb.anchor_a[i]))
    pb = f.anchors.position(int(f.uwb.anchor_b[i]))
    np.testing.assert_allclose(s.x[k], np.concatenate([pa - f.truth.pos[i], pb - f.truth.pos[i], [0, 0, 0]]))
    assert s.bias[k] == pytest.approx(f.uwb.value[i] - f.uwb.true_value[i])  # type: ignore[index]
    with pytest.raises(ValueError, match="does not fit"):
        flight_samples(f, LAYOUT_TWR_POS)


def test_split_is_by_flight_and_needs_two_flights() -> None:
    s = build_samples(synthetic_flights(6, 1))
    tr, va = split_by_flight(s, 0.34, seed=0)
    assert not set(s.flight[tr]) & set(s.flight[va]) and len(set(s.flight[va])) == 2
    with pytest.raises(ValueError, match="at least 2 flights"):
        split_by_flight(build_samples(synthetic_flights(1, 2)), 0.2, seed=0)


def test_training_learns_the_bias_and_is_reproducible() -> None:
    samples = build_samples(synthetic_flights(6, 11))
    cfg = TrainConfig(max_epochs=25, patience=5, batch_size=256, seed=4, val_fraction=0.34)
    net, report = train_network(samples, cfg)
    # Bias std ~0.09 m, noise 0.02 m: the network must remove most of the learnable part on unseen flights.
    assert report.val_rmse_before_m > 0.07
    assert report.val_rmse_after_m < 0.45 * report.val_rmse_before_m
    assert report.n_train + report.n_val == len(samples)
    net2, _ = train_network(samples, cfg)
    assert BiasModel(tdoa=net).hash == BiasModel(tdoa=net2).hash
    test = build_samples(synthetic_flights(2, 99))
    ev = evaluate("network", test, lambda s: net.predict_batch(s.x))
    assert ev.overall.reduction > 0.5


def test_sgd_option_trains_too() -> None:
    samples = build_samples(synthetic_flights(4, 12))
    _, report = train_network(samples, TrainConfig(optimizer="sgd", lr=0.05, max_epochs=8, seed=1, val_fraction=0.25))
    assert report.val_rmse_after_m < report.val_rmse_before_m
    with pytest.raises(ValueError, match="optimizer"):
        train_network(samples, TrainConfig(optimizer="rmsprop"))


# ------------------------------------------------------------------------------ baselines
def test_pair_constant_and_voxel_table() -> None:
    flights = synthetic_flights(3, 21, noise=0.0)
    train = build_samples(flights)
    pc = PairConstant().fit(train)
    keys = train.pair_keys()
    for k in np.unique(keys)[:3]:
        assert pc.table[int(k)] == pytest.approx(float(np.mean(train.bias[keys == k])))
    vt = VoxelTable(voxel_m=0.25, min_count=5).fit(train)
    e_pc = evaluate("pc", train, pc.predict).overall
    e_vt = evaluate("vt", train, vt.predict).overall
    # On its own training data a finer (position-aware) table fits better than one constant per pair.
    assert e_vt.rmse_corrected < e_pc.rmse_corrected < e_pc.rmse_raw


def test_pair_keys_separate_constellations() -> None:
    (f,) = synthetic_flights(1, 3)
    moved = Anchors(ids=f.anchors.ids, positions=f.anchors.positions + np.array([0.5, 0.0, 0.0]))
    g = Flight(name="moved", anchors=moved, uwb=f.uwb, truth=f.truth)
    s = build_samples([f, g])
    keys_f = set(s.pair_keys()[s.flight == 0].tolist())
    keys_g = set(s.pair_keys()[s.flight == 1].tolist())
    assert keys_f and keys_g and not keys_f & keys_g


# ------------------------------------------------------------------------------ device refusals
def test_emulator_with_another_model_is_refused_naming_both_hashes(tmp_path: Path) -> None:
    from harness.device.registry import DeviceSpec, open_device
    model = random_model(5)
    fw = firmware_for(model, build_root=tmp_path)
    with open_device(DeviceSpec(firmware=fw), expected_model_hash=model.hash) as dev:
        assert dev.identity.model_hash == model.hash
    shipped = BiasModel.load(DEFAULT_NPZ)
    with pytest.raises(ModelMismatch) as err:
        with open_device(DeviceSpec(firmware=fw), expected_model_hash=shipped.hash):
            pass
    assert shipped.hash_hex in str(err.value) and model.hash_hex in str(err.value)


def test_cli_run_with_model_builds_matching_firmware(tmp_path: Path) -> None:
    from harness.cli import main
    model = random_model(6)
    path = model.save(tmp_path / "m.npz")
    import contextlib
    import io
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        # the device must carry the random network; applying it (outlier+nn) would steer the filter off
        # and the run's verdict fail (exit 1), which is not what this test is about
        rc = main(["run", "--mode", "twr", "--duration", "2", "--model", str(path), "--stages", "outlier", "--json"])
    assert rc == 0
    summary = json.loads(buf.getvalue())
    assert summary["device"]["model_hash"] == model.hash_hex


#: how far the rebuilt network's held-out RMSE may be from the one models.json records. Training is
#: reproducible bit for bit on one machine only (another CPU's float kernels give other weights: the
#: one-network recipe gave 0b1a156d9dfb20ca on one machine, 589c642569e8b819 on another, both 0.0575 m on
#: sequence 5); the distilled recipe's seeds 0-3 give 0.058-0.076 m on one machine (one network's 0.058-0.160 m),
#: so 10 % still catches a broken recipe.
HELDOUT_RTOL = 0.10


@pytest.mark.skipif(not (shared_data_dir() / "rcv_twr").is_dir(), reason="../shared/data/rcv_twr is absent")
def test_recorded_network_rebuilds_reproducibly_with_the_recorded_heldout_figures(tmp_path: Path,
                                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    # The networks trained on ../shared/data are not committed; `make campaign` rebuilds them. On one machine
    # two builds give the same weights (hash); on any machine the held-out figures are those models.json
    # records, within HELDOUT_RTOL (never the bit-exact hash: that differs across CPUs).
    from harness.biasnet import shipped
    recorded = json.loads(shipped.SUMMARY.read_text())["rcv_twr"]
    builds = []
    for k in range(2):
        d = tmp_path / f"build{k}"
        d.mkdir()
        monkeypatch.setattr(shipped, "MODELS_DIR", d)
        monkeypatch.setattr(shipped, "SUMMARY", d / "models.json")
        out = shipped.build_shipped_models(shared_data_dir(), only="rcv", write_summary=False)["rcv_twr"]
        model = BiasModel.load(d / "rcv_twr.npz")
        assert out["hash"] == model.hash_hex
        assert model.meta["twr_trained_on"] == [f"rcv_twr/sequence{k}" for k in range(1, 5)]  # not this machine's paths
        assert not (d / "models.json").exists()
        builds.append(out)
    assert builds[0]["hash"] == builds[1]["hash"]                      # same machine: same weights
    assert builds[0]["heldout"] == builds[1]["heldout"]
    for seq, methods in recorded["heldout"].items():
        got = builds[0]["heldout"][seq]
        want = methods["network"]["rmse_corrected"]
        assert got["network"]["rmse_corrected"] == pytest.approx(want, rel=HELDOUT_RTOL), seq
        assert got["network"]["rmse_corrected"] < got["pair-constant"]["rmse_corrected"], seq   # beats the baseline
        assert got["network"]["rmse_raw"] == pytest.approx(methods["network"]["rmse_raw"], rel=1e-9), seq  # same data


def test_the_obstacle_arena_network_is_trained_there_and_learns_the_blocked_links() -> None:
    """bias_model_nlos.npz (make models --only nlos): trained on simulated flights in the nlos arena, and on a
    held-out circle there it removes most of the delay of the blocked links, where the LOS network does not."""
    from harness.biasnet.recipes import SimRecipe
    from harness.flight.arena import NLOS_BOXES, Arena
    from harness.flight.scenarios import scenario_flight
    assert SimRecipe(mode="tdoa", profile="nlos", flights=1, spins=0).flight(0).meta["profile"] == "nlos"
    nlos = BiasModel.load(DEFAULT_NPZ.with_name("bias_model_nlos.npz"))
    los = BiasModel.load(DEFAULT_NPZ)
    assert nlos.tdoa is not None and nlos.twr is not None and los.tdoa is not None
    assert all(":nlos:" in s for s in nlos.meta["tdoa_trained_on"]) and nlos.meta["tdoa_xi"] == pytest.approx(1.0)
    f = scenario_flight("circle", mode="tdoa", duration_s=40.0, seed=1000, profile="nlos", radius=1.5)
    s = build_samples([f], LAYOUT_TDOA_POSE, xi=10.0)
    tag = s.anchor_pos[:, :3] - s.x[:, :3]
    arena = Arena(boxes=NLOS_BOXES)
    one = arena.blocked(tag, s.anchor_pos[:, :3]) ^ arena.blocked(tag, s.anchor_pos[:, 3:6])  # one link blocked
    assert one.mean() > 0.2                                    # the circle flies in the boxes' shadows
    left = {name: np.abs(np.mean(np.sign(s.bias[one]) * (s.bias[one] - m.tdoa.predict_batch(s.x[one]))))
            for name, m in (("los", los), ("nlos", nlos))}
    # measured 0.30 m (LOS network) and 0.03 m (nlos network) of the ~0.31 m mean delay left
    assert left["los"] > 0.2 and left["nlos"] < 0.08
