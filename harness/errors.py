"""Exceptions of the uwb-hil harness, and the exit code each family means.

Every error the harness raises on purpose is a UwbHilError:
  InputError   bad input from the user (options, data files, results files, campaign directories): exit 2;
  LinkError    the byte transport failed (pty, UART, TCP): closed, or a write could not make progress: exit 3;
  DeviceError  the device misbehaved: died, went silent, or is not the firmware we expected: exit 3.
Anything else that reaches a command is a bug of the harness: exit 4 (harness/cli.py writes its traceback
to a file and says where).

Every exception takes a plain message as its first argument (so `raise DeviceTimeout("...")` works);
the structured details are keyword-only and kept as attributes for reports.
"""

from __future__ import annotations

from pathlib import Path


class UwbHilError(Exception):
    """Base of every error the harness raises on purpose."""


# ------------------------------------------------------------------------------------------ input
class InputError(UwbHilError, ValueError):
    """Bad input from the user: an option, a data file, a results file (CLI exit code 2)."""


class InputFileNotFound(InputError, FileNotFoundError):
    """A file the user named (recording, anchors, model, results file, firmware) does not exist."""


class UsageError(InputError):
    """Options that contradict each other or are out of range."""


class ResultsFileError(InputError):
    """A results file cannot be written, is in use, or would be overwritten / resumed unsafely."""


# ------------------------------------------------------------------------------------------- link
class LinkError(UwbHilError):
    """The byte transport failed."""


class LinkClosed(LinkError):
    """The other end is gone: EOF, or EIO on a pty master (the last slave fd was closed)."""


class LinkTimeout(LinkError):
    """A write made no progress within its time limit (the peer stopped reading)."""

    def __init__(self, message: str, *, pending_bytes: int | None = None, waited_s: float | None = None) -> None:
        super().__init__(message)
        self.pending_bytes = pending_bytes
        self.waited_s = waited_s


# ----------------------------------------------------------------------------------------- device
class DeviceError(UwbHilError):
    """The device misbehaved or is not what the test expects."""


class DeviceDied(DeviceError):
    """The device process exited. Carries its exit code and the tail of its log."""

    def __init__(self, message: str, *, exit_code: int | None = None, log_tail: str = "",
                 log_path: Path | None = None) -> None:
        self.message = message          # without the details appended below (a wrapper names its own context)
        self.exit_code = exit_code
        self.log_tail = log_tail
        self.log_path = log_path
        text = message
        if exit_code is not None:
            text += f" (exit code {exit_code}{_signal_note(exit_code)})"
        if log_path is not None:
            text += f"; log: {log_path}"
        if log_tail:
            text += "\n--- last lines of the device log ---\n" + log_tail.rstrip("\n")
        super().__init__(text)


class DeviceTimeout(DeviceError):
    """The device is alive but did not answer a request in time."""

    def __init__(self, message: str, *, request: str | None = None, waited_s: float | None = None) -> None:
        super().__init__(message)
        self.request = request
        self.waited_s = waited_s

    @classmethod
    def for_request(cls, request: str, waited_s: float, detail: str = "") -> DeviceTimeout:
        text = f"device did not answer {request} within {waited_s:.2f} s"
        if detail:
            text += f" ({detail})"
        return cls(text, request=request, waited_s=waited_s)


class ProtocolMismatch(DeviceError):
    """The device speaks another protocol version than this harness."""

    def __init__(self, message: str, *, expected: int | None = None, actual: int | None = None) -> None:
        super().__init__(message)
        self.expected = expected
        self.actual = actual

    @classmethod
    def versions(cls, expected: int, actual: int) -> ProtocolMismatch:
        return cls(f"protocol version mismatch: the harness speaks version {expected}, the device "
                   f"reports {actual}; rebuild the firmware from this tree (or update the harness)",
                   expected=expected, actual=actual)


class ModelMismatch(DeviceError):
    """The device's compiled-in bias networks are not the expected ones."""

    def __init__(self, message: str, *, expected_hash: int | None = None, actual_hash: int | None = None,
                 layouts: tuple[int, int] | None = None,
                 expected_layouts: tuple[int, int] | None = None) -> None:
        super().__init__(message)
        self.expected_hash = expected_hash
        self.actual_hash = actual_hash
        self.layouts = layouts
        self.expected_layouts = expected_layouts

    @classmethod
    def hashes(cls, expected_hash: int | None, actual_hash: int, layouts: tuple[int, int],
               expected_layouts: tuple[int, int] | None = None) -> ModelMismatch:
        parts = []
        if expected_hash is not None and expected_hash != actual_hash:
            parts.append(f"model hash: expected {expected_hash:#018x}, device has {actual_hash:#018x}")
        if expected_layouts is not None and tuple(expected_layouts) != tuple(layouts):
            parts.append(f"layouts (twr, tdoa): expected {_layouts(expected_layouts)}, device has {_layouts(layouts)}")
        text = "bias model mismatch: " + "; ".join(parts or ["(no difference given)"])
        text += f" [device layouts {_layouts(layouts)}, model hash {actual_hash:#018x}]"
        return cls(text, expected_hash=expected_hash, actual_hash=actual_hash, layouts=layouts,
                   expected_layouts=expected_layouts)


def _signal_note(exit_code: int) -> str:
    if exit_code >= 0:
        return ""
    import signal

    try:
        return f", killed by {signal.Signals(-exit_code).name}"
    except ValueError:
        return f", killed by signal {-exit_code}"


def _layouts(layouts: tuple[int, int]) -> str:
    try:
        from protocol.messages import Layout

        names = []
        for value in layouts:
            try:
                names.append(Layout(value).name)
            except ValueError:
                names.append(str(value))
        return f"({names[0]}, {names[1]})"
    except ImportError:  # pragma: no cover - the protocol package is part of this repository
        return str(tuple(layouts))


#: exit codes of every command (README "Reading a report", `uwb-hil --help`): 0 pass, 1 verdict failed, then by
#: error family
EXIT_PASS, EXIT_VERDICT, EXIT_INPUT, EXIT_DEVICE, EXIT_BUG = 0, 1, 2, 3, 4


def exit_code(exc: BaseException) -> int:
    """The exit code of a run that ended in `exc`: 3 for a device or link failure, 2 for an input error (and
    an OSError on a file the user named: a full disk, no permission), 4 for anything else: a bug. Every
    command and `python -m` tool maps its errors through this."""
    if isinstance(exc, (DeviceError, LinkError)):
        return EXIT_DEVICE
    if isinstance(exc, (UwbHilError, OSError)):
        return EXIT_INPUT
    return EXIT_BUG


def report_failure(exc: BaseException, prog: str, bug_dir: Path | None = None) -> int:
    """Say on one line (stderr) why a command ended in `exc` and return its exit code: the message of an
    input, device or link error; for anything else (a bug of the harness, exit 4) the exception's type and
    message, and the path of a file that holds its traceback (in `bug_dir`, default the temp directory)."""
    import sys

    code = exit_code(exc)
    if code != EXIT_BUG:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return code
    import tempfile
    import time
    import traceback

    text = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    try:
        directory = Path(bug_dir) if bug_dir is not None else Path(tempfile.gettempdir())
        fd, name = tempfile.mkstemp(prefix=f"uwb-hil-bug-{time.strftime('%Y%m%d-%H%M%S')}-", suffix=".txt",
                                    dir=directory)
        with open(fd, "w", encoding="utf-8") as fh:
            fh.write(f"{prog}: {' '.join(sys.argv)}\n{text}")
        where = f"traceback written to {name}"
    except OSError as write_exc:
        where = f"traceback not written ({write_exc.strerror or write_exc})"
    first = (str(exc).splitlines() or [""])[0]
    print(f"{prog}: internal error (a bug in uwb-hil, not in your input): {type(exc).__name__}: {first}; "
          f"{where}; please report it", file=sys.stderr)
    return code
