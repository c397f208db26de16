"""Code shape: no source file over 400 lines and no function over 60, in the product and its tests.

Covered: every Python file under harness/, protocol/, tests/, firmware_sim/ and scripts/ (functions measured
with ast: `end_lineno - lineno + 1`, the `def` line through the last line of the body, decorators not counted),
and every C source and header under firmware_sim/ (functions measured by a brace-depth scan of the text with
comments, string and character literals and preprocessor lines blanked out: from the line that names the
function through its closing brace). Build output (any `build/` folder) and caches are not read.

Exempt: the generated files listed in GENERATED (each must say it is generated and not to be edited).
The C scan does not evaluate #if blocks: code whose braces only balance per preprocessor branch is reported
as unbalanced (none is today).
"""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass
from fnmatch import fnmatch
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MAX_FILE_LINES = 400
MAX_FUNCTION_LINES = 60
PY_ROOTS = ("harness", "protocol", "tests", "firmware_sim", "scripts")
C_ROOTS = ("firmware_sim",)
SKIP_DIRS = frozenset({"build", ".venv", "__pycache__", ".pytest_cache"})

# Written by a generator (protocol/generate.py, `uwb-hil export-c`), never by hand.
GENERATED = (
    "protocol/_generated.py",
    "firmware_sim/proto/uwb_msgs.c",
    "firmware_sim/proto/uwb_msgs.h",
    "firmware_sim/tests/uwb_msgs_format.h",
    "firmware_sim/models/*bias_model*.h",
)


@dataclass(frozen=True)
class Function:
    name: str
    first_line: int
    last_line: int

    @property
    def length(self) -> int:
        return self.last_line - self.first_line + 1


def _generated(rel: str) -> bool:
    return any(fnmatch(rel, pattern) for pattern in GENERATED)


def _files(roots: tuple[str, ...], suffixes: tuple[str, ...]) -> list[Path]:
    found: list[Path] = []
    for root in roots:
        for path in sorted((ROOT / root).rglob("*")):
            rel = path.relative_to(ROOT)
            if path.suffix in suffixes and path.is_file() and not SKIP_DIRS.intersection(rel.parts[:-1]):
                found.append(path)
    return found


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


# --- Python ---------------------------------------------------------------------------------------------------


def python_functions(source: str) -> list[Function]:
    """Every def / async def, nested ones included, named by its qualified path (Class.method, outer.inner)."""
    found: list[Function] = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = prefix + child.name
                found.append(Function(name, child.lineno, child.end_lineno or child.lineno))
                visit(child, name + ".")
            elif isinstance(child, ast.ClassDef):
                visit(child, prefix + child.name + ".")
            else:
                visit(child, prefix)

    visit(ast.parse(source), "")
    return found


# --- C --------------------------------------------------------------------------------------------------------

_C_TOKENS = re.compile(
    r"""/\*.*?\*/           # block comment
      | //[^\n]*            # line comment
      | "(?:\\.|[^"\\\n])*" # string literal
      | '(?:\\.|[^'\\\n])*' # character literal
    """,
    re.S | re.X,
)
_PREPROCESSOR = re.compile(r"^[ \t]*#(?:[^\n]*\\\n)*[^\n]*", re.M)
_NAME_BEFORE_PAREN = re.compile(r"([A-Za-z_]\w*)\s*$")


def _blank(match: re.Match[str]) -> str:
    """The match as spaces, keeping its newlines so that line numbers stay true."""
    return re.sub(r"[^\n]", " ", match.group(0))


def strip_c(source: str) -> str:
    """The source with comments, string and char literals and preprocessor lines (continuations included)
    replaced by blanks, line for line, so that only code braces and parentheses remain."""
    code = _C_TOKENS.sub(_blank, source)
    return _PREPROCESSOR.sub(_blank, code)


def _function_name(head: str) -> tuple[str, int] | None:
    """For the code between the previous top-level `;`/`}` and a top-level `{`: the function's name and its
    offset in `head` when it is a definition `... name(params) {`, else None (struct, enum, initialiser)."""
    text = head.rstrip()
    if not text.endswith(")") or "=" in text:
        return None
    depth = 0
    for i in range(len(text) - 1, -1, -1):
        depth += {")": 1, "(": -1}.get(text[i], 0)
        if depth == 0:
            name = _NAME_BEFORE_PAREN.search(text[:i])
            return (name.group(1), name.start(1)) if name else None
    return None


def c_functions(source: str) -> list[Function]:
    """Top-level function definitions, from the line that names the function to the line of its closing brace."""
    code = strip_c(source)
    found: list[Function] = []
    depth, head_start, opened = 0, 0, None
    for i, ch in enumerate(code):
        if ch == "{":
            if depth == 0:
                named = _function_name(code[head_start:i])
                opened = (named[0], code.count("\n", 0, head_start + named[1]) + 1) if named else None
            depth += 1
        elif ch == "}":
            depth -= 1
            if depth < 0:
                raise ValueError(f"unbalanced '}}' at line {code.count(chr(10), 0, i) + 1}")
            if depth == 0:
                if opened is not None:
                    found.append(Function(opened[0], opened[1], code.count("\n", 0, i) + 1))
                opened, head_start = None, i + 1
        elif ch == ";" and depth == 0:
            head_start = i + 1
    if depth != 0:
        raise ValueError("unbalanced braces at end of file")
    return found


# --- the rule -------------------------------------------------------------------------------------------------


def _checked(roots: tuple[str, ...], suffixes: tuple[str, ...]) -> list[Path]:
    return [p for p in _files(roots, suffixes) if not _generated(_rel(p))]


PY_FILES = _checked(PY_ROOTS, (".py",))
C_FILES = _checked(C_ROOTS, (".c", ".h"))


def _too_long_functions(path: Path, functions: list[Function]) -> list[str]:
    return [
        f"{_rel(path)}:{f.first_line} {f.name}() is {f.length} lines (at most {MAX_FUNCTION_LINES})"
        for f in functions
        if f.length > MAX_FUNCTION_LINES
    ]


def test_files_at_most_400_lines() -> None:
    too_long = []
    for path in PY_FILES + C_FILES:
        lines = len(path.read_text(encoding="utf-8").splitlines())
        if lines > MAX_FILE_LINES:
            too_long.append(f"{_rel(path)} is {lines} lines (at most {MAX_FILE_LINES})")
    assert not too_long, "files too long:\n" + "\n".join(too_long)


def test_python_functions_at_most_60_lines() -> None:
    too_long = []
    for path in PY_FILES:
        too_long += _too_long_functions(path, python_functions(path.read_text(encoding="utf-8")))
    assert not too_long, "functions too long:\n" + "\n".join(too_long)


def test_c_functions_at_most_60_lines() -> None:
    too_long = []
    for path in C_FILES:
        too_long += _too_long_functions(path, c_functions(path.read_text(encoding="utf-8")))
    assert not too_long, "functions too long:\n" + "\n".join(too_long)


def test_exemptions_are_generated_files_that_exist() -> None:
    """Every GENERATED pattern matches a file that says it is generated, so the list cannot hide hand code."""
    for pattern in GENERATED:
        matches = [p for p in _files(PY_ROOTS + C_ROOTS, (".py", ".c", ".h")) if fnmatch(_rel(p), pattern)]
        assert matches, f"exempt pattern {pattern} matches no file"
        for path in matches:
            head = path.read_text(encoding="utf-8")[:300].lower()
            assert "generated" in head and "do not edit" in head, f"{_rel(path)} is exempt but not marked generated"


# --- the scanners themselves ----------------------------------------------------------------------------------

C_SAMPLE = """\
#include <stdio.h>
#define BLOCK(x) do { if (x) { \\
    puts("}"); } } while (0)
/* a comment with { braces } and f(void) { */
typedef struct { int a; } pair_t;
static const int table[2] = { 1, 2 };
static int add(int a,
               int b)
{
    const char *s = "{ not a brace }";  // nor this {
    char c = '}';
    (void)s; (void)c;
    return a + b;
}
enum colour { RED, GREEN };
int main(void) {
    BLOCK(1);
    if (add(1, 2) == 3) {
        return 0;
    }
    return 1;
}
"""


def test_c_scan_finds_definitions_only() -> None:
    functions = c_functions(C_SAMPLE)
    assert [(f.name, f.first_line, f.last_line) for f in functions] == [("add", 7, 14), ("main", 16, 22)]
    assert functions[0].length == 8


def test_c_scan_refuses_unbalanced_braces() -> None:
    with pytest.raises(ValueError, match="unbalanced"):
        c_functions("int f(void) { if (1) { return 0; }\n")


def test_python_scan_names_methods_and_nested_functions() -> None:
    source = ("class A:\n    def m(self):\n        def inner():\n            pass\n        return 1\n\n\n"
              "def g():\n    pass\n")
    found = [(f.name, f.length) for f in python_functions(source)]
    assert found == [("A.m", 4), ("A.m.inner", 2), ("g", 2)]


def test_failure_message_names_file_function_and_length() -> None:
    message = _too_long_functions(ROOT / "harness" / "x.py", [Function("big", 10, 80)])
    assert message == ["harness/x.py:10 big() is 71 lines (at most 60)"]


def test_a_61_line_function_is_reported_and_a_60_line_one_is_not() -> None:
    def python(n: int) -> str:
        return "def f():\n" + "    x = 1\n" * (n - 2) + "    return x\n"

    def c(n: int) -> str:
        return "int f(void)\n{\n" + "    int x = 1;\n" * (n - 4) + "    return x;\n}\n"

    path = ROOT / "harness" / "x.py"
    assert _too_long_functions(path, python_functions(python(60))) == []
    assert _too_long_functions(path, python_functions(python(61))) == ["harness/x.py:1 f() is 61 lines (at most 60)"]
    assert [f.length for f in c_functions(c(60))] == [60]
    assert _too_long_functions(path, c_functions(c(61))) == ["harness/x.py:1 f() is 61 lines (at most 60)"]
