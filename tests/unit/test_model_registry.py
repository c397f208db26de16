"""The model registry (harness/biasnet/registry.py) finds the shipped networks: by family, by purpose (the
position-only network of a kind), and models.json holds an entry under each registered name."""

from __future__ import annotations

import json

from harness.biasnet.registry import (RECORDED_MODELS, SUMMARY, position_only_hint, position_only_model,
                                      takes_attitude)
from harness.campaign.plan import RECORDED_MODELS as PLAN_MODELS
from harness.flight.data import KIND_TDOA, KIND_TWR
from harness.paths import MODELS_DIR


def test_the_registry_names_the_shipped_recorded_networks() -> None:
    summary = json.loads(SUMMARY.read_text())
    for family, model in RECORDED_MODELS.items():
        assert model.family == family and model.name in summary
        assert model.path == MODELS_DIR / f"{model.name}.npz"
        assert summary[model.name]["file"] == model.repo_path
        assert PLAN_MODELS[family] == (model.name, model.path)


def test_the_position_only_hint_comes_from_the_registry() -> None:
    tdoa = position_only_model(KIND_TDOA)
    assert tdoa is not None and tdoa.name == "util_tdoa_pos" and not takes_attitude(tdoa.layout)
    assert f"--model {tdoa.repo_path} (built by `make models`)" in position_only_hint(KIND_TDOA)
    assert position_only_model(KIND_TWR) is None          # the rcv_twr network takes the attitude
    assert position_only_hint(KIND_TWR).startswith("train one with `uwb-hil train")
