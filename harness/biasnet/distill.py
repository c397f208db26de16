"""An ensemble of bias networks distilled into one 2x50 network (same layout, export and MCU cost).

Why: on the small recorded sets the held-out figure of one network depends on the seed, i.e. on which
whole flights early stopping watched (docs/decisions/2026-11-24-rcv-twr-one-network.md). Here K *teachers* are trained,
teacher k validated on flight group k (leave-one-group-out: a group is a UTIL trial or an rcv_twr
sequence, so early stopping never watches a flight recorded with its training flights) and seeded
differently; their averaged prediction is the *teacher*. One *student* of the shipped layout is then
fitted to the teacher's prediction on the training inputs (plus optional jittered copies of them, which
ask the student to follow the teacher between the training points), early-stopped on how well it follows
the teacher on inputs it did not fit (a jittered copy drawn with another stream). The student is what the
firmware runs; the teacher costs K networks and is reported for comparison only.

Its std head (uncertainty.py) describes the error on unseen flights: it is fitted on the training
flights' *out-of-fold* residual, bias minus the prediction of the teachers that never trained on that
flight's group (the student itself has seen every training flight through the teacher).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from harness.biasnet.dataset import Samples
from harness.biasnet.network import BiasNetwork
from harness.biasnet.train import ProgressFn, TrainConfig, TrainReport, train_network
from harness.biasnet.uncertainty import fit_std_head
from harness.errors import UsageError

#: a recording's group: UTIL "constC-trialT-..." -> "trialT"; rcv_twr "rcv_twr-sequenceS" -> "sequenceS"
GROUP_PATTERN = re.compile(r"(trial\d+|sequence\d+)")


@dataclass(frozen=True)
class DistillConfig:
    """K teachers on leave-one-group-out folds, one student fitted to their mean."""

    teachers: int = 4
    jitter: float = 0.0      # std of the input jitter, as a fraction of each input's training range
    copies: int = 1          # jittered copies of the training inputs added to the student's data (jitter > 0)
    val_samples: int = 200_000  # at most this many (jittered) inputs to early-stop the student on

    def validate(self) -> None:
        if self.teachers < 2:
            raise UsageError(f"an ensemble needs at least 2 teachers, got {self.teachers}")
        if self.jitter < 0.0 or self.copies < 0 or self.val_samples < 10:
            raise UsageError("jitter and copies must be >= 0 and val_samples >= 10")


@dataclass
class DistillReport:
    teachers: list[TrainReport] = field(default_factory=list)
    folds: list[str] = field(default_factory=list)          # validation group of each teacher
    student: TrainReport | None = None
    student_vs_teacher_m: float = float("nan")              # RMS of student - teacher on the training inputs
    oof_rmse_m: float = float("nan")                        # RMSE of bias - out-of-fold teacher prediction


@dataclass(frozen=True)
class Ensemble:
    """The teacher: the mean of its networks' predictions (each clamped to its own output range)."""

    nets: tuple[BiasNetwork, ...]

    def predict_batch(self, x: np.ndarray) -> np.ndarray:
        return np.mean([n.predict_batch(x) for n in self.nets], axis=0)


def flight_groups(names: tuple[str, ...]) -> tuple[np.ndarray, list[str]]:
    """Group index of every flight name and the group labels (a name without trial/sequence is its own)."""
    labels: list[str] = []
    out = np.empty(len(names), dtype=np.int64)
    for i, name in enumerate(names):
        m = GROUP_PATTERN.search(name)
        key = m.group(1) if m else name
        if key not in labels:
            labels.append(key)
        out[i] = labels.index(key)
    return out, labels


def _member_config(cfg: TrainConfig, seed: int, head: bool) -> TrainConfig:
    return replace(cfg, seed=seed, std_head=cfg.std_head if head else None)


def train_teachers(samples: Samples, cfg: TrainConfig, dcfg: DistillConfig,
                   progress: Callable[[str], ProgressFn | None] | None = None
                   ) -> tuple[Ensemble, np.ndarray, DistillReport]:
    """K networks, teacher k validated on group k mod G and trained on the others, seed cfg.seed * K + k.
    Returns the ensemble, the out-of-fold prediction of every sample (NaN where every teacher trained on
    it) and the report."""
    dcfg.validate()
    group_of_flight, labels = flight_groups(samples.names)
    if len(labels) < 2:
        raise UsageError(f"leave-one-group-out needs at least 2 flight groups, got {labels}")
    group = group_of_flight[samples.flight]
    report = DistillReport()
    nets = []
    oof_sum = np.zeros(len(samples))
    oof_n = np.zeros(len(samples))
    for k in range(dcfg.teachers):
        g = k % len(labels)
        val_mask = group == g
        seed = cfg.seed * dcfg.teachers + k
        net, rep = train_network(samples.subset(~val_mask), _member_config(cfg, seed, head=False),
                                 val=samples.subset(val_mask),
                                 progress=progress(f"teacher {k + 1}/{dcfg.teachers} (val {labels[g]})") if progress else None)
        nets.append(net)
        report.teachers.append(rep)
        report.folds.append(labels[g])
        oof_sum[val_mask] += net.predict_batch(samples.x[val_mask])
        oof_n[val_mask] += 1
    with np.errstate(invalid="ignore", divide="ignore"):
        oof = np.where(oof_n > 0, oof_sum / np.maximum(oof_n, 1), np.nan)
    seen = np.isfinite(oof)
    report.oof_rmse_m = float(np.sqrt(np.mean((samples.bias[seen] - oof[seen]) ** 2))) if seen.any() else float("nan")
    return Ensemble(tuple(nets)), oof, report


def _jittered(samples: Samples, teacher: Ensemble, jitter: float, copies: int, rng: np.random.Generator) -> Samples:
    """``copies`` copies of ``samples`` with inputs moved by N(0, (jitter * range)^2), teacher-labelled."""
    lo, hi = samples.x.min(axis=0), samples.x.max(axis=0)
    parts = []
    for _ in range(copies):
        # clipped to the data's box: the student's stored input ranges (the firmware's fade) stay the data's
        x = np.clip(samples.x + rng.standard_normal(samples.x.shape) * (jitter * (hi - lo)), lo, hi)
        parts.append(replace(samples, x=x, bias=teacher.predict_batch(x)))
    return Samples.concat(parts) if parts else samples.subset(np.zeros(len(samples), bool))


def distill(samples: Samples, cfg: TrainConfig = TrainConfig(), dcfg: DistillConfig = DistillConfig(),
            progress: Callable[[str], ProgressFn | None] | None = None
            ) -> tuple[BiasNetwork, Ensemble, DistillReport]:
    """Teachers on the folds, then the student fitted to their mean on ``samples``' inputs (+ jitter)."""
    teacher, oof, report = train_teachers(samples, cfg, dcfg, progress)
    rng = np.random.default_rng(cfg.seed + 7919)  # not the teachers' torch streams
    target = replace(samples, bias=teacher.predict_batch(samples.x))
    data = target
    if dcfg.jitter > 0.0 and dcfg.copies > 0:
        data = Samples.concat([target, _jittered(samples, teacher, dcfg.jitter, dcfg.copies, rng)])
    # Early stopping: how well the student follows the teacher off the points it is fitted to. Without
    # jitter, a small one (1 % of each range) still makes those points new.
    pick = rng.permutation(len(samples))[:dcfg.val_samples]
    val = _jittered(samples.subset(np.isin(np.arange(len(samples)), pick)), teacher, dcfg.jitter or 0.01, 1, rng)
    student, rep = train_network(data, _member_config(cfg, cfg.seed * dcfg.teachers + dcfg.teachers, head=False),
                                 val=val, progress=progress("student") if progress else None)
    report.student = rep
    report.student_vs_teacher_m = float(np.sqrt(np.mean((student.predict_batch(samples.x) - target.bias) ** 2)))
    seen = np.isfinite(oof)
    if cfg.std_head is not None and seen.sum() >= 10:
        # residual on unseen flights ~ the out-of-fold teacher's: fit the head to exactly that residual
        s = samples.subset(seen)
        student = fit_std_head(student, replace(s, bias=student.predict_batch(s.x) + (s.bias - oof[seen])),
                               cfg.std_head)
    return student, teacher, report
