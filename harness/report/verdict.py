"""Pass criteria and the verdict of a run: every run ends in pass or fail, with each check named.

Criteria (all optional; from options `--max-rmse ...` or a TOML file with the same keys, underscores):
  max_rmse             position RMSE [m]; 3-D, or over the observable axes when z is not observable
  max_rmse_xy          horizontal RMSE [m]
  max_p99_compute_us   p99 of the device's compute time per measurement [us, or instructions]
  max_p99_rtt_us       p99 of the round trip [us] (in windowed pacing it includes queueing)
  max_lost             measurements without an answer
  max_deadline_misses  compute over the budget, plus (lockstep/realtime pacing) round trips over it
  vdop_threshold       z counts as unobservable when VDOP is above this for most of the flight (5)
  allow_unobservable   false (default): a flight whose position is not observable (no axis: the anchors
                       cannot localise it, or they stand on one vertical plane) fails, whatever its RMSE;
                       true: reported, not failed (`--allow-unobservable`)
When z alone is not observable, the horizontal position is judged and the check "observable" says so
(the verdict line names it).

The filter's health is always checked, criteria or not: no supervisor reset (DIVERGED), no non-finite
estimate, no sign that P is not positive definite (a variance <= 0, or S = H P H^T + R below R), at
least one measurement fused, and no input frame refused by the device ("device_refusals": its STATS counters
of CRC, framing, length, non-finite, time-backwards, ... errors over the run; the harness validates what it
sends, so a refusal is a defect, unless the run injects link faults on purpose). A restart after a gap without measurements (RESULT.flags GAP_RESTART: the
covariance outgrew its bound while nothing was measured) is reported as the check "measurement_gaps",
which always passes: it says the data has holes, not that the filter diverged.

A run with a ground phase (accuracy.phases: measurements whose true tag height is below `--flight-above`,
0.4 m by default; report/phases.py) has its position criteria (max_rmse, max_rmse_xy) judged on the flight
phase, the checks' detail saying so; the ground phase is the check "ground_phase", reported and always
passed. The health checks cover the whole run.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any, Collection, Mapping

from harness.errors import InputError

DEFAULT_VDOP_THRESHOLD = 5.0


class CriteriaError(InputError):
    """A criterion is malformed (bad value, unknown key, unreadable file)."""


@dataclass(frozen=True)
class Criteria:
    """Thresholds of a verdict; None = not checked."""

    max_rmse: float | None = None
    max_rmse_xy: float | None = None
    max_p99_compute_us: float | None = None
    max_p99_rtt_us: float | None = None
    max_lost: float | None = None
    max_deadline_misses: float | None = None
    vdop_threshold: float = DEFAULT_VDOP_THRESHOLD
    allow_unobservable: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.allow_unobservable, bool):
            raise CriteriaError(f"allow_unobservable must be true or false, got {self.allow_unobservable!r}")
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None or f.name == "allow_unobservable":
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise CriteriaError(f"{f.name} must be a finite number >= 0, got {v!r}")

    @classmethod
    def from_toml(cls, path: Path, applicable: Collection[str] | None = None, command: str = "") -> "Criteria":
        """Read criteria from a TOML file (top level or a [criteria] table); with `applicable`, a known
        criterion outside it is refused as not applicable to `command` (e.g. fly has no compute figures)."""
        try:
            data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise CriteriaError(f"{path}: criteria file not found") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise CriteriaError(f"{path}: cannot read the criteria file ({exc})") from None
        except tomllib.TOMLDecodeError as exc:
            raise CriteriaError(f"{path}: not valid TOML ({exc})") from None
        table = data.get("criteria", data)
        if not isinstance(table, dict):
            raise CriteriaError(f"{path}: [criteria] must be a table")
        return cls.from_mapping(table, where=str(path), applicable=applicable, command=command)

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], where: str = "criteria", applicable: Collection[str] | None = None,
                     command: str = "") -> "Criteria":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise CriteriaError(f"{where}: unknown criterion {', '.join(unknown)} (known: {', '.join(sorted(known))})")
        foreign = sorted(set(values) - set(applicable)) if applicable is not None else []
        if foreign:
            raise CriteriaError(f"{where}: {', '.join(foreign)} not applicable to {command or 'this command'} "
                                f"(it judges: {', '.join(sorted(applicable or ())) or 'nothing'})")
        try:
            return cls(**dict(values))
        except CriteriaError as exc:
            raise CriteriaError(f"{where}: {exc}") from None

    def overridden_by(self, other: Mapping[str, Any]) -> "Criteria":
        """These criteria with the non-None values of `other` (command-line options win over a file)."""
        return replace(self, **{k: v for k, v in other.items() if v is not None})


@dataclass(frozen=True)
class Check:
    name: str
    threshold: float | None
    value: float | None
    passed: bool
    detail: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "threshold": _num(self.threshold), "value": _num(self.value),
                "passed": self.passed, "detail": self.detail}


@dataclass(frozen=True)
class Verdict:
    passed: bool
    checks: tuple[Check, ...]

    def as_dict(self) -> dict[str, Any]:
        return {"passed": self.passed, "checks": [c.as_dict() for c in self.checks]}

    def failures(self) -> list[Check]:
        return [c for c in self.checks if not c.passed]

    def notes(self) -> list[str]:
        """What a passed verdict judged differently from what was asked (e.g. xy only: z not observable)."""
        return [c.detail for c in self.checks if c.passed and c.name.endswith("observable") and c.detail]

    def reason(self) -> str:
        """One line naming every failed check."""
        return "; ".join(f"{c.name} {_fmt(c.value)}" + (f" > {_fmt(c.threshold)}" if c.threshold is not None else "")
                         + (f" ({c.detail})" if c.detail else "") for c in self.failures())


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _fmt(x: float | None) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "n/a"
    return f"{x:g}" if isinstance(x, float) else str(x)


def _at_most(name: str, value: float | None, threshold: float, detail: str = "") -> Check:
    ok = value is not None and math.isfinite(value) and value <= threshold
    if value is None or not math.isfinite(value):
        detail = detail or "no value (no measurement answered?)"
    return Check(name, threshold, value, ok, detail)


def health_checks(summary: Mapping[str, Any]) -> list[Check]:
    """The checks every run must pass (from run_summary's "health" and "accuracy")."""
    h = summary.get("health") or {}
    acc = summary.get("accuracy") or {}
    out = [
        _at_most("diverged", h.get("divergences", 0), 0,
                 h.get("divergence_reasons", "") and f"supervisor resets: {h.get('divergence_reasons')}"),
        _at_most("non_finite_estimates", h.get("non_finite", 0), 0),
        _at_most("covariance_not_pd", h.get("not_pd", 0), 0,
                 "results with a variance <= 0 or S = H P H^T + R below R"),
    ]
    out += _refusal_checks(summary)
    gaps = int(h.get("gap_restarts", 0) or 0)
    if gaps:   # reported, never failed: no measurements is the data's state, not the filter's fault
        out.append(Check("measurement_gaps", None, gaps, True,
                         f"the filter restarted from its last fix after {gaps} gap(s) without measurements "
                         f"(longest {_fmt(h.get('longest_gap_s'))} s): not a divergence"))
    accepted = acc.get("accepted", 0)
    out.append(Check("measurements_fused", 1, accepted, bool(accepted and accepted >= 1),
                     "" if accepted else "the filter fused no measurement"))
    return out


def _refusal_checks(summary: Mapping[str, Any]) -> list[Check]:
    """'device_refusals': input frames the device refused over the run (STATS counters), 0 allowed; a run
    over a link that injects faults on purpose reports them without failing."""
    counts = summary.get("device_refusals")
    if not isinstance(counts, Mapping):
        return []      # not measured (a resumed run: the counters before it are unknown)
    total = sum(int(v) for v in counts.values())
    named = ", ".join(f"{k} {int(v)}" for k, v in counts.items() if v)
    if summary.get("faults_injected"):
        return [Check("device_refusals", None, total, True, f"faults injected on purpose: {named}")] if total else []
    return [_at_most("device_refusals", total, 0,
                     f"the device refused frames the harness sent as valid: {named}" if total else "")]


def observability_check(geo: Mapping[str, Any], allow_unobservable: bool = False) -> Check | None:
    """"observable": fails when no axis is observable (the RMSE of such a flight means nothing: the anchors
    cannot localise it, or its mirror image across the anchors' plane has the same ranges) unless allowed;
    passes with a note when only z is not observable (xy judged); None when both are."""
    if not geo.get("xy_observable", True):
        why = (f"anchors on one vertical plane in {100 * geo['mirror_share']:.0f} % of epochs: the mirror "
               "image across it has the same ranges, so the horizontal position is ambiguous"
               if geo.get("mirror_axis") == "xy" else "the anchors cannot localise this flight")
        return Check("observable", None, None, allow_unobservable,
                     f"position not observable (HDOP p50 {_fmt(geo.get('hdop_p50'))}, VDOP p50 "
                     f"{_fmt(geo.get('vdop_p50'))}): {why}" + ("; allowed" if allow_unobservable else ""))
    if not geo.get("z_observable", True):
        mirror = (f"; anchors on one plane in {100 * geo['mirror_share']:.0f} % of epochs: the mirror image "
                  "has the same ranges" if geo.get("mirror_axis") == "z" else "")
        return Check("observable", None, None, True,
                     f"z not observable (VDOP p50 {_fmt(geo.get('vdop_p50'))}{mirror}): xy judged")
    return None


def judged_accuracy(summary: Mapping[str, Any]) -> Mapping[str, Any]:
    """The accuracy the position criteria judge: the flight phase's when the run has a ground phase
    (accuracy.phases, report/phases.py), else the whole run's."""
    acc = summary.get("accuracy") or {}
    phases = acc.get("phases")
    return phases["flight"] if isinstance(phases, Mapping) and "flight" in phases else acc


def _phase_noted(checks: list[Check], summary: Mapping[str, Any]) -> list[Check]:
    """With a ground phase: the position checks say they judge the flight phase, and the check
    "ground_phase" (always passed) reports the ground phase's accuracy, not judged."""
    acc = summary.get("accuracy") or {}
    phases = acc.get("phases")
    if not isinstance(phases, Mapping) or "ground" not in phases:
        return checks
    above, fl, gr = _fmt(acc.get("flight_above")), phases.get("flight") or {}, phases["ground"]
    scope = f"flight phase, truth above {above} m: {fl.get('n', 0)} of {acc.get('n', 0)} measurements"
    out = [replace(c, detail=f"{scope}; {c.detail}" if c.detail else scope) if c.name in ("rmse", "rmse_xy") else c
           for c in checks]
    m = {k: "n/a" if not isinstance(v, (int, float)) or not math.isfinite(v)
         else format(v, "+.3f" if k == "z_mean_error" else ".3f") for k, v in gr.items()}
    out.append(Check("ground_phase", None, gr.get("rmse"), True,
                     f"{gr.get('n', 0)} measurements with truth below {above} m: RMSE {m.get('rmse')} m (xy "
                     f"{m.get('rmse_xy')}, z {m.get('rmse_z')}, z mean error {m.get('z_mean_error')}): reported, "
                     "not judged"))
    return out


def evaluate(summary: Mapping[str, Any], criteria: Criteria = Criteria()) -> Verdict:
    """The verdict of one run summary (harness.report.metrics.run_summary) under `criteria`."""
    checks = health_checks(summary)
    acc = judged_accuracy(summary)      # the flight phase when the run has a ground phase
    geo = summary.get("geometry") or {}
    comp = summary.get("compute") or {}
    rtt = summary.get("round_trip_us") or {}
    obs = observability_check(geo, criteria.allow_unobservable)
    if obs is not None:
        checks.append(obs)
    if criteria.max_rmse is not None:
        if not geo.get("xy_observable", True):
            checks.append(Check("rmse", criteria.max_rmse, acc.get("rmse"), criteria.allow_unobservable,
                                "not judged: position not observable"))
        elif geo.get("z_observable", True):
            checks.append(_at_most("rmse", acc.get("rmse"), criteria.max_rmse))
        else:
            checks.append(_at_most("rmse", acc.get("rmse_xy"), criteria.max_rmse,
                                   f"horizontal RMSE; z RMSE {_fmt(acc.get('rmse_z'))} reported, not judged"))
    if criteria.max_rmse_xy is not None:
        checks.append(_at_most("rmse_xy", acc.get("rmse_xy"), criteria.max_rmse_xy))
    checks = _phase_noted(checks, summary)
    if criteria.max_p99_compute_us is not None:
        checks.append(_at_most("p99_compute", comp.get("p99"), criteria.max_p99_compute_us,
                               str(summary.get("compute_unit", ""))))
    if criteria.max_p99_rtt_us is not None:
        checks.append(_at_most("p99_rtt_us", rtt.get("p99"), criteria.max_p99_rtt_us,
                               "includes queueing (windowed pacing)" if summary.get("pacing") == "windowed" else ""))
    if criteria.max_lost is not None:
        checks.append(_at_most("lost", summary.get("lost"), criteria.max_lost))
    if criteria.max_deadline_misses is not None:
        checks.append(_at_most("deadline_misses", summary.get("deadline_misses"), criteria.max_deadline_misses))
    return Verdict(passed=all(c.passed for c in checks), checks=tuple(checks))


def evaluate_all(summaries: list[Mapping[str, Any]], criteria: Criteria = Criteria()) -> Verdict:
    """One verdict over several runs (demo, campaign): each check named after its run."""
    checks: list[Check] = []
    for s in summaries:
        label = "/".join(str(s[k]) for k in ("mode", "config") if s.get(k) is not None) or str(s.get("flight", "run"))
        checks += [replace(c, name=f"{label}:{c.name}") for c in evaluate(s, criteria).checks]
    return Verdict(passed=all(c.passed for c in checks), checks=tuple(checks))


def assert_verdict(summary: Mapping[str, Any], criteria: Criteria | None = None, **thresholds: float) -> Verdict:
    """The verdict of `summary` under `criteria` overridden by `thresholds` (e.g. max_rmse=0.1); raises
    AssertionError naming every failed check (the pytest plugin's `uwb_verdict` fixture)."""
    verdict = evaluate(summary, (criteria or Criteria()).overridden_by(thresholds))
    if not verdict.passed:
        raise AssertionError(f"verdict failed: {verdict.reason()}")
    return verdict


#: The criteria `uwb-hil fly` judges (the closed loop has no run summary: its cells carry tracking RMSE).
FLY_CRITERIA = ("max_rmse",)


def fly_verdict(result: Mapping[str, Any], criteria: Criteria = Criteria()) -> Verdict:
    """The verdict of `uwb-hil fly` (harness.closedloop.fly.fly_cells): per cell, every flight
    took off and completed its mission; with max_rmse, the worst seed's tracking RMSE |p_true - p_cmd|."""
    checks: list[Check] = []
    for c in result.get("cells", []):
        label = f"{c['mode']}/{c['mission']}/{c['config']}"
        n = int(c["flights"])
        checks.append(_at_most(f"{label}:takeoff_failures", n - int(c["takeoff_success"]), 0))
        checks.append(_at_most(f"{label}:incomplete_flights", n - int(c["completed"]), 0))
        if criteria.max_rmse is not None:
            checks.append(_at_most(f"{label}:tracking_rmse_max", c.get("tracking_rmse_max"), criteria.max_rmse))
    return Verdict(passed=all(ch.passed for ch in checks), checks=tuple(checks))
