"""One run of `uwb-hil run`: a flight streamed through a device into a summary; or the resumption of an
interrupted run from its results file (harness/stream/resume.py)."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

from harness.config import EstimatorConfig
from harness.errors import ResultsFileError
from harness.paths import output_path
from harness.flight.data import Flight
from harness.report.summarize import summarize_run
from harness.run.source import RunSource, long_simulation, make_flight, make_run_flight, source_config
from harness.device.registry import DeviceSpec, open_device
from harness import kinds
from harness.biasnet.registry import check_network_inputs
from harness.stream.streamer import Pacing, Streamer

Progress = Callable[[int, int], None]
#: label -> (update(done, total), stop()): how a caller shows a run's progress (a no-op by default)
ProgressFactory = Callable[[str], tuple[Progress, Callable[[], None]]]


def no_progress(label: str) -> tuple[Progress, Callable[[], None]]:
    return (lambda done, total: None), (lambda: None)


@contextmanager
def _shown(progress: ProgressFactory, label: str) -> Iterator[Progress]:
    update, stop = progress(label)
    try:
        yield update
    finally:
        stop()


def checked_results_path(results: str | None, overwrite: bool, inputs: Sequence[str | None] = ()) -> Path | None:
    """The results file, refused before any device starts if it is a directory, an unfinished run, or one
    of the run's `inputs` (recording, anchors, model, ...: by inode, --overwrite or not)."""
    if not results:
        return None
    from harness.paths import same_file_as_input
    from harness.stream.results_file import check_not_in_use, describe_existing
    path = Path(results)
    if path.is_dir():
        raise ResultsFileError(f"results file {path} is a directory: give a file name, e.g. {path / 'run.jsonl'}")
    output_path(path, "--results")             # not under a file ("File exists" named the folder)
    clash = same_file_as_input(path, list(inputs))
    if clash is not None:
        raise ResultsFileError(f"results file {path} is an input of this run ({clash[:100]}): it would be "
                               "destroyed; give another file name")
    check_not_in_use(path)
    why = describe_existing(path)
    if why is not None and not overwrite:
        raise ResultsFileError(f"results file {path} not overwritten: {why}, or pass --overwrite")
    return path


def run_one(spec: DeviceSpec, want_hash: int | None, src: RunSource, pacing: Pacing, timeout_s: float,
            results: Path | None = None, overwrite: bool = False,
            progress: ProgressFactory = no_progress) -> dict[str, Any]:
    """Stream the flight of `src` through the device and return the run's summary (without a verdict).
    Long simulated flights are built and streamed in slices (not at radio level, nor with heights: those
    need the whole flight)."""
    radio = bool(src.radio or src.radio_trace)
    plan = None if (radio or src.height) else long_simulation(src)
    flight = make_run_flight(src) if plan is None else None
    with open_device(spec, expected_model_hash=want_hash) as device:
        ident = device.identity
        layouts = ident.layouts

        def checked_config(first: Flight) -> EstimatorConfig:
            cfg = source_config(src, first)
            kinds.check_network_present(kinds.kind_of(first.uwb.kind).network, cfg.stages, layouts, f"--stages {src.stages}")
            if not src.force:
                check_network_inputs(first, cfg, layouts)
            return cfg

        header = {"source": src.as_header(), "device": ident.as_dict()}
        streamer = Streamer(device, timeout_s=timeout_s)
        with _shown(progress, f"{flight.name if flight is not None else plan.name} ({src.stages})") as update:
            if plan is not None:
                from harness.stream.chunked_run import stream_plan
                chunked = stream_plan(streamer, plan, checked_config, pacing, results_path=results,
                                      header_extra=header, progress=update, overwrite=overwrite)
                run, flight = chunked.run, chunked.flight
            else:
                cfg = checked_config(flight)
                if results is not None:
                    from harness.stream.digest import flight_digest
                    header["flight_digest"] = flight_digest(flight)
                run = streamer.run(flight, cfg, pacing, results_path=results, progress=update,
                                   header_extra=header, overwrite=overwrite, radio=radio)
        return summarize_run(run, flight, ident, config=src.stages, radio_streamer=streamer if radio else None,
                             connection=device.connection(), flight_above=src.flight_above)


def resume_one(path: Path, device_spec: Callable[[RunSource], tuple[DeviceSpec, int | None]], timeout_s: float,
               progress: ProgressFactory = no_progress,
               check_source: Callable[[Mapping[str, Any], str], None] = lambda src, where: None) -> dict[str, Any]:
    """Continue the interrupted run recorded in `path`: the flight, configuration and pacing come from its
    header; `device_spec` gives the device (and the model hash it must carry) for the recorded source.
    Returns the summary over the whole flight, with `resume` = what the resume did. `check_source(source,
    where)` validates the header's source (the command line's types and bounds) before anything is built."""
    from harness.stream.resume import ResumeError, check_resumable, read_results, resume_run
    from harness.stream.results_file import LockedResults
    locked = LockedResults.existing(path)     # held until the resume is done
    try:
        rec = read_results(path)
        header_src = rec.header.get("source")
        if not isinstance(header_src, dict):
            raise ResumeError(f"{rec.path}:1: header has no 'source' (not written by `uwb-hil run`): "
                              "cannot rebuild the flight")
        if header_src.get("radio") or header_src.get("radio_trace"):
            raise ResumeError(f"{rec.path}: a radio-level run cannot be resumed (the tag's TDoA engine state "
                              "is not in the results file): run it again")
        # a header edited by hand passes the command line's schema and bounds before anything is built
        check_source(header_src, f"{rec.path}:1: header source")
        src = RunSource.from_mapping(header_src)
        plan = None if (src.radio or src.height) else long_simulation(src)
        if plan is not None:     # a long simulated flight: resumed in slices, as it was streamed
            from harness.stream.resume_sliced import check_plan
            check_plan(rec, plan)
            flight = None
        else:
            flight = make_flight(src)
            cfg = source_config(src, flight)
        spec, want_hash = device_spec(src)
        with open_device(spec, expected_model_hash=want_hash) as device:
            ident = device.identity
            with _shown(progress, f"{plan.name if plan else flight.name} (resume at {rec.next_index})") as update:
                if plan is not None:
                    from harness.stream.resume import check_device
                    from harness.stream.resume_sliced import resume_plan
                    check_device(rec, ident.as_dict())
                    run, flight, info = resume_plan(device, rec, plan, lambda first: source_config(src, first), locked,
                                                    timeout_s=timeout_s, progress=update)
                else:
                    check_resumable(rec, flight, cfg, ident.as_dict())
                    run, info = resume_run(device, rec, flight, locked, timeout_s=timeout_s, progress=update)
            summary = summarize_run(run, flight, ident, config=header_src.get("stages"),
                                    connection=device.connection(), flight_above=src.flight_above)
    finally:
        locked.close()
    summary["resume"] = info
    return summary
