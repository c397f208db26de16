"""Merge the directories of a sharded campaign (`uwb-hil campaign --shard K/N`, one per machine) into one
campaign directory, which the report then reads like an unsharded one.

Refused, naming the directories: a directory that is not a campaign shard, shards of different campaigns
(plan digest: the runs, their configurations and networks), different options, different firmware
(SHA-256 of the binary) or different networks (DIR/models/index.json), two directories claiming the same
shard or the same run. Missing shards are not an error: their runs show as "not run" in the report.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from harness.campaign.store import CampaignDataError, CampaignDir, read_json, write_json_atomic

# Options that name places on one machine, not what the campaign is (they differ between machines).
_MACHINE_OPTIONS = ("firmware", "data_dir", "sim_model")


class MergeError(CampaignDataError):
    """The directories are not shards of one campaign (names the directories and what differs)."""


def _manifest(d: Path) -> dict[str, Any]:
    cdir = CampaignDir(d)
    if not cdir.manifest.is_file():
        raise MergeError(f"{cdir.manifest}: not found; is {d} a campaign directory?")
    m = read_json(cdir.manifest)
    if not isinstance(m, dict) or not isinstance(m.get("plan"), dict):
        raise MergeError(f"{cdir.manifest}: no 'plan' (written before sharding existed): run it again")
    return m


def _spec(m: dict[str, Any]) -> dict[str, Any]:
    opts = {k: v for k, v in (m.get("options") or {}).items() if k not in _MACHINE_OPTIONS}
    return {"plan": m["plan"]["digest"], "options": opts,
            "firmware_sha256": (m.get("provenance") or {}).get("firmware_sha256")}


def _models(d: Path) -> Any:
    path = d / "models" / "index.json"
    index = read_json(path) if path.is_file() else None
    return {k: v for k, v in (index or {}).items() if k != "files"} | {
        "hashes": sorted((index or {}).get("files") or {})}


def check_shards(dirs: list[Path]) -> list[dict[str, Any]]:
    """The manifests, once every directory is known to be a shard of the same campaign."""
    manifests = [_manifest(d) for d in dirs]
    ref_spec, ref_models = _spec(manifests[0]), _models(dirs[0])
    seen_shards: dict[tuple[int, int], Path] = {}
    seen_runs: dict[str, Path] = {}
    for d, m in zip(dirs, manifests):
        spec = _spec(m)
        for key, what in (("plan", "planned runs (another campaign spec)"), ("options", "options"),
                          ("firmware_sha256", "firmware binary (SHA-256)")):
            if spec[key] != ref_spec[key]:
                raise MergeError(f"{d} and {dirs[0]} are not shards of one campaign: different {what}: "
                                 f"{spec[key]!r} vs {ref_spec[key]!r}")
        if _models(d) != ref_models:
            raise MergeError(f"{d} and {dirs[0]} ran different networks (models/index.json differ)")
        sh = m.get("shard")
        key = (int(sh["index"]), int(sh["count"])) if isinstance(sh, dict) else (1, 1)
        if key in seen_shards:
            raise MergeError(f"{d} and {seen_shards[key]} are both shard {key[0]}/{key[1]}")
        seen_shards[key] = d
        for r in m.get("runs") or []:
            if r["run_id"] in seen_runs:
                raise MergeError(f"run {r['run_id']} is in both {seen_runs[r['run_id']]} and {d}")
            seen_runs[r["run_id"]] = d
    counts = {k[1] for k in seen_shards}
    if len(counts) > 1:
        raise MergeError(f"shards of different splits: {sorted(f'{k}/{n}' for k, n in seen_shards)}")
    return manifests


def merge_shards(dirs: list[Path], out: Path) -> Path:
    """Copy the shards' runs, flights and networks into `out` with one manifest covering the whole plan."""
    dirs = [Path(d).resolve() for d in dirs]
    out = Path(out).resolve()
    if out in dirs:
        raise MergeError(f"--out {out} is one of the shard directories: give a new directory")
    manifests = check_shards(dirs)
    target = CampaignDir(out)
    target.make()
    for d, m in zip(dirs, manifests):
        src = CampaignDir(d)
        for r in m.get("runs") or []:
            for path in (src.summary_path(r["run_id"]), src.array_path(r["run_id"]),
                         src.results_gz_path(r["run_id"]), src.results_path(r["run_id"])):
                if path.exists():
                    shutil.copyfile(path, target.runs / path.name)
        for path in sorted(src.flights.glob("*.npz")):
            shutil.copyfile(path, target.flights / path.name)
    shutil.copytree(dirs[0] / "models", out / "models", dirs_exist_ok=True)
    first = manifests[0]
    plan_runs = first["plan"].get("runs") or [r for m in manifests for r in m.get("runs") or []]
    merged = {k: v for k, v in first.items() if k not in ("runs", "shard", "notes")}
    merged["runs"] = plan_runs
    merged["notes"] = sorted({n for m in manifests for n in m.get("notes") or []})
    merged["shard"] = None
    merged["merged_from"] = [{"dir": str(d), "shard": m.get("shard"), "provenance": m.get("provenance")}
                             for d, m in zip(dirs, manifests)]
    write_json_atomic(target.manifest, merged)
    verdict = _merged_verdict([CampaignDir(d) for d in dirs])
    if verdict is not None:
        write_json_atomic(target.verdict, verdict)
    return out


def _merged_verdict(shards: list[CampaignDir]) -> dict[str, Any] | None:
    """The shards' verdicts as one (each shard judged its own runs), if every shard was judged under the same
    criteria and configurations; else none (the merged report says nothing rather than something partial)."""
    vs = [read_json(c.verdict) if c.verdict.is_file() else None for c in shards]
    if any(not isinstance(v, dict) for v in vs) or any(
            (v["criteria"], v["judged_configs"]) != (vs[0]["criteria"], vs[0]["judged_configs"]) for v in vs):
        return None
    out = {k: vs[0][k] for k in ("criteria", "judged_configs")}
    out["runs"] = sorted((r for v in vs for r in v.get("runs") or []), key=lambda r: str(r.get("run_id")))
    out["failed_runs"] = sorted(x for v in vs for x in v.get("failed_runs") or [])
    out["passed"] = all(v.get("passed") for v in vs)
    out["judged_runs"] = len(out["runs"])
    out["not_judged"] = sum(int(v.get("not_judged") or 0) for v in vs)
    out["unavailable"] = sorted(x for v in vs for x in v.get("unavailable") or [])
    return out
