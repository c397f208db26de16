"""The verdict of a campaign: each judged run's stored summary under the campaign's criteria.

Which runs are judged: those of the configurations in `judge` (`uwb-hil campaign --judge`). By default
every configuration flown except "none": that configuration (no outlier rejection) is the paper's
baseline, kept to be compared against, and on real NLOS/TDoA3 data it legitimately diverges (one gross
range is fused as it is); failing a campaign for it would fail every campaign with recorded flights.

The verdict is computed from the summaries on disk (DIR/runs/<run_id>.json), so runs resumed from an
earlier invocation or run by this shard are judged alike, and written to DIR/verdict.json (a shard: its
own runs), which the report carries into report.json ("verdict") and report.md.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Iterable, Sequence

from harness.campaign.plan import RunSpec
from harness.campaign.store import STATUS_OK, CampaignDataError, CampaignDir, write_json_atomic
from harness.errors import UsageError
from harness.report.verdict import Criteria, evaluate

#: The configuration a campaign's verdict leaves out unless `--judge` names it (see the module doc).
BASELINE_CONFIG = "none"


def default_judged(configs: Iterable[str]) -> tuple[str, ...]:
    """Every configuration flown except the baseline."""
    return tuple(c for c in configs if c != BASELINE_CONFIG)


def check_judged(judge: Sequence[str], configs: Sequence[str]) -> tuple[str, ...]:
    """`judge` if every name is a configuration the campaign flies (ValueError naming the others)."""
    unknown = [c for c in judge if c not in configs]
    if unknown:
        raise UsageError(f"--judge: {', '.join(unknown)} not among the configurations flown "
                         f"({', '.join(configs)}; --configs chooses them)")
    return tuple(dict.fromkeys(judge))


@dataclass(frozen=True)
class RunVerdict:
    run_id: str
    flight_id: str
    config: str
    role: str
    passed: bool
    checks: list[dict[str, Any]]
    reason: str

    def line(self) -> str:
        return f"{self.flight_id} {self.config} ({self.role}): {self.reason}"


@dataclass(frozen=True)
class CampaignVerdict:
    passed: bool
    criteria: dict[str, Any]
    judged_configs: tuple[str, ...]
    runs: tuple[RunVerdict, ...]
    not_judged: int                 # runs of configurations outside `judged_configs`
    unavailable: tuple[str, ...]    # judged runs without an ok summary (failed or not run): judged elsewhere

    def failures(self) -> list[RunVerdict]:
        return [r for r in self.runs if not r.passed]

    def reason(self) -> str:
        bad = self.failures()
        return f"{len(bad)} of {len(self.runs)} judged runs failed: " + "; ".join(r.line() for r in bad)

    def as_dict(self) -> dict[str, Any]:
        return {"passed": self.passed, "criteria": self.criteria, "judged_configs": list(self.judged_configs),
                "judged_runs": len(self.runs), "failed_runs": sorted(r.line() for r in self.failures()),
                "not_judged": self.not_judged, "unavailable": list(self.unavailable),
                "runs": [asdict(r) for r in self.runs]}


def judge_campaign(cdir: CampaignDir, runs: Sequence[RunSpec], criteria: Criteria,
                   judged: Sequence[str]) -> CampaignVerdict:
    """Judge the stored summary of every run of a judged configuration; write DIR/verdict.json."""
    verdicts: list[RunVerdict] = []
    unavailable: list[str] = []
    not_judged = 0
    for run in runs:
        if run.config not in judged:
            not_judged += 1
            continue
        try:
            stored = cdir.read_summary(run.run_id)
        except CampaignDataError:
            stored = None
        if not stored or stored.get("status") != STATUS_OK or not isinstance(stored.get("summary"), dict):
            unavailable.append(run.run_id)   # the campaign already fails for it (a run that did not complete)
            continue
        v = evaluate(stored["summary"], criteria)
        verdicts.append(RunVerdict(run_id=run.run_id, flight_id=run.flight.flight_id, config=run.config,
                                   role=run.role, passed=v.passed, checks=v.as_dict()["checks"],
                                   reason=v.reason() if not v.passed else "pass"))
    verdicts.sort(key=lambda r: r.run_id)     # the order a merge of shards gives too
    out = CampaignVerdict(passed=all(r.passed for r in verdicts),
                          criteria={k: v for k, v in asdict(criteria).items() if v is not None},
                          judged_configs=tuple(judged), runs=tuple(verdicts), not_judged=not_judged,
                          unavailable=tuple(sorted(unavailable)))
    write_json_atomic(cdir.verdict, out.as_dict())
    return out
