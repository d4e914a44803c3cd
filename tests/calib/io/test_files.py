"""calib.files: atomic writes, strict JSON, UTF-8 and YAML reading with one-line errors."""

import errno
import json
import os
import signal
import subprocess
import sys
from unittest import mock

import pytest

import trackcal.calib.io.files as files_mod
from trackcal.calib.errors import CalibError
from trackcal.calib.io.files import atomic_open, finite_or_null, read_json, read_text, read_yaml, write_json


def test_atomic_open_gives_the_permissions_open_would(tmp_path):
    with atomic_open(tmp_path / "a.txt") as fh:
        fh.write("x")
    open(tmp_path / "b.txt", "w").close()
    assert os.stat(tmp_path / "a.txt").st_mode == os.stat(tmp_path / "b.txt").st_mode


def test_a_failed_write_leaves_the_previous_file_and_no_temporary(tmp_path):
    path = tmp_path / "model.json"
    write_json(path, {"a": 1})
    with pytest.raises(RuntimeError), atomic_open(path) as fh:
        fh.write('{"a": ')
        raise RuntimeError("killed mid-write")
    read_only = OSError(errno.EROFS, "read-only")
    with mock.patch.object(files_mod.os, "replace", side_effect=read_only), pytest.raises(OSError):
        write_json(path, {"a": 2})
    assert json.loads(path.read_text()) == {"a": 1} and os.listdir(tmp_path) == ["model.json"]


def test_json_is_strict_both_ways(tmp_path):
    with pytest.raises(ValueError):
        write_json(tmp_path / "x.json", {"rho0_mm": float("inf")})
    assert not (tmp_path / "x.json").exists()
    doc = finite_or_null({"rho0_mm": float("inf"), "score": float("nan"), "n": 3}, "infeasible")
    assert doc == {"rho0_mm": None, "rho0_why": "infeasible", "score": None, "score_why": "infeasible", "n": 3}
    (tmp_path / "nan.json").write_text('{"value": NaN}')
    with pytest.raises(CalibError, match=r"nan.json: NaN is not JSON"):
        read_json(tmp_path / "nan.json", CalibError)
    (tmp_path / "cut.json").write_text('{"value": \n 1.5,')
    with pytest.raises(CalibError, match=r"cut.json: line 2: not JSON"):
        read_json(tmp_path / "cut.json", CalibError)
    (tmp_path / "list.json").write_text("[1]")
    with pytest.raises(CalibError, match=r"list.json: expected a JSON object at the top level, got list"):
        read_json(tmp_path / "list.json", CalibError)


def test_text_is_utf8_with_an_optional_bom(tmp_path):
    p = tmp_path / "cell.yaml"
    p.write_bytes(b"\xef\xbb\xbfname: x\n")
    assert read_yaml(p, CalibError) == {"name": "x"}
    p.write_bytes("name: x\nrobot: K\xf6ln\n".encode("latin-1"))
    with pytest.raises(CalibError, match=r"cell.yaml: line 2: not UTF-8 text \(byte 0xf6\)"):
        read_text(p, CalibError)
    with pytest.raises(CalibError, match=r"nope.yaml: no such file"):
        read_text(tmp_path / "nope.yaml", CalibError)


@pytest.mark.parametrize(
    "text, message",
    [
        ("a: [1, 2\n", r"not valid YAML \(line 2\)"),
        ("- 1\n- 2\n", r"expected a mapping of keys at the top level, got list"),
        ("", r"expected a mapping of keys at the top level, got NoneType"),
    ],
)
def test_yaml_mistakes_are_one_line(tmp_path, text, message):
    p = tmp_path / "c.yaml"
    p.write_text(text)
    with pytest.raises(CalibError, match=message) as exc:
        read_yaml(p, CalibError)
    assert "\n" not in str(exc.value)


def test_a_killed_writer_s_temporary_is_removed_by_the_next_write_and_nothing_else(tmp_path):
    """Issue 27, finding 8: a writer killed with SIGKILL mid-write leaves `.NAME.PID.RANDOM.tmp`; the next write into
    that directory removes it (its PID is dead). A live writer's temporary, a link and other names stay."""
    child = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time\nfrom trackcal.calib.io.files import atomic_open\n"
            f"with atomic_open({str(tmp_path / 'report.html')!r}) as fh:\n"
            "    fh.write('<html>half'); fh.flush(); print('writing', flush=True); time.sleep(60)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert child.stdout.readline() == "writing\n"
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait(10)
    [left] = [p.name for p in tmp_path.iterdir()]
    assert left.startswith(f".report.html.{child.pid}.") and left.endswith(".tmp")  # kill -9 leaves it
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        keep = [
            f".model.json.{live.pid}.abcd_123.tmp",
            f".model.json.{os.getpid()}.zzzzzzzz.tmp",
            "notes.tmp",
            f".model.json.{child.pid}.short.tmp",
            f"model.json.{child.pid}.abcdefgh.tmp",
        ]
        for name in keep:
            (tmp_path / name).write_text("someone else's")
        (tmp_path / f".plan.json.{child.pid}.linklink.tmp").symlink_to(tmp_path / "notes.tmp")
        keep.append(f".plan.json.{child.pid}.linklink.tmp")
        write_json(tmp_path / "verdict.json", {"cause": "none"})
        assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*keep, "verdict.json"])
        assert all((tmp_path / n).read_text() == "someone else's" for n in keep)
    finally:
        live.kill()
        live.wait(10)
