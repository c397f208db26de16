"""Campaigns on boards (`uwb-hil campaign --target qemu --target qemu`, `--port P --port P2`, `--boards FILE`).

Each board serves one flight at a time: a campaign worker process (campaign/worker.py) opens the board's
port, streams the flight in every configuration and closes it; the boards run in parallel, flights dealt
costliest first to whichever board is free. Boards the harness runs itself (host build, QEMU) are started
once and stand for the whole campaign as a real board would (device/board_process.py). Every run summary
records its board ("board": name, target, port, USB serial number, and the board's HELLO at the start;
"device" is the run's own HELLO). A flight with failed runs gets its board probed (process alive, HELLO
within the timeout): a board that stops answering is taken out, the flight's failed runs go back to the
queue for the other boards, and the campaign says so (campaign.json "executor", CampaignOutcome.boards_out;
the CLI exits 3 when the verdict itself passed). With no board left, the flights not run fail with that reason.
Once every flight is back, every board still in service is probed once more (the same HELLO): a board that
died after its last flight would otherwise never be asked again. One that does not answer is taken out the
same way ("after_last_flight": its runs were complete, they stand and are judged; nothing is moved).
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

from harness.campaign.plan import RunSpec
from harness.campaign.runner import ExecContext, start_worker, stop_worker, worker_env, worker_finished
from harness.campaign.store import STATUS_OK, CampaignDir, read_json, write_json_atomic
from harness.device.board_list import BoardSpec, usb_serial_number
from harness.device.board_process import BoardProcess, start_board
from harness.device.registry import DeviceSpec, open_device
from harness.errors import DeviceError, UwbHilError


@dataclass
class Board:
    spec: BoardSpec
    process: BoardProcess | None = None
    port: str = ""
    hello: dict[str, Any] | None = None
    out: str | None = None                  # why the board was taken out
    flights: int = 0
    moved: int = 0                          # runs moved from it to the other boards
    after_last_flight: bool = False         # found dead by the check once every flight was back
    active: Active | None = None

    def info(self) -> dict[str, Any]:
        pid = self.process.pid if self.process is not None else None
        serial = self.spec.serial_number or usb_serial_number(self.port)
        return {**self.spec.as_dict(), "port": self.port, "serial_number": serial, "pid": pid, "hello": self.hello}

    def device(self) -> dict[str, Any]:
        return {"target": "serial", "port": self.port, "baud": self.spec.baud}


def probe(port: str, baud: int, timeout_s: float) -> dict[str, Any]:
    """The HELLO of the board on `port` (DeviceError / LinkError when it does not answer)."""
    with open_device(DeviceSpec(target="serial", port=port, baud=baud, timeout_s=timeout_s)) as dev:
        return dict(dev.identity.as_dict())


class BoardExecutor:
    """A GroupExecutor (campaign/runner.py) on boards; a context manager owning the boards it starts."""

    def __init__(self, boards: list[BoardSpec], log_dir: Path, probe_timeout_s: float = 5.0) -> None:
        self.boards = [Board(spec=b) for b in boards]
        self.log_dir = Path(log_dir)
        self.probe_timeout_s = probe_timeout_s
        self.final_check_s: float | None = None     # how long the end-of-campaign check took

    def __enter__(self) -> BoardExecutor:
        try:
            for b in self.boards:
                self._bring_up(b)
        except BaseException:
            self._stop_all()
            raise
        if not self.alive():
            self._stop_all()
            raise DeviceError("no board answered: " + "; ".join(f"{b.spec.name}: {b.out}" for b in self.boards))
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None) -> None:
        self._stop_all()

    def _bring_up(self, b: Board) -> None:
        try:
            b.process = start_board(b.spec, self.log_dir)
            b.port = b.process.port if b.process is not None else str(b.spec.resolved_port())
            b.hello = probe(b.port, b.spec.baud, max(self.probe_timeout_s, 10.0))
        except (UwbHilError, OSError) as exc:
            b.out = f"did not answer at the start: {exc}"

    def _stop_all(self) -> None:
        for b in self.boards:
            if b.process is not None:
                b.process.stop()

    def alive(self) -> list[Board]:
        return [b for b in self.boards if b.out is None]

    def describe(self) -> dict[str, Any]:
        names = ", ".join(b.spec.name for b in self.alive())
        return {"kind": "boards", "boards": [b.info() for b in self.boards],
                "text": f"on {len(self.alive())} boards: {names}"}

    def run(self, ctx: ExecContext, groups: list[list[RunSpec]]) -> None:
        queue: deque[list[RunSpec]] = deque(groups)
        env = worker_env()
        try:
            while queue or any(b.active for b in self.boards):
                for b in self.alive():
                    if b.active is None and queue:
                        b.active = start_worker(ctx, queue.popleft(), env, device=b.device())
                if queue and not self.alive():
                    why = "no board left: " + "; ".join(f"{b.spec.name} {b.out}" for b in self.boards)
                    while queue:
                        ctx.group_done(queue.popleft(), why, None)
                    continue
                time.sleep(0.1)
                for b in self.boards:
                    if b.active is not None and worker_finished(b.active):
                        self._finish(ctx, b, queue)
            self._check_at_end(ctx)
        finally:
            for b in self.boards:
                if b.active is not None:
                    stop_worker(b.active)
            self._record(ctx)

    def _finish(self, ctx: ExecContext, b: Board, queue: deque[list[RunSpec]]) -> None:
        a, b.active = b.active, None
        assert a is not None
        b.flights += 1
        ctx.annotate(a.runs, "board", {k: v for k, v in b.info().items() if k != "pid"})
        failed = [r for r in a.runs if not _ok(ctx, r)]
        why = a.why_missing()
        if failed and self._lost(b):
            for r in failed:
                ctx.cdir.summary_path(r.run_id).unlink(missing_ok=True)
            b.moved += len(failed)
            queue.appendleft(failed)
            ctx.n_groups += 1
            ctx.log(f"  board {b.spec.name} taken out ({b.out}): {len(failed)} runs of "
                    f"{a.runs[0].flight.flight_id} moved to the other boards")
            done = [r for r in a.runs if r not in failed]
            if not done:
                return
            ctx.group_done(done, why, a.log, where=f" on {b.spec.name}")
            return
        ctx.group_done(a.runs, why, a.log, where=f" on {b.spec.name}")

    def _lost(self, b: Board) -> bool:
        """Whether the board stopped answering (then it is taken out, with the reason)."""
        if b.process is not None and not b.process.alive():
            b.out = "its process exited"
            return True
        try:
            probe(b.port, b.spec.baud, self.probe_timeout_s)
        except (UwbHilError, OSError) as exc:
            b.out = f"stopped answering: {exc}"
            return True
        return False

    def _check_at_end(self, ctx: ExecContext) -> None:
        """Every flight is back: one probe of each board still in service (process alive, HELLO within the
        probe timeout), since a board that died during or after its last flight is otherwise never asked again.
        Its runs completed before it went and stand; the board is reported as taken out."""
        t0 = time.monotonic()
        for b in self.alive():
            if self._lost(b):
                b.after_last_flight = True
                ctx.log(f"  board {b.spec.name} taken out ({b.out}) after its last flight: the runs of its "
                        f"{b.flights} flights stand")
        self.final_check_s = time.monotonic() - t0

    def boards_out(self) -> list[dict[str, Any]]:
        return [{"board": b.spec.name, "reason": b.out, "moved_runs": b.moved,
                 "after_last_flight": b.after_last_flight} for b in self.boards if b.out]

    def _record(self, ctx: ExecContext) -> None:
        manifest = read_json(ctx.cdir.manifest)
        check = round(self.final_check_s, 3) if self.final_check_s is not None else None
        manifest["executor"] = {**self.describe(), "taken_out": self.boards_out(),
                                "flights_per_board": {b.spec.name: b.flights for b in self.boards},
                                "final_check_s": check}
        write_json_atomic(ctx.cdir.manifest, manifest)
        ctx.outcome.boards_out = self.boards_out()


def _ok(ctx: ExecContext, run: RunSpec) -> bool:
    try:
        summary = read_json(ctx.cdir.summary_path(run.run_id))
    except (OSError, ValueError):
        return False
    return bool(summary.get("status") == STATUS_OK and summary.get("fingerprint") == run.fingerprint())


def note_boards_in_verdict(cdir: CampaignDir, boards_out: list[dict[str, Any]]) -> None:
    """verdict.json says which boards were taken out and how many runs moved (the runs themselves are judged)."""
    try:
        verdict = read_json(cdir.verdict)
    except (OSError, ValueError):
        return
    verdict["boards_taken_out"] = boards_out
    write_json_atomic(cdir.verdict, verdict)
