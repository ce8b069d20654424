"""Every code block of ``README.md`` and ``docs/*.md`` runs as written (issue 39).

Per file, the blocks run in order in one folder and one namespace, as a reader pastes them:

* ``python`` blocks are executed; a block whose first line is ``# NAME.py`` is the file a reader saves under that
  name: it is written to the folder and imported there.
* ``bash`` blocks: every ``softreach`` command is parsed by the real command-line parser (each option, choice and
  model argument checked); the few in :data:`RUN` are also run, on the small grids given there. Other shell lines
  (installing, the test suite itself, the example and benchmark scripts, a shell loop around ``softreach``) must
  be in :data:`NOT_SOFTREACH`.
* a ``toml`` block whose first line is ``# NAME.toml: COMMAND`` is written to ``NAME.toml`` and loaded by the
  loader that ``COMMAND`` uses, and ``COMMAND`` is parsed as above.

What does not run, each named here: the long work (solving the full tables, training) in place of which the
snippets read small tables (:data:`TABLES`, copied to the names the snippets load); blocks marked
``<!-- excerpt of FILE ... -->``, pieces of a file that ``tests/test_examples.py`` matches against it and runs;
``json`` blocks, which show the shape of an output file; and blocks without a language (diagrams).
"""

from __future__ import annotations

import contextlib
import importlib
import io
import re
import shlex
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FILES = ["README.md"] + sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "docs").glob("*.md"))

#: the file names the snippets load -> the fixture (tests/conftest.py) with a small table of the same kind
TABLES = {"pointmass.srt": "pointmass_table_path", "pointmass-held.srt": "pointmass_held_table"}

#: ``(file, start of a softreach command)`` -> arguments appended: the commands run, not only parsed, because a
#: later block of the same file reads what they write; a solve gets a small grid
RUN = {
    ("docs/models.md", "softreach solve cart:Cart"): ["--grid", "15", "15", "--accuracy", "low", "--quiet"],
    ("docs/models.md", "softreach plot cart.srt"): [],
    # the cart's filter from its cells, on the table solved above
    ("docs/models.md", "softreach evaluate cart:Cart --policy random"): ["--episodes", "2", "--quiet"],
}

#: the shell lines that are not softreach commands, by their start (and the words of a shell loop, whole)
NOT_SOFTREACH = ("python3 -m venv ", ". .venv/bin/activate", "pip install ", "python -m pytest", "ray start",
                 "python examples/torch_reinforce.py ", "python benchmarks/", "for ")
LOOP_WORDS = ("do", "done")

EXCERPT = re.compile(r"<!-- excerpt of (\S+)")


@dataclass(frozen=True)
class Block:
    file: str
    line: int  # of the opening fence
    lang: str
    text: str
    excerpt_of: str | None  # the file a preceding ``<!-- excerpt of FILE -->`` names

    @property
    def where(self) -> str:
        return f"{self.file}:{self.line}"


def blocks(rel: str) -> list[Block]:
    """The fenced code blocks of a Markdown file, in order."""
    lines = (ROOT / rel).read_text().splitlines()
    out, i = [], 0
    while i < len(lines):
        m = re.match(r"^```(\S*)\s*$", lines[i])
        if not m:
            i += 1
            continue
        j = i + 1
        while j < len(lines) and not lines[j].startswith("```"):
            j += 1
        marker = EXCERPT.search(lines[i - 1]) if i else None
        out.append(Block(rel, i + 1, m.group(1), "\n".join(lines[i + 1:j]) + "\n", marker and marker.group(1)))
        i = j + 1
    return out


def shell_commands(text: str) -> list[str]:
    """The commands of a bash block: continuation lines joined, comments dropped, ``&&`` / ``;`` split, leading
    ``VAR=value`` assignments removed."""
    joined = re.sub(r"\s*\\\n\s*", " ", text)
    out = []
    for line in joined.splitlines():
        line = line.split(" #", 1)[0].strip() if not line.lstrip().startswith("#") else ""
        for part in re.split(r"&&|;", line):
            part = re.sub(r"^(\w+=\S*\s+)+", "", part.strip())
            if part:
                out.append(part)
    return out


def softreach_argv(command: str, previous: dict[str, list[str]]) -> list[str]:
    """The arguments of a ``softreach`` command line: shell substitutions (``$p``, ``$(...)``) become one word; an
    elided ``softreach CMD ... REST`` stands for the file's last full ``softreach CMD`` command followed by REST."""
    while re.search(r"\$\([^()]*\)", command):
        command = re.sub(r"\$\([^()]*\)", "X", command)
    command = re.sub(r"\$\w+", "X", command)
    argv = shlex.split(command)[1:]
    if len(argv) > 1 and argv[1] == "...":
        assert argv[0] in previous, f"'softreach {argv[0]} ...' elides a command that the file does not give in full"
        return previous[argv[0]] + argv[2:]
    previous[argv[0]] = argv
    return argv


def check_softreach(command: str, block: Block, previous: dict[str, list[str]]) -> None:
    """Parse a softreach command with the real parser; run it where :data:`RUN` says so."""
    from softreach.cli import build_parser, main

    argv = softreach_argv(command, previous)
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            build_parser().parse_args(argv)
    except SystemExit as exc:
        assert exc.code == 0, f"{block.where}: `{command}` does not parse: {err.getvalue().strip()}"
    extra = next((v for (f, start), v in RUN.items() if f == block.file and command.startswith(start)), None)
    if extra is not None:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            rc = main(argv + extra)
        assert rc == 0, f"{block.where}: `{command}` failed: {err.getvalue().strip()}"


def check_toml(block: Block) -> None:
    """A sweep grid file: written under its name, loaded by the sweep's loader, its command parsed."""
    from softreach.agents.sweep import load_sweep_file

    first = block.text.splitlines()[0]
    m = re.match(r"#\s*(\S+\.toml):\s*(softreach .*)$", first)
    assert m, f"{block.where}: a toml block starts with '# NAME.toml: softreach COMMAND', got {first!r}"
    Path(m.group(1)).write_text(block.text)
    load_sweep_file(m.group(1))
    check_softreach(m.group(2), block, {})


def run_file(rel: str) -> list[str]:
    """Run every block of ``rel`` in the current folder; return what was not run, one line each."""
    namespace: dict = {"__name__": "__snippet__"}
    previous: dict[str, list[str]] = {}
    skipped = []
    for block in blocks(rel):
        start = time.perf_counter()
        run_block(block, namespace, previous, skipped)
        print(f"{block.where}: {block.lang or 'plain'} block, {time.perf_counter() - start:.1f} s")
    return skipped


def run_block(block: Block, namespace: dict, previous: dict[str, list[str]], skipped: list[str]) -> None:
    """Run one block (:func:`run_file`), appending what is not run to ``skipped``."""
    if block.lang == "python":
        first = block.text.splitlines()[0] if block.text.strip() else ""
        name = re.fullmatch(r"#\s*(\w+)\.py", first.strip())
        if block.excerpt_of:
            assert (ROOT / block.excerpt_of).is_file(), f"{block.where}: excerpt of a missing {block.excerpt_of}"
            skipped.append(f"{block.where}: excerpt of {block.excerpt_of} (tests/test_examples.py)")
        elif name:
            Path(f"{name.group(1)}.py").write_text(block.text)
            sys.modules.pop(name.group(1), None)
            importlib.import_module(name.group(1))
        else:
            exec(compile(block.text, block.where, "exec"), namespace)
    elif block.lang == "bash":
        for command in shell_commands(block.text):
            if command.startswith("softreach "):
                check_softreach(command, block, previous)
            else:
                assert command.startswith(NOT_SOFTREACH) or command in LOOP_WORDS, (
                    f"{block.where}: `{command}` is neither a softreach command nor a known shell line")
                skipped.append(f"{block.where}: shell line `{command[:40]}`")
    elif block.lang == "toml":
        check_toml(block)
    elif block.lang in ("json", ""):
        skipped.append(f"{block.where}: {block.lang or 'plain'} block (an output's shape or a diagram)")
    else:
        raise AssertionError(f"{block.where}: a ```{block.lang} block; this test runs python, bash and toml")


@pytest.mark.parametrize("rel", FILES)
def test_code_blocks_run_as_written(rel, tmp_path, monkeypatch, request):
    code = "".join(b.text for b in blocks(rel) if b.lang == "python")
    for name, fixture in TABLES.items():
        if f'"{name}"' in code:  # a snippet loads it
            value = request.getfixturevalue(fixture)
            shutil.copyfile(getattr(value, "path", value), tmp_path / name)
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))  # `python` run from this folder finds the files saved here
    modules = set(sys.modules)
    try:
        skipped = run_file(rel)
    finally:
        for name in set(sys.modules) - modules:
            if getattr(sys.modules[name], "__file__", None) and str(tmp_path) in sys.modules[name].__file__:
                del sys.modules[name]
    print(f"{rel}: not run:", *skipped, sep="\n  ")


def test_the_block_reader_finds_what_a_reader_sees(tmp_path):
    """The parser of this test: fences, excerpt markers, continuation lines, elisions and substitutions."""
    assert [b.lang for b in blocks("README.md")].count("python") >= 1
    assert any(b.excerpt_of == "examples/torch_reinforce.py" for b in blocks("docs/agents.md"))
    assert shell_commands("OMP_NUM_THREADS=1 softreach solve a \\\n   --grid 5 5  # note\n# only\nx && y; z\n") == [
        "softreach solve a --grid 5 5", "x", "y", "z"]
    previous: dict[str, list[str]] = {}
    assert softreach_argv("softreach sweep --table t.srt --seeds 0", previous) == ["sweep", "--table", "t.srt",
                                                                                  "--seeds", "0"]
    assert softreach_argv("softreach sweep ... --workers 2", previous)[-2:] == ["--workers", "2"]
    assert softreach_argv("softreach demo --policy $p --out r_$(basename $(dirname $p))", {}) == [
        "demo", "--policy", "X", "--out", "r_X"]
    block = Block("x.md", 1, "bash", "softreach solve pointmass --no-such-option\n", None)
    with pytest.raises(AssertionError, match="does not parse"):
        check_softreach("softreach solve pointmass --no-such-option", block, {})
