"""The project documents itself: no file points outside the repository (except to the
measured data, which we may not copy), and every relative link in the Markdown resolves."""

from __future__ import annotations

import itertools
import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: the only thing outside the repository a file may name: the measured dyno data
ALLOWED_OUTSIDE = "shared/data/measured"
#: Markdown link targets: ``[text](target)``, without the scheme-qualified ones
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def _tracked() -> list[Path]:
    try:
        out = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True,
                             check=True).stdout.split()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return [REPO / f for f in out if (REPO / f).is_file()]


def _text(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8")
    except (UnicodeDecodeError, OSError):
        return None          # binary (plots, bags)


def test_no_file_refers_to_documents_outside_the_repository():
    bad = []
    for path in _tracked():
        text = _text(path)
        if text is None or path == Path(__file__):
            continue
        for n, line in enumerate(text.splitlines(), 1):
            outside = "shared/" in line or '"shared"' in line
            measured = ALLOWED_OUTSIDE in line or '"shared" / "data" / "measured"' in line
            if (outside and not measured) or re.search(r"\b(MODEL|CONTRACT)\.md\b", line):
                bad.append(f"{path.relative_to(REPO)}:{n}: {line.strip()}")
    assert not bad, "\n".join(bad)


def test_every_relative_markdown_link_resolves():
    bad = []
    for path in _tracked():
        if path.suffix != ".md":
            continue
        for target in LINK.findall(_text(path) or ""):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue
            file_part = target.split("#", 1)[0]
            if not (path.parent / file_part).exists():
                bad.append(f"{path.relative_to(REPO)}: {target}")
    assert not bad, "\n".join(bad)


def test_the_model_and_interface_documents_cover_what_the_code_cites():
    """Every ``docs/model.md §N`` a file cites exists as a heading of docs/model.md."""
    model = (REPO / "docs" / "model.md").read_text(encoding="utf-8")
    headings = set(re.findall(r"^#+ (\d+(?:\.\d+)?)\.? ", model, flags=re.M))
    interfaces = (REPO / "docs" / "interfaces.md").read_text(encoding="utf-8")
    iface_headings = set(re.findall(r"^#+ (\d+)\. ", interfaces, flags=re.M))
    bad = []
    for path in _tracked():
        text = _text(path) or ""
        for doc, sec in re.findall(r"(model|interfaces)\.md`*,? §(\d+(?:\.\d+)?)", text):
            if sec not in (headings if doc == "model" else iface_headings):
                bad.append(f"{path.relative_to(REPO)}: {doc}.md §{sec}")
    assert headings and iface_headings
    assert not bad, "\n".join(bad)


def test_the_parameter_reference_is_generated_from_the_schema():
    from damper_hil import param_reference

    assert param_reference.main(["--check"]) == 0, (
        "docs/parameters.md is out of date: python -m damper_hil.param_reference")


def test_every_number_in_the_schema_states_its_unit_and_rule():
    from damper_emulator.params import field_specs
    from damper_hil.param_reference import _groups

    missing = [s.key for group, _, _, cls, _ in _groups() for s in field_specs(cls, group)
               if s.type in ("double", "double_array") and not s.unit]
    assert not missing, missing
    # every spec says what its rule is (none falls through to a bare type)
    assert all(s.constraint for group, _, _, cls, _ in _groups()
               for s in field_specs(cls, group))


def test_the_pre_commit_hooks_run_what_make_test_runs():
    """``.pre-commit-config.yaml`` runs the linter and the type checker ``make test`` runs,
    with the same arguments (their settings live in pyproject.toml for both)."""
    import yaml

    config = yaml.safe_load((REPO / ".pre-commit-config.yaml").read_text(encoding="utf-8"))
    hooks = {h["id"]: h for repo in config["repos"] for h in repo["hooks"]}
    makefile = (REPO / "Makefile").read_text(encoding="utf-8")
    # make test runs the lint target first
    assert " lint " in makefile.split("\ntest:", 1)[1].splitlines()[1]
    recipe = makefile.split("\nlint:", 1)[1]
    made = [line.strip().replace("$(BIN)", ".venv/bin") for line in recipe.splitlines()[1:3]]
    # make test lints the whole tree (ruff check .); the hook gets the changed files
    assert made == [hooks["ruff"]["entry"] + " .", hooks["mypy"]["entry"]]
    assert hooks["mypy"]["pass_filenames"] is False


def _benchmark_driver():
    """``benchmarks/run_all.py`` as a module (it imports ``machine`` from its directory)."""
    import importlib.util
    import sys

    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        spec = importlib.util.spec_from_file_location("run_all",
                                                      REPO / "benchmarks/run_all.py")
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(REPO / "benchmarks"))
    return module


def test_make_bench_runs_every_benchmark_into_its_section_of_the_performance_page():
    """Every ``benchmarks/*_bench.py`` is one the driver runs (``make bench`` or by name),
    ``make bench`` calls the driver with the page, and the page holds a section per
    benchmark for the driver to rewrite."""
    run_all = _benchmark_driver()
    scripts = {p.stem for p in (REPO / "benchmarks").glob("*_bench.py")}
    assert scripts == set(run_all.BENCHMARKS) | set(run_all.BY_NAME_ONLY)
    recipe = (REPO / "Makefile").read_text(encoding="utf-8").split("\nbench:", 1)[1]
    assert "benchmarks/run_all.py --doc docs/performance.md" in recipe.split("\n\n", 1)[0]
    page = (REPO / "docs/performance.md").read_text(encoding="utf-8")
    for name in [*scripts, "machine"]:
        begin, end = run_all.markers(name)
        assert page.count(begin) == 1 and page.count(end) == 1, name
        assert page.index(begin) < page.index(end), name


def test_the_benchmark_driver_rewrites_a_section_and_keeps_the_rest(tmp_path):
    """A section written twice holds only the second text; text around it stays; a missing
    section is added at the end."""
    run_all = _benchmark_driver()
    page = tmp_path / "p.md"
    page.write_text("intro\n\n<!-- a -->\nold\n<!-- /a -->\n\ntail\n", encoding="utf-8")
    run_all.write_section(page, "a", "first")
    run_all.write_section(page, "a", "second\n")
    run_all.write_section(page, "b", "new")
    assert page.read_text(encoding="utf-8") == (
        "intro\n\n<!-- a -->\nsecond\n<!-- /a -->\n\ntail\n\n<!-- b -->\nnew\n<!-- /b -->\n\n")


# ------------------------------------------------------------------------------------------
# The command lines of the README and docs parse with the command line's own parser

#: fence languages whose lines are commands (```text holds usage synopses and output)
SHELL_FENCES = {"", "sh", "bash", "shell", "console"}
#: a variable set in a block (``BUS="--can-interface ..."``), used by later lines
ASSIGNMENT = re.compile(r"^([A-Z_][A-Z0-9_]*)=(.*)$")
#: words that end one command of a line and start the next
SEPARATORS = ("&&", "||", ";", "|")


def _shell_blocks(text: str) -> list[list[tuple[int, str]]]:
    """The shell blocks of a Markdown text, each its (line number, line) pairs: fenced
    blocks of :data:`SHELL_FENCES`, and indented blocks outside fences (only their
    command lines: a list item's indented paragraphs are text)."""
    blocks: list[list[tuple[int, str]]] = []
    fence: str | None = None
    indented: list[tuple[int, str]] = []
    for number, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if fence is None and stripped.startswith("```"):
            fence = stripped[3:].strip()
            blocks.append([])
            continue
        if fence is not None:
            if stripped.startswith("```"):
                if fence not in SHELL_FENCES:
                    blocks.pop()
                fence = None
            else:
                blocks[-1].append((number, line))
            continue
        continued = bool(indented) and indented[-1][1].rstrip().endswith("\\")
        if line.startswith("    ") and (continued or stripped.split(" ")[0].endswith(
                "damper-hil")):
            indented.append((number, line))
        elif indented:
            blocks.append(indented)
            indented = []
    if indented:
        blocks.append(indented)
    return blocks


def documented_commands() -> list[tuple[str, list[str], int]]:
    """Every ``damper-hil …`` command line of README.md and docs/ as ``(file:line,
    arguments after damper-hil, number of its block)``: continuation lines joined,
    comments and a trailing ``&`` dropped, the block's variables expanded as the shell
    would."""
    import shlex

    found = []
    blocks = [(path, block)
              for path in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
              for block in _shell_blocks(path.read_text(encoding="utf-8"))]
    for block_number, (path, block) in enumerate(blocks):
        variables: dict[str, list[str]] = {}
        lines = iter(block)
        for number, line in lines:
            text = line.strip().removeprefix("$ ")
            while text.endswith("\\"):
                following = next(lines, None)
                assert following is not None, f"{path.name}:{number}: a block ends in \\"
                text = text[:-1] + " " + following[1].strip()
            words = shlex.split(text, comments=True)
            assignment = ASSIGNMENT.match(text)
            if assignment and len(words) == 1:
                # an unquoted $NAME splits into words at blanks
                variables[assignment[1]] = " ".join(
                    shlex.split(assignment[2], comments=True)).split()
                continue
            expanded: list[str] = []
            for word in words:
                name = word[1:].strip("{}") if word.startswith("$") else None
                expanded.extend(variables.get(name, [word]))
            # each command of the line (cd x && damper-hil ...), past VAR=1 prefixes
            command: list[str] = []
            for word in [*expanded, ";"]:
                if word not in SEPARATORS and word != "&":
                    command.append(word)
                    continue
                while command and ASSIGNMENT.match(command[0]):
                    command.pop(0)
                if command and command[0].endswith("damper-hil"):
                    found.append((f"{path.relative_to(REPO)}:{number}", command[1:],
                                  block_number))
                command = []
    return found


def test_every_documented_command_line_parses():
    """Each parses with the command line's parser (nothing runs): an option renamed, a
    subcommand removed or a placeholder left in a command fails here."""
    from damper_hil.cli import build_parser

    commands = documented_commands()
    assert len(commands) > 40            # the README's and the docs' examples were found
    reference = (REPO / "docs" / "parameters.md").read_text(encoding="utf-8")
    bad = []
    written: dict[tuple[int, str], str] = {}     # (block, folder) → where
    for where, argv, block in commands:
        if any(w == "..." or (w.startswith("[") and w.endswith("]")) for w in argv):
            bad.append(f"{where}: a usage synopsis in a shell block (use a text block)")
            continue
        argv = [part for w in argv
                for part in (w.split("=", 1) if w.startswith("--") and "=" in w else [w])]
        # a block's commands, run in turn, must not write one folder twice: a folder
        # output is replaced as a whole
        for flag, value in itertools.pairwise(argv):
            if flag in ("--out", "--report") and not value.endswith((".csv", ".json")):
                key = (block, value.rstrip("/"))
                if key in written:
                    bad.append(f"{where}: {flag} {value} again (also {written[key]})")
                written[key] = where
        head = argv[:argv.index("--ros-args")] if "--ros-args" in argv else argv
        try:
            args = build_parser().parse_args(head)
        except SystemExit:
            bad.append(f"{where}: damper-hil {' '.join(argv)}")
            continue
        if len(head) < len(argv) and not getattr(args, "takes_ros_args", False):
            bad.append(f"{where}: {args.command} takes no --ros-args")
        # every node parameter set with -p is one the parameter reference lists
        ros_args = argv[len(head):]
        for flag, value in itertools.pairwise(ros_args):
            if flag == "-p" and f"| `{value.split(':=')[0]}` |" not in reference:
                bad.append(f"{where}: -p {value}: not in docs/parameters.md")
    assert not bad, "\n".join(bad)
