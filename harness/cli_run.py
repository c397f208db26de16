"""Command-line helpers of `uwb-hil run` (CLI side, as cli_verdict.py): which options were typed, a results
header's source checked with the `run` options' own types and bounds, the help formatter that shows every
default, `--version`, and how warnings reach the user."""

from __future__ import annotations

import argparse
import sys
from typing import Any, Mapping, Sequence

from harness.errors import ResultsFileError


def given_dests(parser: argparse.ArgumentParser, argv: Sequence[str]) -> set[str]:
    """The destinations of the options typed in `argv` (a value equal to the default counts as given; an
    abbreviation, as argparse accepts it, too)."""
    flags = {s: a.dest for a in parser._actions for s in a.option_strings}
    out: set[str] = set()
    for token in argv:
        if token == "--":
            break
        if not token.startswith("--"):
            continue
        name = token.split("=", 1)[0]
        hits = {dest for flag, dest in flags.items() if flag == name} or \
            {dest for flag, dest in flags.items() if flag.startswith(name)}
        if len(hits) == 1:
            out |= hits
    return out


def check_header_source(run_parser: argparse.ArgumentParser, keys: Sequence[str], src: Mapping[str, Any],
                        where: str) -> None:
    """A results header's source through the `run` options' own types, choices and bounds (a header edited
    by hand: `duration 20000` is refused as `--duration 20000` is, before any flight is built)."""
    actions = {a.dest: a for a in run_parser._actions if a.option_strings}
    for key in keys:
        value, action = src.get(key), actions.get(key)
        if value is None or action is None:
            continue
        flag = action.option_strings[-1]
        if action.nargs == 0:                    # a switch: true or false
            if not isinstance(value, bool):
                raise ResultsFileError(f"{where} {key} = {str(value)[:100]!r}: {flag} is a switch, expected true or false")
            continue
        many = isinstance(action, argparse._AppendAction)
        if isinstance(value, tuple):                       # as RunSource.as_header gives it (JSON: a list)
            value = list(value)
        if not many and isinstance(value, list) and value and \
                all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            value = ",".join(str(v) for v in value)          # a tuple option (--lever-arm x,y,z)
        if many != isinstance(value, list) or any(isinstance(v, (dict, list, bool)) for v in
                                                   (value if many else [value])):
            raise ResultsFileError(f"{where} {key} = {str(value)[:100]!r}: not a value {flag} takes")
        for v in (value if many else [value]):
            _check_option_value(action, flag, v, f"{where} {key}")


#: longest option value a results header may hold (paths, --set items)
MAX_HEADER_VALUE = 4096


def _check_option_value(action: argparse.Action, flag: str, value: Any, where: str) -> None:
    text = str(value)
    if len(text) > MAX_HEADER_VALUE:
        raise ResultsFileError(f"{where} = {text[:100]!r}...: too long ({len(text)} characters, at most {MAX_HEADER_VALUE})")
    try:
        parsed = action.type(text) if callable(action.type) else text
    except (argparse.ArgumentTypeError, ValueError) as exc:
        raise ResultsFileError(f"{where} = {text[:100]!r}: {flag} {exc}") from None
    if action.choices is not None and parsed not in action.choices:
        raise ResultsFileError(f"{where} = {text[:100]!r}: {flag} must be one of {', '.join(map(str, action.choices))}")


class HelpFormatter(argparse.HelpFormatter):
    """Every option's default in its help, unless the text already names it."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if "default" in text or default in (None, False, [], argparse.SUPPRESS) or not action.option_strings:
            return text
        return text + " (default: %(default)s)"


class RawDescriptionHelpFormatter(HelpFormatter, argparse.RawDescriptionHelpFormatter):
    """HelpFormatter that keeps the description's own line breaks (a command's examples)."""


def version_text() -> str:
    """`uwb-hil --version`: the package, the protocol and the firmware sources it carries."""
    from importlib.metadata import PackageNotFoundError, version
    from harness.firmware_cache import firmware_source_version
    from protocol import PROTOCOL_VERSION
    try:
        package = version("uwb-hil")
    except PackageNotFoundError:
        package = "not installed"
    return f"uwb-hil {package}, protocol {PROTOCOL_VERSION}, firmware {firmware_source_version()}"


class VersionAction(argparse.Action):
    """--version, computed only when asked (the metadata and firmware header are read then)."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS, **kw: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kw)

    def __call__(self, parser: argparse.ArgumentParser, *args: Any) -> None:
        print(version_text())
        parser.exit()


def subparser(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser:
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[name]


def show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                  file: Any = None, line: str | None = None) -> None:
    """Warnings for the user (a recording's dropped last line, ...): one line, no source location."""
    print(f"uwb-hil: warning: {message}", file=sys.stderr)
