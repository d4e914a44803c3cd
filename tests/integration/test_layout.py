"""Code an editor can follow (issue 37): pyright, the analyser of VS Code, resolves every `trackcal.*` import of the
package and not the forbidden top-level form (`calib.*`), and a test run holds one module object per module.

pyright is the npm package `make setup` installs into .venv/node (pinned in the Makefile); .venv/links holds the
`trackcal` link to the repository root that pyproject's [tool.pyright] search paths name (docs/layout.md)."""

import ast
import importlib
import json
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from tests.helpers import ROOT

PYRIGHT = Path(sys.prefix) / "node" / "node_modules" / ".bin" / "pyright"
LINKS = Path(sys.prefix) / "links"
FOLDERS = ("calib", "campaign", "drivers", "mocks", "configs", "tests", "bench", "studies")


def trackcal_modules() -> set[str]:
    """Every module named by a `trackcal.*` import in the package, its tests, bench and studies."""
    names = set()
    for folder in FOLDERS:
        for path in (ROOT / folder).rglob("*.py"):
            if "thirdparty" in path.parts or "__pycache__" in path.parts:
                continue
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names.add(node.module)
                elif isinstance(node, ast.Import):
                    names.update(a.name for a in node.names)
    return {n for n in names if n == "trackcal" or n.startswith("trackcal.")}


def pyright(*args: str, cwd: Path) -> list[dict]:
    assert PYRIGHT.exists(), f"{PYRIGHT} is missing: run `make setup` (it installs pyright with npm)"
    done = subprocess.run([str(PYRIGHT), "--outputjson", *args], cwd=cwd, capture_output=True, text=True, timeout=1200)
    return json.loads(done.stdout)["generalDiagnostics"]


def unresolved(diagnostics: list[dict]) -> list[str]:
    return sorted(
        f"{Path(d['file']).relative_to(ROOT) if d['file'].startswith(str(ROOT)) else d['file']}:"
        f"{d['range']['start']['line'] + 1}: {d['message']}"
        for d in diagnostics
        if d.get("rule") == "reportMissingImports"
    )


def test_a_room_is_importable_only_inside_trackcal():
    """From the root, `campaign.cli` would be a second module object beside `trackcal.campaign.cli`."""
    for room in ("calib", "campaign", "drivers", "mocks", "configs"):
        with pytest.raises(ModuleNotFoundError, match=f"trackcal.{room}"):
            importlib.import_module(room)
    assert importlib.import_module("trackcal.campaign.cli").__file__ == str(ROOT / "campaign" / "cli" / "__init__.py")


def test_every_folder_is_a_pyright_environment_searching_only_the_link():
    """A folder missing here would fall back to the root as its search path, where `calib.*` resolves."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pyright"]
    environments = {e["root"]: e["extraPaths"] for e in config["executionEnvironments"]}
    code_folders = {
        d.name for d in ROOT.iterdir() if d.is_dir() and d.name[0] != "." and d.name != "build" and any(d.rglob("*.py"))
    }
    assert code_folders <= set(environments), code_folders - set(environments)
    assert all(paths == [".venv/links"] for paths in environments.values()), environments
    assert (LINKS / "trackcal").resolve() == ROOT


def test_pyright_resolves_every_trackcal_module_the_code_imports_and_not_the_bare_room(tmp_path):
    """One file importing each module the code imports, checked with the link as the only first-party path."""
    modules = sorted(trackcal_modules())
    assert len(modules) > 100  # the package's imports are found (about 150 distinct modules)
    probe = tmp_path / "probe.py"
    probe.write_text("".join(f"import {m}\n" for m in modules) + "import calib.model\nimport campaign.cli\n")
    (tmp_path / "pyrightconfig.json").write_text(
        json.dumps(
            {
                "extraPaths": [str(LINKS)],
                "venvPath": str(Path(sys.prefix).parent),
                "venv": Path(sys.prefix).name,
                "typeCheckingMode": "off",
                "reportMissingImports": "error",
            }
        )
    )
    missing = unresolved(pyright("probe.py", cwd=tmp_path))
    assert [m.split(": ", 1)[1] for m in missing] == [
        'Import "calib.model" could not be resolved',
        'Import "campaign.cli" could not be resolved',
    ], missing


@pytest.mark.slow
def test_pyright_over_the_package_resolves_every_trackcal_import():
    """The editor's view: pyright with pyproject's configuration over every folder (minutes: the slow suite)."""
    missing = unresolved(pyright(*FOLDERS, cwd=ROOT))
    assert not [m for m in missing if "trackcal" in m.split(": ", 1)[1]], missing
