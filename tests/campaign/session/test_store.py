"""The session store under operator mistakes: one process per session, the database file alone is the record,
hash-chained events and `trackcal check`, stored plan and config, and damaged, read-only or full disks."""

import io
import json
import os
import re
import shutil
import sqlite3
import subprocess
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rich.console import Console

from tests.helpers import ROOT, TRACKCAL, assert_stopped, before_call, feasible_plan, inproc_live
from trackcal.calib.model.cell import load_cell
from trackcal.campaign.cli import main
from trackcal.campaign.cli.campaign import campaign_exit
from trackcal.campaign.cli.console import ConsoleOperator
from trackcal.campaign.jobs.campaign import new_session, run_stored
from trackcal.campaign.jobs.completeness import completeness, run_completeness
from trackcal.campaign.session.session import export_table, session_plan
from trackcal.campaign.session.store import SessionStore, StoreError
from trackcal.drivers.errors import ConnectionLost
from trackcal.mocks.cell import NotVisible, World

HOLDER = r"in use by process (\d+) since \d{4}-\d\d-\d\d \d\d:\d\d:\d\d UTC"


@pytest.fixture(scope="module")
def plan(kr270):
    return feasible_plan(kr270, 3, seed=5, repeat=1)


@pytest.fixture(scope="module")
def reference(kr270, plan, tmp_path_factory):
    """An uninterrupted in-process campaign: its session directory and its table."""
    store, _ = new_session(tmp_path_factory.mktemp("ref") / "s", "kr270", plan, "sim", 3)
    run_stored(store, inproc_live(kr270)[1])
    table = export_table(store)
    store.close()
    return store.directory, table


def same_table(a, b) -> None:
    assert a.pose == b.pose and a.station == b.station and a.point == b.point
    np.testing.assert_array_equal(a.q_deg, b.q_deg)
    np.testing.assert_array_equal(a.xyz, b.xyz)


def one_line_error(capsys, argv) -> str:
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and "Traceback" not in err, err
    return err


def copy_of(session: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(session, tmp_path / "copy"))


# ---------------------------------------------------------------------------------------------- one process
def test_a_second_opener_in_the_same_process_is_refused(reference, tmp_path):
    d = copy_of(reference[0], tmp_path)
    store = SessionStore.open(d)
    with pytest.raises(StoreError, match=HOLDER) as err:
        SessionStore.open(d)
    assert f"process {os.getpid()} " in str(err.value)
    store.close()  # released: the next opener gets it
    SessionStore.open(d).close()


HOLD = (
    "import sys, time; from trackcal.campaign.session.store import SessionStore; SessionStore.open(sys.argv[1]); "
    "print(flush=True); time.sleep(600)"
)


def test_a_second_process_is_refused_naming_the_first_and_kill_9_leaves_no_stale_lock(plan, reference, tmp_path):
    """A process holding the session (the store's own lock, as run and resume take it); a real second
    `trackcal resume`, and a `trackcal run` into the same directory, exit 2 naming its pid; after kill -9 of
    the holder, resume goes ahead."""
    d = copy_of(reference[0], tmp_path)
    (tmp_path / "plan.json").write_text(json.dumps(plan))
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(d)], stdout=subprocess.PIPE, text=True)
    try:
        holder.stdout.readline()  # the lock is taken
        for argv in (
            ["resume", d, "--no-analysis"],
            ["run", "--cell", "kr270", "--plan", tmp_path / "plan.json", "--sim", "--session", d],
        ):
            out = subprocess.run([*TRACKCAL, *map(str, argv)], capture_output=True, text=True, timeout=120)
            assert out.returncode == 2 and out.stderr.count("\n") == 1 and "Traceback" not in out.stderr, out.stderr
            assert int(re.search(HOLDER, out.stderr).group(1)) == holder.pid
    finally:
        holder.kill()  # SIGKILL: the process cannot clean anything up
        holder.wait()
    out = subprocess.run([*TRACKCAL, "resume", str(d), "--no-analysis"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and "already complete" in out.stdout, out.stderr


# ---------------------------------------------------------------------------------------------- the record
def test_a_copy_of_the_database_file_alone_holds_every_committed_measurement(kr270, plan, reference, tmp_path):
    """Copies of session.sqlite alone taken right after the k-th measurement is committed (no -journal, no
    config, no plan.json beside them) export those k measurements, and a copy can be resumed to the end."""
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", 3)
    append, copies, measured = store.append, {}, []

    def append_and_copy(kind, *args):
        event = append(kind, *args)
        measured.extend([1] if kind == "measurement" else [])
        n = len(measured)
        if kind == "measurement" and n in (1, len(reference[1]) // 2):
            (tmp_path / f"c{n}").mkdir()
            shutil.copyfile(store.path, tmp_path / f"c{n}" / "session.sqlite")
            copies[n] = tmp_path / f"c{n}"
        return event

    store.append = append_and_copy
    run_stored(store, inproc_live(kr270)[1])
    full = export_table(store)
    for n, d in copies.items():
        table = export_table(SessionStore.open(d, readonly=True))
        assert len(table) == n and table.pose == full.pose[:n]
        np.testing.assert_array_equal(table.xyz, full.xyz[:n])
    resumed = SessionStore.open(copies[1])  # the stored cell and plan are all a resume needs
    run_stored(resumed, inproc_live(kr270, store=resumed)[1])
    same_table(export_table(resumed), full)


class Crash(Exception):
    """Stands for kill -9 between two device calls (the two-process test does it for real)."""


def crash():
    raise Crash()


def test_resume_uses_the_stored_plan_and_says_the_files_differ(kr270, plan, reference, tmp_path, capsys):
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", 3)
    _, live = inproc_live(kr270)
    before_call(live.tracker, "measure", 2, crash)
    with pytest.raises(Crash):
        run_stored(store, live)
    store.close()
    edited = json.loads((tmp_path / "s" / "plan.json").read_text())
    edited["poses_deg"][0][0] += 5.0  # pose Q1 moved by hand in the file
    (tmp_path / "s" / "plan.json").write_text(json.dumps(edited))
    (tmp_path / "s" / "config" / "tool.yaml").unlink()
    assert main(["resume", str(tmp_path / "s"), "--no-analysis"]) == 0
    out = capsys.readouterr().out
    note = [line for line in out.splitlines() if line.startswith("note")]
    assert len(note) == 1 and "config/tool.yaml, plan.json" in note[0] and "uses the stored copies" in note[0]
    done = SessionStore.open(tmp_path / "s", readonly=True)
    assert session_plan(done) == plan
    table = export_table(done)
    assert table.pose == reference[1].pose  # the plan as it was, pose for pose
    q1 = table.q_deg[[p == "Q1" for p in table.pose]]
    np.testing.assert_allclose(q1, np.tile(plan["poses_deg"][0], (len(q1), 1)), atol=1e-3)  # controller's 4 dp


# ---------------------------------------------------------------------------------------------- integrity
def test_check_names_the_first_bad_event_and_export_and_resume_refuse(reference, tmp_path, capsys):
    d = copy_of(reference[0], tmp_path)
    assert main(["check", str(d)]) == 0
    out = capsys.readouterr().out
    with sqlite3.connect(d / "session.sqlite") as db:
        head = db.execute("SELECT hash FROM events ORDER BY id DESC LIMIT 1").fetchone()[0]
        n_events = db.execute("SELECT count(*) FROM events").fetchone()[0]
        victim, step, data = db.execute(
            "SELECT id, step, data FROM events WHERE kind='measurement' ORDER BY id LIMIT 1 OFFSET 2"
        ).fetchone()
    assert f"{n_events} events" in out and head in out
    doc = json.loads(data)
    doc["xyz_mm"][0] += 800.0  # the 3136.75 -> 3936.75 mm
    with sqlite3.connect(d / "session.sqlite") as db:
        db.execute("UPDATE events SET data=? WHERE id=?", (json.dumps(doc), victim))
    named = f"event {victim} (measurement, step {step}) breaks the hash chain"
    for argv in (["check", d], ["export", d, "--csv", tmp_path / "t.csv"], ["resume", d]):
        assert named in one_line_error(capsys, argv)
    assert not (tmp_path / "t.csv").exists()


def test_an_edited_stored_plan_is_named(reference, tmp_path, capsys):
    d = copy_of(reference[0], tmp_path)
    with sqlite3.connect(d / "session.sqlite") as db:
        db.execute("UPDATE documents SET text=replace(text, '1', '2') WHERE name='plan.json'")
    assert "the stored copy of plan.json does not match its hash" in one_line_error(capsys, ["check", d])


def chained_store(directory: Path, n: int) -> SessionStore:
    store = SessionStore.create(directory, {"mode": "test"}, {"plan.json": "{}"})
    for i in range(n):
        store.append("warning", {"message": f"event {i}", "x": i * 0.1}, step=i, t_campaign=float(i))
    return store


EDITS = {
    "data": "UPDATE events SET data=replace(data, 'event', 'Event') WHERE id=?",
    "time": "UPDATE events SET t_campaign=t_campaign + 1e-9 WHERE id=?",
    "kind": "UPDATE events SET kind='error' WHERE id=?",
    "hash": "UPDATE events SET hash=substr(hash, 2) || '0' WHERE id=?",
    "delete": "DELETE FROM events WHERE id=?",
}


@settings(max_examples=30, deadline=None)
@given(st.integers(2, 12), st.data(), st.sampled_from(sorted(EDITS)))
def test_any_edit_is_found_at_the_event_it_touched(n, data, edit):
    """One edit anywhere (a removed event: anywhere but the last, which the chain cannot see) fails the
    chain exactly at the edited event, or at the one after a removed one; every event before is intact."""
    victim = data.draw(st.integers(1, n - 1 if edit == "delete" else n))
    with tempfile.TemporaryDirectory() as tmp:
        chained_store(Path(tmp), n).close()
        assert SessionStore.open(tmp, readonly=True).verify().events == n
        with sqlite3.connect(Path(tmp) / "session.sqlite") as db:
            db.execute(EDITS[edit], (victim,))
        first_bad = victim + 1 if edit == "delete" else victim
        with pytest.raises(StoreError, match=rf"event {first_bad} .* events 1 to {victim - 1} are intact"):
            SessionStore.open(tmp, readonly=True)


# ---------------------------------------------------------------------------------------------- damaged, old
@pytest.mark.parametrize("damage", ["truncated", "overwritten", "empty"])
def test_a_damaged_database_is_one_line_for_resume_export_and_check(reference, tmp_path, capsys, damage):
    d = copy_of(reference[0], tmp_path)
    db = d / "session.sqlite"
    raw = db.read_bytes()
    if damage == "truncated":
        db.write_bytes(raw[: len(raw) // 2])
    elif damage == "overwritten":
        db.write_bytes(raw[:4096] + bytes(range(256)) * 16 + raw[8192:])  # the second page is garbage
    else:
        db.write_bytes(b"")
    for argv in (["resume", d], ["export", d, "--csv", tmp_path / "t.csv"], ["check", d]):
        assert str(db) in one_line_error(capsys, argv)


def test_a_session_of_the_previous_schema_is_refused_clearly(tmp_path, capsys):
    d = tmp_path / "old"
    d.mkdir()
    with sqlite3.connect(d / "session.sqlite") as db:  # schema 1: no documents, no hash column
        db.execute("CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL)")
        db.execute(
            "CREATE TABLE events(id INTEGER PRIMARY KEY, t_wall REAL, t_campaign REAL, step INTEGER, "
            "kind TEXT, data TEXT)"
        )
        db.execute("INSERT INTO meta VALUES ('schema', '1')")
    for argv in (["resume", d], ["export", d, "--csv", tmp_path / "t.csv"], ["check", d]):
        assert "session schema 1, this trackcal reads schema 2" in one_line_error(capsys, argv)


# ---------------------------------------------------------------------------------------------- the machine
@contextmanager
def read_only(path: Path):
    """`path` read-only: a read-only bind mount as root (root ignores permissions), else permissions."""
    if os.geteuid() != 0:
        path.chmod(0o555)
        try:
            yield
        finally:
            path.chmod(0o755)
        return
    if subprocess.run(["mount", "--bind", "-o", "ro", str(path), str(path)], capture_output=True).returncode:
        pytest.skip("cannot bind-mount a read-only directory here")
    try:
        yield
    finally:
        subprocess.run(["umount", "-l", str(path)], check=True)  # lazy: the CLI calls above leave their store open


def test_a_read_only_session_can_be_read_but_not_resumed(reference, tmp_path, capsys):
    d = copy_of(reference[0], tmp_path)
    with read_only(d):
        assert "read-only" in one_line_error(capsys, ["resume", d])
        assert main(["check", str(d)]) == 0
        assert main(["export", str(d), "--csv", str(tmp_path / "t.csv")]) == 0
    assert len(export_table(SessionStore.open(d, readonly=True))) == len(reference[1])


@pytest.fixture
def small_disk(reference, tmp_path):
    """A tmpfs half the size of the complete session's database: room for the session's creation and a part
    of the campaign (mounting it needs root)."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    size = (reference[0] / "session.sqlite").stat().st_size // 2
    if (
        os.geteuid() != 0
        or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)], capture_output=True
        ).returncode
    ):
        pytest.skip("mounting a small tmpfs needs root")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], check=True)


def test_a_full_disk_stops_the_campaign_and_loses_nothing(kr270, plan, reference, small_disk, tmp_path, capsys):
    store, _ = new_session(small_disk / "s", "kr270", plan, "sim", 3)
    with pytest.raises(StoreError, match="the disk is full") as err:
        run_stored(store, inproc_live(kr270)[1])
    assert "\n" not in str(err.value) and "copy" in str(err.value)
    stored = len(store.events("measurement"))
    store.close()
    assert 0 < stored < len(reference[1])  # full in the middle of the campaign
    elsewhere = SessionStore.open(shutil.copytree(small_disk / "s", tmp_path / "elsewhere"))
    run_stored(elsewhere, inproc_live(kr270, store=elsewhere)[1])
    same_table(export_table(elsewhere), reference[1])
    (tmp_path / "plan.json").write_text(json.dumps(plan))  # and the command line says it in one line
    one_line_error(
        capsys, ["run", "--cell", "kr270", "--plan", tmp_path / "plan.json", "--sim", "--session", small_disk / "t"]
    )


def test_the_console_at_end_of_input_stops_the_campaign_safely(kr270, plan, tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "stdin", io.StringIO(""))  # stdin closed: nobody at the console
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", 3)
    operator = ConsoleOperator(Console(file=io.StringIO()))
    assert_stopped(run_stored(store, inproc_live(kr270, operator=operator)[1]), "operator console: end of input")
    assert not [e for e in store.events("call") if e.data["op"] == "move"]  # nothing moved unacknowledged


# ------------------------------------------------------------------------------------ the folder is the user's
def test_a_lock_file_replaced_by_a_link_is_refused_and_its_target_untouched(reference, tmp_path, capsys):
    # issue 27: `resume` truncated and overwrote whatever session.lock pointed at (trackcal runs as root on cell PCs)
    d = copy_of(reference[0], tmp_path)
    precious = tmp_path / "precious.txt"
    precious.write_text("a file of the cell PC\n")
    (d / "session.lock").unlink(missing_ok=True)
    (d / "session.lock").symlink_to(precious)
    err = one_line_error(capsys, ["resume", d, "--no-analysis"])
    assert "session.lock: a symbolic link" in err
    assert precious.read_text() == "a file of the cell PC\n"
    (d / "session.lock").unlink()
    (d / "session.lock").symlink_to(tmp_path / "etc" / "created-by-trackcal")  # dangling: nothing may be created
    one_line_error(capsys, ["resume", d, "--no-analysis"])
    assert not (tmp_path / "etc").exists()


def test_a_linked_session_folder_or_database_is_refused(reference, tmp_path, capsys):
    d = copy_of(reference[0], tmp_path)
    (tmp_path / "link").symlink_to(d, target_is_directory=True)
    for command in (
        ["check", tmp_path / "link"],
        ["export", tmp_path / "link", "--csv", tmp_path / "t.csv"],
        ["resume", tmp_path / "link"],
    ):
        assert "link: a symbolic link" in one_line_error(capsys, command)
    (tmp_path / "db").mkdir()
    (tmp_path / "db" / "session.sqlite").symlink_to(d / "session.sqlite")
    assert "session.sqlite: a symbolic link" in one_line_error(capsys, ["check", tmp_path / "db"])


@pytest.mark.parametrize("name", ["with space", "unicode-Kö€ln", "what?", "hash#tag", "per%cent", "%3F"])
def test_session_paths_with_uri_characters_are_read_where_they_are(reference, tmp_path, capsys, name):
    # issue 27: the path was pasted unescaped into SQLite's `file:` URI: `?`, `#`, `%` made check/export/resume
    # open another file (and check create stray ones)
    d = Path(shutil.copytree(reference[0], tmp_path / name))
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["check", str(d)]) == 0 and "sound" in capsys.readouterr().out
    assert main(["export", str(d), "--csv", str(tmp_path / "t.csv")]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*before, "t.csv"])  # no stray files
    assert main(["resume", str(d), "--no-analysis"]) == 0  # complete: nothing to do, but it opens and locks
    assert "already complete" in capsys.readouterr().out


@pytest.mark.parametrize(
    "ddl, named",
    [
        (
            "CREATE TRIGGER t AFTER INSERT ON events BEGIN UPDATE events SET data = '{}' WHERE id = NEW.id; END",
            "trigger t",
        ),
        ("CREATE VIEW v AS SELECT * FROM events", "view v"),
        ("CREATE INDEX i ON events(kind)", "index i"),
    ],
)
def test_a_schema_object_added_to_the_database_is_named(reference, tmp_path, capsys, ddl, named):
    # issue 27: a trigger or view added to session.sqlite was not noticed by `check`
    d = copy_of(reference[0], tmp_path)
    with sqlite3.connect(d / "session.sqlite") as db:
        db.execute(ddl)
    err = one_line_error(capsys, ["check", d])
    assert "its schema is not trackcal's" in err and named in err


KILLED_REPLAY = (
    "import os, signal, sys; from pathlib import Path; import trackcal.campaign.jobs.campaign as job; "
    "from trackcal.campaign.session.store import SessionStore\n"
    "seen = []\n"
    "def kill_at_the_fifth_measurement(doc):  # after the session log: five measurements committed\n"
    "    seen.extend([1] if doc.name == 'measurement' else [])\n"
    "    if len(seen) == 5:\n"
    "        os.kill(os.getpid(), signal.SIGKILL)  # kill -9\n"
    "job.replay(SessionStore.open(sys.argv[1], readonly=True), Path(sys.argv[2]), "
    "subscribers=[kill_at_the_fifth_measurement])\n"
)


def test_a_killed_replay_leaves_no_session_and_the_next_replay_makes_it(reference, tmp_path, capsys):
    # issue 27: a killed `replay --into` was a dead end (replay again: "use resume"; resume: "cannot be run live")
    into = tmp_path / "replay"
    proc = subprocess.run([sys.executable, "-c", KILLED_REPLAY, str(reference[0]), str(into)], capture_output=True)
    assert proc.returncode == -9, proc.stderr
    staging = tmp_path / "replay.replaying"
    assert not into.exists() and (staging / "session.sqlite").exists()
    err = one_line_error(capsys, ["resume", staging])
    assert f"trackcal replay {reference[0]} --into DIR" in err  # the one piece of advice: replay again
    assert main(["replay", str(reference[0]), "--into", str(into)]) == 0
    assert not staging.exists()
    same_table(export_table(SessionStore.open(into, readonly=True)), reference[1])


# ------------------------------------------------------------------------------------ check tells the whole truth
def test_a_session_whose_tail_was_deleted_checks_sound_but_incomplete(reference, tmp_path, capsys):
    # issue 27: deleting the last measurements and campaign_done (no rehash needed: the chain is a prefix) checked
    # "sound" with nothing saying that planned measurements are missing
    d = copy_of(reference[0], tmp_path)
    planned = len(reference[1])  # the reference measured every planned measurement (test_hardware: none skipped)
    assert main(["check", str(d)]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert f"campaign complete: {planned} of {planned} planned measurements stored, 0 skipped" in out
    with sqlite3.connect(d / "session.sqlite") as db:
        (third_last,) = db.execute("SELECT id FROM events WHERE kind = 'measurement' ORDER BY id DESC LIMIT 1 OFFSET 2")
        db.execute("DELETE FROM events WHERE id >= ?", third_last)
    assert main(["check", str(d)]) == 0  # the prefix of a chain is a chain: the truth is in the counts
    out = " ".join(capsys.readouterr().out.split())
    assert (
        f"campaign incomplete (it has not reached its end): {planned - 3} of {planned} planned measurements "
        f"stored, 0 skipped, 3 not measured yet"
    ) in out
    assert main(["export", str(d), "--csv", str(tmp_path / "t.csv")]) == 0
    first = " ".join(capsys.readouterr().out.split())
    assert first.startswith(f"note: {d}: campaign incomplete")  # export says so in its first line


def test_report_of_an_incomplete_session_says_so_in_its_first_line(reference, tmp_path, capsys):
    # issue 27: "`export` and `report` of an incomplete session say so in their first line" (export: above)
    d = copy_of(reference[0], tmp_path)
    with sqlite3.connect(d / "session.sqlite") as db:
        db.execute("DELETE FROM events WHERE kind = 'campaign_done'")
    main(["report", str(d)])  # not analysed either: that is its error, on stderr, after the note
    out = capsys.readouterr().out
    assert " ".join(out.split()).startswith(f"note: {d}: campaign incomplete (it has not reached its end)")


def test_a_campaign_that_measured_nothing_ends_with_exit_code_3(kr270, plan, tmp_path, monkeypatch, capsys):
    # issue 27: 48 of 48 measurements skipped ended "complete" with exit 0 (README: exit codes)
    monkeypatch.setattr(World, "measure", lambda self: (_ for _ in ()).throw(NotVisible("covered")))
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", 3)
    result = run_stored(store, inproc_live(kr270)[1])
    assert result.exit_status == "success" and result.measured == 0  # the engine went through every step
    assert campaign_exit(store, completeness(store)) == 3
    assert campaign_exit(store, run_completeness(result, kr270)) == 3  # what `trackcal run` decides it from
    assert "it measured nothing" in capsys.readouterr().err


def test_a_campaign_may_skip_the_cells_share_and_no_more(kr270, plan, tmp_path, monkeypatch):
    # the cell's max_skipped_share (calib.model.cell.MAX_SKIPPED_SHARE: rho0 at most 10 % worse, 1 - 1/1.1^2); the
    # reflector on P1 covered at S1: that block is skipped, every other measured
    original = World.measure

    def covered_at_s1(self):
        if (self.station, self.point) == ("S1", "P1"):
            raise NotVisible("covered")
        return original(self)

    monkeypatch.setattr(World, "measure", covered_at_s1)
    for share, code in ((0.0, 3), (1.0, 0)):
        cell = tmp_path / f"cell-{share}.yaml"
        cell.write_text((ROOT / "configs" / "cells" / "kr270.yaml").read_text() + f"max_skipped_share: {share}\n")
        store, _ = new_session(tmp_path / f"s{share}", str(cell), plan, "sim", 3)
        result = run_stored(store, inproc_live(kr270)[1])
        done = completeness(store)
        assert 0 < done.skipped < done.planned and done.measured + done.skipped == done.planned
        assert run_completeness(result, load_cell(str(cell))) == done  # the run's counts are the session's
        assert campaign_exit(store, done) == code


def console_reading(monkeypatch, answers: str) -> ConsoleOperator:
    monkeypatch.setattr(sys, "stdin", io.StringIO(answers))
    return ConsoleOperator(Console(file=io.StringIO()))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.text().filter(lambda s: s.strip().lower() not in ("done", "resume")), min_size=5, max_size=5))
def test_garbage_on_the_console_never_acknowledges(answers):
    """Issue 27, finding 6: any line used to acknowledge. Random text and the other prompt's word are refused;
    5 wrong answers in a row (ConsoleOperator's max_wrong) are an operator who is not there."""
    lines = "".join(a.replace("\n", " ").replace("\r", " ") + "\n" for a in answers)
    for kind in ("change_station", "move_reflector", "resume"):
        with pytest.MonkeyPatch.context() as mp, pytest.raises(ConnectionLost, match="5 answers in a row"):
            console_reading(mp, lines + "done\nresume\n").ask(kind, "S1", "do it")


@settings(max_examples=40, deadline=None)
@given(st.binary(min_size=1, max_size=200))
def test_random_bytes_on_the_console_never_acknowledge(noise):
    """Bytes as a terminal or a pipe delivers them (UTF-8 decoded strictly, as Python's stdin does)."""
    stdin = io.TextIOWrapper(io.BytesIO(noise.replace(b"\n", b" ") + b"\n" * 5), encoding="utf-8")
    with pytest.MonkeyPatch.context() as mp, pytest.raises(ConnectionLost, match="5 answers in a row|end of input"):
        mp.setattr(sys, "stdin", stdin)  # undecodable bytes may end what the decoder can read: end of input
        ConsoleOperator(Console(file=io.StringIO())).ask("resume", "", "leave the cell")


def test_the_console_acknowledges_the_exact_word_only(monkeypatch):
    assert console_reading(monkeypatch, "\n  Done \n").ask("change_station", "S1", "move the tracker") == "console"
    assert console_reading(monkeypatch, "y\nok\nresume\n").ask("resume", "", "leave the cell") == "console"
    with pytest.raises(ConnectionLost, match="not 'resume'"):  # "done" does not release the robot
        console_reading(monkeypatch, "done\n" * 5 + "resume\n").ask("resume", "", "leave the cell")


def test_wrong_answers_stop_the_campaign_safely_and_resume_asks_again(kr270, plan, tmp_path, monkeypatch):
    store, _ = new_session(tmp_path / "s", "kr270", plan, "sim", 3)
    operator = console_reading(monkeypatch, "done\n" + "done\n" * 5)  # the station set, then "done" to resume
    assert_stopped(run_stored(store, inproc_live(kr270, operator=operator)[1]), "5 answers in a row were not")
    assert not [e for e in store.events("call") if e.data["op"] == "move"]  # nothing moved unacknowledged
    assert len(store.events("operator")) == 1  # only the station prompt was acknowledged
    prompts = len(store.events("prompt"))
    operator = console_reading(monkeypatch, "")  # resume: the prompts are asked again
    assert_stopped(run_stored(store, inproc_live(kr270, store=store, operator=operator)[1]), "end of input")
    assert len(store.events("prompt")) > prompts
