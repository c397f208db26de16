"""An ensemble distilled into one network (harness/biasnet/distill.py): folds by flight group, the student
reproduces the teacher, the std head sees out-of-fold residuals, same machine -> same weights."""

from __future__ import annotations

import numpy as np
import pytest

from harness.biasnet.dataset import Samples
from harness.biasnet.distill import DistillConfig, distill, flight_groups, train_teachers
from harness.biasnet.network import BiasModel
from harness.biasnet.train import TrainConfig
from harness.twin.features import LAYOUT_TDOA_POS

CFG = TrainConfig(max_epochs=30, patience=6, batch_size=256, seed=3)


def smooth_bias(x: np.ndarray) -> np.ndarray:
    return 0.1 * np.sin(x[:, 0]) + 0.08 * np.tanh(x[:, 4] - x[:, 5]) + 0.02 * x[:, 2]


def synthetic(groups: int = 4, per_group: int = 2, n: int = 1500, seed: int = 0, noise: float = 0.03) -> Samples:
    """Flights named like UTIL files (constC-trialT-...), inputs in a box, bias = smooth function + noise."""
    rng = np.random.default_rng(seed)
    names = tuple(f"const{c + 1}-trial{g + 1}-tdoa2" for g in range(groups) for c in range(per_group))
    m = len(names) * n
    x = rng.uniform(-3.0, 3.0, (m, 6))
    return Samples(layout=LAYOUT_TDOA_POS, x=x, bias=smooth_bias(x) + noise * rng.standard_normal(m),
                   flight=np.repeat(np.arange(len(names)), n), pair=np.tile([1, 2], (m, 1)), names=names)


def test_flight_groups_are_trials_and_sequences() -> None:
    g, labels = flight_groups(("const1-trial1-tdoa2-extracted", "const2-trial1-tdoa2-extracted",
                               "const1-trial2-tdoa3-extracted", "rcv_twr-sequence3", "other"))
    assert labels == ["trial1", "trial2", "sequence3", "other"]
    assert g.tolist() == [0, 0, 1, 2, 3]


def test_teachers_validate_on_one_group_each_and_give_out_of_fold_predictions() -> None:
    s = synthetic(groups=3)
    ens, oof, rep = train_teachers(s, CFG, DistillConfig(teachers=2))
    assert rep.folds == ["trial1", "trial2"] and len(ens.nets) == 2
    group, _ = flight_groups(s.names)
    g = group[s.flight]
    # groups 0 and 1 were each some teacher's validation: predicted by the one that never trained on them
    assert np.all(np.isfinite(oof[g < 2])) and np.all(np.isnan(oof[g == 2]))
    np.testing.assert_allclose(oof[g == 0], ens.nets[0].predict_batch(s.x[g == 0]))
    assert rep.oof_rmse_m < 0.6 * float(np.std(s.bias))
    with pytest.raises(ValueError, match="at least 2 teachers"):
        train_teachers(s, CFG, DistillConfig(teachers=1))
    one_group = Samples(s.layout, s.x, s.bias, np.zeros(len(s), np.int64), s.pair, ("const1-trial1-tdoa2",))
    with pytest.raises(ValueError, match="2 flight groups"):
        train_teachers(one_group, CFG, DistillConfig(teachers=2))


@pytest.mark.parametrize("jitter", [0.0, 0.03])
def test_student_reproduces_the_teacher_and_is_as_good_on_new_inputs(jitter: float) -> None:
    s = synthetic()
    student, teacher, rep = distill(s, CFG, DistillConfig(teachers=4, jitter=jitter))
    t_train = teacher.predict_batch(s.x)
    spread = float(np.std(t_train))                                   # ~0.09 m of learnable bias
    assert rep.student_vs_teacher_m < 0.15 * spread
    fresh = np.random.default_rng(42).uniform(-3.0, 3.0, (20000, 6))  # inputs neither saw
    gap = student.predict_batch(fresh) - teacher.predict_batch(fresh)
    assert float(np.sqrt(np.mean(gap ** 2))) < 0.15 * spread
    truth = smooth_bias(fresh)
    err_student = float(np.sqrt(np.mean((student.predict_batch(fresh) - truth) ** 2)))
    err_teacher = float(np.sqrt(np.mean((teacher.predict_batch(fresh) - truth) ** 2)))
    assert err_student < 1.2 * err_teacher + 0.003 and err_teacher < 0.3 * spread
    # the same shape as the shipped networks: one 2x50 network, the data's input box
    assert student.w1.shape == (6, 50) and student.w2.shape == (50, 50)
    np.testing.assert_allclose(student.in_min, s.x.min(axis=0), rtol=1e-6)
    np.testing.assert_allclose(student.in_max, s.x.max(axis=0), rtol=1e-6)
    assert student.has_std      # fitted on the out-of-fold residual
    _, std = student.predict_with_std_batch(fresh)
    assert 0.03 <= float(np.sqrt(np.mean(std ** 2))) < 0.1   # noise 0.03 m plus what the teachers miss


def test_same_machine_same_weights() -> None:
    s = synthetic(groups=3, n=800)
    dcfg = DistillConfig(teachers=3, jitter=0.02)
    a, _, _ = distill(s, CFG, dcfg)
    b, _, _ = distill(s, CFG, dcfg)
    assert BiasModel(tdoa=a).hash == BiasModel(tdoa=b).hash
    c, _, _ = distill(s, TrainConfig(max_epochs=30, patience=6, batch_size=256, seed=4), dcfg)
    assert BiasModel(tdoa=c).hash != BiasModel(tdoa=a).hash


def test_train_ensemble_option_writes_one_distilled_network(tmp_path, capsys) -> None:  # noqa: ANN001
    from harness import cli
    out = tmp_path / "m.npz"
    argv = ["train", "--mode", "tdoa", "--flights", "3", "--duration", "8", "--epochs", "4", "--patience", "2",
            "--out", str(out), "--json"]
    assert cli.main([*argv, "--ensemble", "2"]) == 0
    res = __import__("json").loads(capsys.readouterr().out)
    model = BiasModel.load(out)
    assert res["hash"] == model.hash_hex and model.tdoa is not None and model.tdoa.w2.shape == (50, 50)
    dist = res["distilled"]
    assert dist["teachers"] == 2 and len(dist["folds"]) == 2 and dist["student_vs_teacher_m"] < 0.05
    assert cli.main([*argv, "--ensemble", "1"]) == 2           # an ensemble of one is refused, by name
    assert "at least 2 teachers" in capsys.readouterr().err
    assert cli.main([*argv, "--jitter", "0.1"]) == 2             # jitter without a student to jitter for
    assert "needs --ensemble" in capsys.readouterr().err
