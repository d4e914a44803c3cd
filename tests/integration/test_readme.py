"""Every ```sh example of README.md and of the manual's pages (docs/) runs verbatim, in a declared order, in one
temporary directory, and makes the files it names.

The examples build their own fixtures (the README's campaign makes the plan and the session that later pages read), so
a newcomer can paste them one after the other. PAGES is the order: a page may read what the pages before it made;
every other page of docs/ runs after them, in name order (a new page's examples run without being listed). A command
line ending in `# not run by the README test: REASON` (hardware, a cluster, many minutes) is shown but skipped here;
a block that uses $TRACKCAL_IPA_DATA runs only where the IPA data set is (next to the repository, as in CI, or where
TRACKCAL_IPA_DATA points). A `python -m MODULE` line that is not run must still name a module the empty directory can
import. A block that starts a detached `trackcal mock` must stop it: a mock still running after the block fails the
test (and is stopped).
"""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.helpers import ROOT
from trackcal.campaign.cli.mock import mock_pid, running_mock

README = ROOT / "README.md"
# The order of the examples: the README first (its campaign makes plan.json, plan.csv and sessions/kr270-a), then the
# pages whose files later pages read, in the order they are made (table.csv, model.json, kr270-a.csv, cal.json,
# ur10-model.json, iso-before/iso-after ...). Pages not listed run after these, in name order.
PAGES = [
    "README.md",
    "docs/reference/index.md",
    "docs/reference/identify.md",
    "docs/reference/predict.md",
    "docs/reference/locate.md",
    "docs/reference/export-urdf.md",
    "docs/reference/plan.md",
    "docs/reference/diagnose.md",
    "docs/reference/simulate.md",
    "docs/reference/run.md",
    "docs/reference/operator-page.md",
    "docs/reference/mock.md",
    "docs/guides/ur-cell.md",
    "docs/reference/report.md",
    "docs/reference/compensate.md",
    "docs/guides/iso9283.md",
    "docs/guides/fleet.md",
    "docs/guides/new-robot.md",
    "docs/design/real-data.md",
]
NOT_RUN = "# not run by the README test:"
# options whose value is a file or directory the command writes (checked to exist after the example)
OUTPUT_OPTIONS = (
    "--out",
    "--json",
    "--csv",
    "--session",
    "--into",
    "--plots",
    "--write-hardware",
    "--krl-dir",
    "--truth",
)
IPA_DATA = Path(os.environ.get("TRACKCAL_IPA_DATA") or ROOT.parent / "shared" / "data" / "ipa-robot-accuracy")


@dataclass
class Example:
    page: str  # README.md or docs/...
    line: int  # where the block starts in it
    commands: list[str]  # logical command lines (continuations joined), skipped ones left out
    skipped: list[str]

    @property
    def where(self) -> str:
        return f"{self.page}:{self.line}"


def commands_of(block: str) -> tuple[list[str], list[str]]:
    """The block's command lines (a trailing backslash joins the next line), and those marked not run."""
    run, skipped, current = [], [], ""
    for raw in block.splitlines():
        current += raw[:-1] + " " if raw.endswith("\\") else raw
        if raw.endswith("\\"):
            continue
        line, current = current.strip(), ""
        if not line or line.startswith("#"):
            continue
        (skipped if NOT_RUN in line else run).append(line)
    return run, skipped


def pages() -> list[str]:
    """README.md and every page of docs/, in the order their examples run."""
    rest = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "docs").rglob("*.md"))
    return [p for p in PAGES if (ROOT / p).is_file()] + [p for p in rest if p not in PAGES]  # a missing one: below


def examples() -> list[Example]:
    out = []
    for page in pages():
        text = (ROOT / page).read_text(encoding="utf-8")
        for m in re.finditer(r"^```sh\n(.*?)^```", text, re.S | re.M):
            run, skipped = commands_of(m.group(1))
            out.append(Example(page, text.count("\n", 0, m.start()) + 1, run, skipped))
    return out


def outputs_of(command: str) -> list[str]:
    """Files the command names as its outputs: values of OUTPUT_OPTIONS and `# -> PATH` comments."""
    code, _, comment = command.partition(" #")
    words = shlex.split(code)
    named = [words[i + 1] for i, w in enumerate(words[:-1]) if w in OUTPUT_OPTIONS]
    named += [w.split("=", 1)[1] for w in words if w.split("=", 1)[0] in OUTPUT_OPTIONS and "=" in w]
    named += re.findall(r"->\s*(\S+)", comment)
    if "--krl-dir" in words and "--krl" in words:
        krl = words[words.index("--krl") + 1]
        named.append(f"{words[words.index('--krl-dir') + 1]}/{krl}.src")
    return named


EXAMPLES = examples()


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("readme")


def test_the_readme_has_examples_and_marks_the_ones_it_does_not_run():
    assert len(EXAMPLES) >= 10
    for ex in EXAMPLES:
        for line in ex.skipped:
            reason = line.split(NOT_RUN, 1)[1].strip()
            assert reason, f"{ex.where}: say why it is not run: {line}"


def test_every_declared_page_exists_and_the_readme_runs_first():
    """A page renamed or removed would silently drop its examples out of the order."""
    missing = [p for p in PAGES if not (ROOT / p).is_file()]
    assert not missing, f"PAGES names pages that do not exist: {missing}"
    assert EXAMPLES[0].page == "README.md" and any(e.page.startswith("docs/") for e in EXAMPLES)


@pytest.mark.parametrize("example", EXAMPLES, ids=[e.where for e in EXAMPLES])
def test_example_runs_verbatim(example: Example, workdir: Path):
    if not example.commands:
        pytest.skip("every command of this block needs what the test does not have (see its comments)")
    script = "\n".join(example.commands)
    if "TRACKCAL_IPA_DATA" in script and not IPA_DATA.is_dir():
        pytest.skip(f"the IPA data set is not at {IPA_DATA} (set TRACKCAL_IPA_DATA)")
    env = dict(
        os.environ,
        PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
        TRACKCAL_IPA_DATA=str(IPA_DATA),
        OPENBLAS_NUM_THREADS="1",
    )
    script = (
        f"set -eo pipefail\ntrap 'echo \"{example.where}: failed: $BASH_COMMAND\" >&2' ERR\n"
        "trap 'kill $(jobs -p) 2>/dev/null || true' EXIT\n" + script + "\n"
    )
    try:
        done = subprocess.run(
            ["bash", "-c", script], cwd=workdir, env=env, capture_output=True, text=True, stdin=subprocess.DEVNULL
        )
    finally:  # a detached mock outlives the shell: the block must stop it, and a failed block leaves none either
        left = left_running(workdir, example.commands)
    assert done.returncode == 0, f"{example.where}: exit {done.returncode}\n{done.stdout[-3000:]}{done.stderr}"
    assert not left, f"{example.where} left its trackcal mock running (pids {left}; now stopped)"
    missing = [p for c in example.commands for p in outputs_of(c) if not (workdir / p).exists()]
    assert not missing, f"{example.where}: the example did not make {missing}"


def left_running(workdir: Path, commands: list[str]) -> list[int]:
    """Pids of the mocks the commands started (their --write-hardware files) that still run; each is stopped."""
    pids = []
    for command in commands:
        words = shlex.split(command.partition(" #")[0])
        if words[:2] == ["trackcal", "mock"] and "--write-hardware" in words:
            hardware = workdir / words[words.index("--write-hardware") + 1]
            pid = mock_pid(hardware) if hardware.exists() else None
            if pid is not None and running_mock(pid):
                pids.append(pid)
                os.kill(pid, signal.SIGKILL)
    return pids


def test_the_readme_starts_a_mock_and_stops_it():
    """The mock block runs (it is not all marked not run) and stops its mock: test_example_runs_verbatim fails a
    block that leaves one running."""
    blocks = [e for e in EXAMPLES if any(c.startswith("trackcal mock") for c in e.commands)]
    assert blocks and any("--detach" in c for c in blocks[0].commands), "no example runs a detached mock"
    assert any(c.startswith("trackcal mock --stop") for c in blocks[0].commands)


def test_a_module_the_readme_names_but_does_not_run_can_be_imported_from_any_directory(tmp_path):
    modules = [re.match(r"python -m ([\w.]+)", line) for ex in EXAMPLES for line in ex.skipped]
    modules = sorted({m.group(1) for m in modules if m})
    assert modules, "the README names no `python -m` module"
    env = dict(os.environ, PYTHONPATH="")
    for module in modules:  # a spec found from an empty directory: not only from the repository's root
        done = subprocess.run(
            [sys.executable, "-c", f"import importlib.util as u; assert u.find_spec({module!r})"],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
        )
        assert done.returncode == 0, f"README: python -m {module} fails outside the repository root: {done.stderr}"


def test_the_study_without_data_says_where_it_looked(tmp_path):
    nowhere = tmp_path / "no-data"
    done = subprocess.run(
        [sys.executable, "-m", "trackcal.studies.ur10_ipa.study", "--data", str(nowhere)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert str(nowhere) in done.stderr and "TRACKCAL_IPA_DATA" in done.stderr
