"""The operator's page in a real browser (issue 22): Playwright for Python driving Debian's chromium (headless,
no `playwright install`: .ci/run installs chromium). A whole `run --sim --operator web` campaign answered from
the page alone, with a reload in the middle and a second browser watching; the door opened in the mock PLC while
the page shows a prompt; kill -9 of the campaign and its resume (slow). Screenshots at tablet (1024x768) and
phone (390x844) size at three moments go into the test's output folder (printed)."""

import json
import os
import signal
import subprocess
import threading
import time

import numpy as np
import pytest

from tests.helpers import ROOT, TRACKCAL, feasible_plan, inproc_live, placed_residuals
from trackcal.campaign.cells.sim import free_port
from trackcal.campaign.jobs.campaign import OperatorConsole, new_session, open_cell, run_session, run_stored
from trackcal.campaign.session.session import export_table
from trackcal.campaign.session.store import SessionStore
from trackcal.campaign.web.server import WebPage

playwright_api = pytest.importorskip("playwright.sync_api")

CHROMIUM = "/usr/bin/chromium"
# off the network and out of any profile, as tests/test_report.py runs it
ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
TABLET, PHONE = {"width": 1024, "height": 768}, {"width": 390, "height": 844}


@pytest.fixture(scope="module")
def browser():
    if not os.path.exists(CHROMIUM):
        if os.environ.get("CI") == "true":
            pytest.fail("chromium is missing in CI: .ci/run installs Debian's chromium")
        pytest.skip("chromium is not installed (apt-get install chromium; CI installs it)")
    with playwright_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture(scope="module")
def plan(kr270, tmp_path_factory):
    """Three poses seen from both stations: 27 measurements, 16 prompts (a few seconds on the twin)."""
    path = tmp_path_factory.mktemp("plan") / "plan.json"
    path.write_text(json.dumps(feasible_plan(kr270, 3, seed=11, repeat=1)))
    return path


def start_run(plan, session, port, *extra, operator="web"):
    cmd = [
        *TRACKCAL,
        "run",
        "--cell",
        "kr270",
        "--plan",
        str(plan),
        "--sim",
        "--seed",
        "2",
        "--session",
        str(session),
        "--no-analysis",
        *extra,
    ]
    if operator == "web":
        cmd += ["--operator", "web", "--web-port", str(port)]
    return subprocess.Popen(
        cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT
    )


def open_page(context, url, timeout_s=60.0):
    page = context.new_page()
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            page.goto(url)
            break
        except playwright_api.Error:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)
    wait_until(page, "#status", lambda t: t != "connecting…")
    return page


def wait_until(page, selector, ok, timeout_s=30.0) -> str:
    """Poll the text of `selector` until ok(text) (no wait_for_function: the page's policy forbids eval)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = page.locator(selector).text_content()
        if ok(value):
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"{selector}: {value!r}")
        time.sleep(0.05)


def click_next(page, timeout_ms=1000) -> bool:
    """Press the answer button once it is enabled; False if it did not become enabled in time."""
    try:
        page.wait_for_selector("#answer:enabled", timeout=timeout_ms)
    except playwright_api.TimeoutError:
        return False
    page.click("#answer")
    return True


def text(page, selector):
    return page.locator(selector).text_content()


def shoot(pages, folder, moment):
    for name, page in pages.items():
        path = folder / f"{moment}-{name}.png"
        page.screenshot(path=str(path), full_page=True)
        # a full-page screenshot is as wide as the page: wider than the screen, something sticks out (cut)
        width = int.from_bytes(path.read_bytes()[16:20], "big")  # PNG: the IHDR chunk's width (RFC 2083, 4.1.1)
        assert width == page.viewport_size["width"], f"{path.name}: the page is {width} px wide on a narrower screen"


def residual_bars(page) -> list[tuple[str, int, list[float]]]:
    """(station, step, residual mm) of every bar of the residual plot."""
    return [
        (
            b.get_attribute("data-station"),
            int(b.get_attribute("data-step")),
            [float(x) for x in b.get_attribute("data-d").split(",")],
        )
        for b in page.locator("#fits rect").all()
    ]


def test_a_whole_campaign_answered_from_the_page_alone(browser, plan, kr270, tmp_path):
    shots = tmp_path / "screenshots"
    shots.mkdir()
    print(f"\nscreenshots in {shots}")
    port = free_port()
    reference = start_run(plan, tmp_path / "console", 0, operator="console")  # the simulated person's button
    proc = start_run(plan, tmp_path / "web", port)
    tablet = browser.new_context(viewport=TABLET)
    phone = browser.new_context(viewport=PHONE)  # a second browser: it watches
    try:
        page = open_page(tablet, f"http://127.0.0.1:{port}/")
        watcher = open_page(phone, f"http://127.0.0.1:{port}/")
        assert text(page, "#control") == "you have control"
        assert text(watcher, "#control") == "watching (read-only)"
        page.wait_for_selector("#answer:enabled", timeout=60000)
        assert text(page, "#sentence") == "Set up the tracker at station S1"
        assert watcher.locator("#answer").is_disabled()
        wait_until(watcher, "#sentence", lambda t: "station S1" in t)
        shoot({"tablet": page, "phone": watcher}, shots, "1-first-prompt")
        clicks, reloaded = 0, False
        while proc.poll() is None:
            if click_next(page):
                clicks += 1
            if clicks == 9 and not reloaded:  # in the middle: the page comes back from the session
                # S1's block ended before the prompt to set up S2: its residuals are on the page, S2's not yet
                s1 = wait_until(page, "#fit-list", lambda t: t.startswith("S1: rms"))
                assert len(residual_bars(page)) == 9 and "S2" not in s1  # 3 poses x 3 points seen from S1
                assert "after its block" in text(page, "#fits")
                before = text(page, "#counts")
                page.reload()
                wait_until(page, "#status", lambda t: t == "running")
                assert text(page, "#control") == "you have control"  # the tab keeps its client id
                assert int(text(page, "#counts").split()[0]) >= int(before.split()[0])
                assert text(page, "#fit-list") == s1 and len(residual_bars(page)) == 9  # rebuilt from the session
                now = text(page, "#counts")
                wait_until(watcher, "#counts", lambda t, now=now: t == now)
                shoot({"tablet": page, "phone": watcher}, shots, "2-after-reload")
                reloaded = True
        out = proc.stdout.read()
        assert proc.wait() == 0, out[-3000:]
        assert reloaded and clicks == 16, clicks  # every prompt: 2 stations, 6 reflector moves, each then resumed
        for p in (page, watcher):
            wait_until(p, "#status", lambda t: "complete" in t)
            assert text(p, "#counts") == "27 measured, 0 skipped of 27"
            wait_until(p, "#fit-list", lambda t: "S2: rms" in t)
        shoot({"tablet": page, "phone": watcher}, shots, "3-complete")
        bars, shown = residual_bars(page), page.locator("#fit-list li").all_text_contents()
    finally:
        tablet.close()
        phone.close()
        for p in (proc, reference):
            if p.poll() is None:
                p.kill()
    assert reference.wait(timeout=120) == 0
    web, console = (
        SessionStore.open(tmp_path / "web", readonly=True),
        SessionStore.open(tmp_path / "console", readonly=True),
    )
    answers = [e.data["answer"] for e in web.events("operator")]
    assert len(answers) == 16 and all(a.startswith("page ") and a.endswith("from 127.0.0.1") for a in answers)
    a, b = export_table(web), export_table(console)
    assert a.pose == b.pose and a.station == b.station and a.point == b.point
    assert (a.xyz == b.xyz).all() and (a.q_deg == b.q_deg).all() and (a.t_s == b.t_s).all()
    # the residual plot equals the station placed independently on the session's table, bar by bar
    steps = [e.step for e in web.events("measurement")]
    for k, sid in enumerate(("S1", "S2")):
        rows = [i for i, s in enumerate(a.station) if s == sid]
        expected = placed_residuals(kr270, a, rows)
        drawn = {step: d for station, step, d in bars if station == sid}
        assert sorted(drawn) == sorted(steps[i] for i in rows)
        np.testing.assert_allclose([drawn[steps[i]] for i in rows], expected, atol=2e-4)  # rounded to 0.1 um
        norms = np.linalg.norm(expected, axis=1)
        assert shown[k] == (
            f"{sid}: rms {np.sqrt(np.mean(norms**2)):.3f} mm, max {norms.max():.3f} mm "
            f"({len(rows)} of {len(rows)} measured)"
        )


def test_the_door_opened_while_the_page_shows_a_prompt(browser, kr270, tmp_path):
    """The page shows the door open; its answer reaches the engine, whose interlock keeps the robot still."""
    plan = feasible_plan(kr270, 3, seed=11, repeat=1)
    web = WebPage("127.0.0.1", 0, say=lambda text: None, out=lambda text: None)
    result, ready = {}, threading.Event()

    def campaign_thread():  # the session's store lives in the thread that made it (sqlite)
        store, campaign = new_session(tmp_path / "s", "kr270", plan, "sim", 2)
        try:
            live = open_cell(store, campaign, OperatorConsole(say=lambda text: None, operator=None), page=web)
            result["sim"] = live.close.__self__  # the SimCell: its mock PLC and its simulated person
            ready.set()
            result["r"] = run_session(store, campaign, live, (), web)
        finally:
            ready.set()
            store.close()

    run = threading.Thread(target=campaign_thread)
    run.start()
    assert ready.wait(120) and "sim" in result
    sim = result["sim"]
    context = browser.new_context(viewport=TABLET)
    try:
        page = open_page(context, f"http://127.0.0.1:{web.port}/")
        assert click_next(page, 60000)  # set up the tracker at S1
        wait_until(page, "#sentence", lambda t: t.startswith("Leave the cell"))
        page.wait_for_selector("#answer:enabled", timeout=30000)
        wait_until(page, "#c-door", lambda t: t == "Door closed")
        sim.plc.open_door()  # someone opens the door while the page asks to resume
        wait_until(page, "#c-door", lambda t: t == "Door OPEN")
        assert "door OPEN" in text(page, "#drawing")
        page.click("#answer")
        wait_until(page, "#warnings", lambda t: "the cell door is open: motion stays blocked" in t)
        page.wait_for_selector("#answer:enabled", timeout=30000)  # asked again (the person closed it meanwhile)
        assert text(page, "#sentence").startswith("Leave the cell")
        kinds = [(e.kind, e.data.get("device"), e.data.get("op")) for e in web.hub.events]
        answered = [i for i, k in enumerate(kinds) if k[0] == "operator"]
        assert ("call", "robot", "move") not in kinds[answered[0] :], "the robot moved after the page's answer"
        while run.is_alive():  # the rest of the campaign, answered from the page
            click_next(page, 300)
        wait_until(page, "#status", lambda t: "complete" in t)
    finally:
        context.close()
        run.join(timeout=120)
        web.close()
    assert result["r"].exit_status == "success"


def test_a_replay_served_on_the_page_shows_the_recorded_campaign(browser, plan, kr270, tmp_path):
    """`replay --operator web`: the page watches the replay (its answers are the recording's: nothing to answer)
    and, while it lingers, shows the replayed campaign's final state, its station fits included."""
    recording = tmp_path / "recording"
    store, _ = new_session(recording, "kr270", json.loads(plan.read_text()), "sim", 3)
    try:
        assert run_stored(store, inproc_live(kr270)[1]).exit_status == "success"  # in-process: a second or two
    finally:
        store.close()
    port, into = free_port(), tmp_path / "replay"
    proc = subprocess.Popen(
        [
            *TRACKCAL,
            "replay",
            str(recording),
            "--into",
            str(into),
            "--operator",
            "web",
            "--web-port",
            str(port),
            "--web-linger",
            "120",
        ],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=ROOT,
    )
    context = browser.new_context(viewport=PHONE)
    try:
        page = open_page(context, f"http://127.0.0.1:{port}/")
        wait_until(page, "#status", lambda t: t == "complete")
        assert text(page, "#counts") == "27 measured, 0 skipped of 27"
        assert text(page, "#sentence") == "The campaign is complete." and page.locator("#answer").is_disabled()
        # nobody has control of a replay: its recording answers (the page said "you have control" before)
        assert text(page, "#control") == "replay: the recording answers" and page.locator("#take").is_hidden()
        page.wait_for_selector("#outcome-card:not([hidden])", timeout=10000)
        assert text(page, "#outcome").startswith(f"Replayed into {into}") and page.locator("#report").is_hidden()
        assert (into / "table.csv").is_file()  # exported before the page lingers
        shown = page.locator("#fit-list li").all_text_contents()
        shoot({"phone": page}, tmp_path, "replay")
        proc.send_signal(signal.SIGINT)  # ends the lingering
        assert proc.wait(timeout=30) == 0, proc.stdout.read()[-3000:]
        assert "replayed 27 measurements into" in proc.stdout.read()
    finally:
        context.close()
        if proc.poll() is None:
            proc.kill()
    rec, rep = SessionStore.open(recording, readonly=True), SessionStore.open(into, readonly=True)
    # the prompts and their answers are the recording's, replayed; the fits are made again, the same
    assert [e.data for e in rep.events("operator")] == [e.data for e in rec.events("operator")]
    fits = [e.data for e in rec.events("station_fit")]
    assert [e.data for e in rep.events("station_fit")] == fits and len(fits) == 2
    assert shown == [
        f"{f['station']}: rms {f['rms_mm']:.3f} mm, max {f['max_mm']:.3f} mm ({f['measured']} of "
        f"{f['planned']} measured)"
        for f in fits
    ]


@pytest.fixture(scope="module")
def identifiable_plan(kr270, tmp_path_factory):
    """Ten poses in two passes (tests/test_campaign_cli.py): enough to identify, so the run ends in a report."""
    path = tmp_path_factory.mktemp("plan") / "plan.json"
    path.write_text(json.dumps(feasible_plan(kr270, 10, seed=11, repeat=2)))
    return path


@pytest.mark.slow
def test_kill_9_leaves_a_page_that_says_so_and_resume_brings_it_back(browser, identifiable_plan, tmp_path):
    plan = identifiable_plan
    port = free_port()
    session = tmp_path / "web"
    proc = start_run(plan, session, port)
    context = browser.new_context(viewport=PHONE)
    try:
        page = open_page(context, f"http://127.0.0.1:{port}/")
        clicks = 0
        while clicks < 7:
            clicks += click_next(page, 60000)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        wait_until(page, "#status", lambda t: t == "campaign stopped: trackcal is not running", timeout_s=15)
        assert "not running" in text(page, "#sentence") and page.locator("#answer").is_disabled()
        page.screenshot(path=str(tmp_path / "killed-phone.png"), full_page=True)
        resumed = subprocess.Popen(
            [*TRACKCAL, "resume", str(session), "--operator", "web", "--web-port", str(port), "--web-linger", "120"],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            cwd=ROOT,
        )
        wait_until(page, "#status", lambda t: t == "running", timeout_s=60)  # the page reconnects by itself
        assert text(page, "#control") == "you have control"
        while "complete" not in text(page, "#status"):
            assert resumed.poll() is None, resumed.stdout.read()[-3000:]
            click_next(page, 500)
        counts = text(page, "#counts").split()  # "N measured, S skipped of P"
        assert int(counts[0]) + int(counts[2]) == int(counts[-1]) > 24
        assert "resuming at step" in text(page, "#warnings")
        # each block's residuals once, whichever run measured it (a block the kill cut is placed when it ends)
        fits = page.locator("#fit-list li").all_text_contents()
        assert [f.split(":")[0] for f in fits] == ["S1", "S2"] and all(": rms " in f for f in fits), fits
        # the analysis: the report's outcome sentence and a link to the report, served while the page lingers
        page.wait_for_selector("#outcome-card:not([hidden])", timeout=180000)
        assert text(page, "#outcome").startswith("The ")
        report = page.request.get(f"http://127.0.0.1:{port}" + page.locator("#report").get_attribute("href"))
        assert report.status == 200 and "id='verdict'" in report.text()
        assert "sandbox" in report.headers["content-security-policy"]
        page.screenshot(path=str(tmp_path / "outcome-phone.png"), full_page=True)
        resumed.send_signal(signal.SIGINT)  # ends the lingering
        assert resumed.wait(timeout=30) == 0, resumed.stdout.read()[-3000:]
        proc = resumed
    finally:
        context.close()
        for p in (proc,):
            if p.poll() is None:
                p.kill()
