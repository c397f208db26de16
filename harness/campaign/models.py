"""The networks a campaign ran, copied into its directory, so the report reads only the directory.

    DIR/models/<hash>.npz        every bias network a run used (the firmware's default one included)
    DIR/models/index.json        {"default": hash, "families": {"sim"|"util_tdoa_pos"|"rcv_twr": hash},
                                  "files": {hash: {"file", "source"}}, "summary": {models.json entries}}
    DIR/models/fig5_rcv.npz      the real heading sweep for the report's Fig. 5 (native flight), if present
    DIR/models/fig5_cf.npz       a held-out Crazyflie uSD flight (real attitude) for the Crazyflie Fig. 5

"summary" holds only the models.json entries whose network was copied and has the recorded hash: a figure
of a network the campaign did not have is never shown. Written once per campaign (and identical in every
shard of a sharded one: the merge compares index.json).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any, Iterable

from harness.campaign.store import CampaignDir, read_json, write_json_atomic

INDEX = "index.json"
FIG5_RCV_FLIGHT = "fig5_rcv.npz"
FIG5_RCV_SEQUENCE = "rcv_twr/sequence3"        # the real heading sweep (relative to the data folder)
FIG5_CF_FLIGHT = "fig5_cf.npz"
FIG5_CF_LOG = "cf_usd/0425/0425-traj3"         # an evaluation flight of the real-flight network


def models_dir(cdir: CampaignDir) -> Path:
    return cdir.root / "models"


def snapshot_models(cdir: CampaignDir, run_models: Iterable[str | None], default_npz: Path, summary_json: Path,
                    data_dir: Path | None) -> dict[str, Any]:
    """Copy the default network, every run's network and the matching models.json entries into DIR/models."""
    from harness.biasnet.network import BiasModel

    out = models_dir(cdir)
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, dict[str, str]] = {}

    def copy(path: Path) -> str:
        h = BiasModel.load(path).hash_hex        # checks the file's stored hash against its weights
        if h not in files:
            shutil.copyfile(path, out / f"{h}.npz")
            files[h] = {"file": f"{h}.npz", "source": str(path)}
        return h

    index: dict[str, Any] = {"default": copy(default_npz) if default_npz.is_file() else None, "families": {}}
    for m in sorted({m for m in run_models if m}):
        copy(Path(m))
    summary: dict[str, Any] = {}
    try:
        known = json.loads(summary_json.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        known = {}
    root = summary_json.parent.parent.parent     # models.json names files relative to the repository
    notes: list[str] = []
    for key, entry in known.items():
        if not isinstance(entry, dict) or "hash" not in entry:
            continue
        src = root / str(entry.get("file", ""))
        if entry["hash"] not in files and src.is_file():
            # the real-data networks of the report's Fig. 5 / table, if the file is the one recorded
            if BiasModel.load(src).hash_hex == entry["hash"]:
                copy(src)
            else:
                notes.append(f"{src}: not the network models.json records for {key} ({entry['hash']}): left out")
        if entry["hash"] in files:
            index["families"][key] = entry["hash"]
            summary[key] = entry
        else:
            notes.append(f"models.json entry {key} ({entry['hash']}): its network is not here, its figures left out")
    index["files"] = files
    index["summary"] = summary
    for family, key, rel, fname in (("rcv_twr", "fig5_rcv_flight", FIG5_RCV_SEQUENCE, FIG5_RCV_FLIGHT),
                                    ("cf_tdoa_pose", "fig5_cf_flight", FIG5_CF_LOG, FIG5_CF_FLIGHT)):
        index[key] = None
        if family in index["families"]:
            try:
                index[key] = _snapshot_fig5_flight(out, data_dir, rel, fname)
            except (ValueError, OSError) as exc:  # RecordingError is a ValueError: the figure is left out
                notes.append(f"Fig. 5 flight {rel} not stored: {exc}")
    index["notes"] = notes
    write_json_atomic(out / INDEX, index)
    return index


def _snapshot_fig5_flight(out: Path, data_dir: Path | None, rel: str, fname: str) -> str | None:
    """The recording `rel` (under data_dir) as a native flight DIR/models/`fname`; None if it is not there."""
    if data_dir is None or not (Path(data_dir) / rel).exists():
        return None
    from harness.flight.loaders import load_recording
    from harness.flight.native import save_flight
    target = out / fname
    if not target.exists():
        save_flight(load_recording(Path(data_dir) / rel), target)
    return fname


def read_index(root: Path) -> dict[str, Any] | None:
    """DIR/models/index.json, or None for a campaign written before networks were copied into it."""
    path = Path(root) / "models" / INDEX
    return read_json(path) if path.is_file() else None


def model_path(root: Path, index: dict[str, Any], model_hash: str | None) -> Path | None:
    entry = (index.get("files") or {}).get(model_hash) if model_hash else None
    return Path(root) / "models" / entry["file"] if entry else None
