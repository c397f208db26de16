"""`uwb-hil range-offset`: fit a TWR range-offset calibration (antenna delay) on recordings with ground
truth and write it for `uwb-hil run --range-offset FILE` (harness/flight/range_offset.py)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def add_parser(sub: Any) -> None:
    p = sub.add_parser("range-offset", help="fit a TWR range-offset calibration (antenna delay) on recordings "
                                            "with ground truth, for `run --range-offset`")
    p.add_argument("--recording", action="append", required=True, metavar="REC",
                   help="a TWR recording with ground truth (repeatable: every range of every recording is used); "
                        "to evaluate, leave the flight you replay out")
    p.add_argument("--anchors", help="anchor file for the recordings (default: each recording's own)")
    p.add_argument("--per-anchor", action="store_true",
                   help="also an offset per anchor id (on rcv_twr it does not carry over between sequences)")
    p.add_argument("--out", required=True, help="calibration file to write (JSON)")
    p.add_argument("--force", action="store_true", help="use recordings that fail the plausibility checks")
    p.add_argument("--json", action="store_true", help="print the calibration as JSON")
    p.set_defaults(func=cmd_range_offset)


def cmd_range_offset(args: argparse.Namespace) -> int:
    from harness.flight.loaders import load_recording
    from harness.flight.range_offset import fit_range_offset, save_range_offset
    flights = [load_recording(Path(r), anchors=Path(args.anchors) if args.anchors else None, check=not args.force)
               for r in args.recording]
    cal = fit_range_offset(flights, per_anchor=args.per_anchor)
    save_range_offset(cal, Path(args.out))
    if args.json:
        print(json.dumps(cal.as_dict(), indent=2))
        return 0
    print(f"range offset {cal.offset_m:+.4f} m (median range - true range over {cal.measurements} ranges of "
          f"{len(flights)} flight(s): {', '.join(cal.fitted_on)})")
    for k, v in sorted(cal.per_anchor_m.items()):
        print(f"  anchor {k}: {v:+.4f} m")
    print(f"written to {args.out}")
    return 0
