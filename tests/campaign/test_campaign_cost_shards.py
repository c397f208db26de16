"""Shards dealt by estimated run time (harness/campaign/shards.py): `make campaign`'s plan split in 2 or 3
gives shards whose estimated wall times are within 25 % of each other, the real-time latency flights land in
different shards, and the estimate follows the pacing (a real-time run costs its duration)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from harness.campaign.plan import ROLE_LATENCY, CampaignOptions, FlightSpec, RunSpec, group_by_flight, plan_campaign
from harness.campaign.shards import GROUP_SETUP_S, costliest_first, deal, group_cost_s, run_cost_s, shard_runs
from harness.paths import DEFAULT_FIRMWARE

pytestmark = pytest.mark.skipif(not DEFAULT_FIRMWARE.exists(), reason="host firmware not built (make firmware)")


def shard_costs(runs: list[RunSpec], count: int) -> list[float]:
    """Estimated wall time of each of `count` shards [s], as shards.deal splits the plan."""
    groups = group_by_flight(runs)
    return [sum(group_cost_s(groups[i]) for i in idx) for idx in deal(groups, count)]


@pytest.mark.parametrize("count", [2, 3])
def test_make_campaign_plan_shards_within_25_percent(count: int) -> None:
    runs, _ = plan_campaign(CampaignOptions())          # what `make campaign` plans (recorded flights if present)
    costs = shard_costs(runs, count)
    assert len(costs) == count and min(costs) > 0
    assert max(costs) <= 1.25 * min(costs), costs
    split = [shard_runs(runs, k, count) for k in range(1, count + 1)]
    assert sorted(r.run_id for s in split for r in s) == sorted(r.run_id for r in runs)
    latency = [sum(r.role == ROLE_LATENCY for r in s) for s in split]
    assert sorted(latency)[-1] == 1, latency              # never two real-time flights in one shard


def test_round_robin_would_not_have_balanced_them() -> None:
    """The reason for the change: round-robin put both latency flights (the first flight of each mode) into
    one shard of two, 2.4x the other's time on this plan."""
    runs, _ = plan_campaign(CampaignOptions(recorded=False))
    groups = group_by_flight(runs)
    rr = [sum(group_cost_s(g) for i, g in enumerate(groups) if i % 2 == k) for k in range(2)]
    assert max(rr) > 1.5 * min(rr)
    costs = shard_costs(runs, 2)
    assert max(costs) <= 1.25 * min(costs)


def test_cost_follows_pacing_and_size() -> None:
    f = FlightSpec(source="sim", mode="twr", trajectory="circle", seed=1000, duration_s=70.0)
    windowed = RunSpec(flight=f, config="outlier")
    realtime = replace(windowed, pacing="realtime", role=ROLE_LATENCY)
    assert run_cost_s(realtime) == pytest.approx(70.0)
    assert 0.1 < run_cost_s(windowed) < 5.0
    tdoa = replace(windowed, flight=replace(f, mode="tdoa"))
    assert run_cost_s(tdoa) == pytest.approx(2 * run_cost_s(windowed))     # 400 Hz against 200 Hz
    assert group_cost_s([windowed, realtime]) == pytest.approx(GROUP_SETUP_S + 70.0 + run_cost_s(windowed))


def test_deal_is_deterministic_and_costliest_first() -> None:
    runs, _ = plan_campaign(CampaignOptions(seeds=3, recorded=False))
    groups = group_by_flight(runs)
    assert deal(groups, 2) == deal(groups, 2)
    ordered = costliest_first(groups)
    assert any(r.role == ROLE_LATENCY for r in ordered[0])
    costs = [group_cost_s(g) for g in ordered]
    assert costs == sorted(costs, reverse=True)
