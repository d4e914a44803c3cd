"""`trackcal run | resume | replay | export`: campaigns on the shop floor or on the simulated cell."""

from __future__ import annotations

import json
from pathlib import Path

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from calib.diagnose import diagnose
from calib.identify import IdentificationError
from calib.noise import TrackerNoise
from calib.table import read_table

from .console import console
from .devices import SimCell
from .diagnose_report import verdict_doc
from .engine import CampaignStopped
from .hardware import connect_hardware, load_hardware
from .jobs import UsageError, choose_params, parse_effects, run_identify
from .recording import ReplayDivergence
from .report import write_report
from .runner import replay_session, run_campaign
from .session import create_session, session_cell, session_plan, write_export
from .steps import PlanError
from .store import SessionStore, StoreError

HARDWARE_COPY = "config/hardware.yaml"  # a hardware session's copy of its hardware config (resume reads it)


def _progress():
    bar = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                   TextColumn("next: {task.fields[next]}"), console=console, transient=False)  # fmt: skip
    task = bar.add_task("measurements", total=None, next="")

    def update(done: int, total: int, nxt: str) -> None:
        bar.update(task, completed=done, total=total, next=nxt or "-")

    return bar, update


def _live_for(store: SessionStore):
    meta = store.meta()
    cell = session_cell(store)
    if meta["mode"] == "sim":
        effects = json.loads(meta.get("effects", "{}") or "{}")
        speed = float(meta["sim_speed"]) if meta.get("sim_speed") else None
        return SimCell(cell, int(meta["seed"] or 0), store, effects, speed).live
    if meta["mode"] == "hardware":
        copy = store.directory / HARDWARE_COPY
        hw = load_hardware(copy)
        try:
            return connect_hardware(hw, cell)
        except UsageError as exc:
            raise UsageError(f"{exc}\n(the session uses its copy {copy}: fix the cell or that file, then "
                             f"`trackcal resume {store.directory}`)") from None
    raise UsageError(f"{store.directory}: a {meta['mode']} session cannot be run live")


def drive(store: SessionStore) -> None:
    bar, update = _progress()
    try:
        with bar:
            run_campaign(store, _live_for(store), progress=update)
    except CampaignStopped as exc:
        raise UsageError(f"{exc}. Fix the cause, then: trackcal resume {store.directory}") from None


def analyse(store: SessionStore) -> None:
    """End of a campaign: export, identification, diagnosis, into the session directory."""
    d = store.directory
    n = write_export(store, d / "table.csv")
    cell = session_cell(store)
    table = read_table(d / "table.csv", n_joints=cell.chain.dof)
    params = choose_params(cell, None)
    try:
        outcome = run_identify(cell, table, params, "tracker")
        (d / "model.json").write_text(json.dumps(outcome.doc, indent=2) + "\n")
        dg = diagnose(cell.chain, table, cell.tool_points, params, TrackerNoise())
        verdict = verdict_doc(cell, dg)
        (d / "verdict.json").write_text(json.dumps(verdict, indent=2) + "\n")
    except IdentificationError as exc:
        console.print(f"[yellow]identification not possible yet[/]: {exc}")
        return
    report = write_report(d / "report", cell, table, outcome.doc, session_plan(store), verdict,
                          f"trackcal campaign {d.name}: cell {cell.name}", diagnosis=dg)  # fmt: skip
    after = outcome.doc["residuals"]["after"]
    console.print(f"{n} measurements -> {d / 'table.csv'}; model {d / 'model.json'} (coordinate RMS "
                  f"{after['coord_rms_mm'] * 1000:.1f} um); diagnosis: {dg.cause} ({d / 'verdict.json'}); "
                  f"report {report}")  # fmt: skip


def cmd_run(args) -> int:
    if bool(args.sim) == bool(args.hardware):
        raise UsageError("give exactly one of --sim or --hardware FILE")
    try:
        plan_doc = json.loads(Path(args.plan).read_text())
    except OSError as exc:
        raise UsageError(f"{args.plan}: cannot read ({exc.strerror})") from None
    except ValueError as exc:
        raise UsageError(f"{args.plan}: not a JSON plan ({exc})") from None
    if args.hardware and (args.effect or args.sim_speed is not None):
        raise UsageError("--effect and --sim-speed are for --sim only (with hardware: `trackcal mock`)")
    effects = parse_effects(args.effect) if args.sim else {}
    mode, seed = ("sim", args.seed) if args.sim else ("hardware", None)
    if args.sim_speed is not None and not args.sim_speed > 0:
        raise UsageError("--sim-speed must be positive (simulated seconds per real second)")
    extra = {"sim_speed": str(args.sim_speed)} if args.sim and args.sim_speed else {}
    if args.hardware:
        return _campaign(lambda: _hardware_session(Path(args.session), args.cell, plan_doc, args.hardware),
                         args.no_analysis)  # fmt: skip
    return _campaign(lambda: create_session(Path(args.session), args.cell, plan_doc, mode, seed, effects=effects,
                                            extra=extra), args.no_analysis)  # fmt: skip


def _hardware_session(directory: Path, cell_ref: str, plan_doc: dict, hardware: str) -> SessionStore:
    """A new session that keeps a copy of the hardware config (validated first: a broken file makes no session)."""
    try:
        text = Path(hardware).read_text()
    except OSError as exc:
        raise UsageError(f"{hardware}: cannot read the hardware config ({exc.strerror})") from None
    load_hardware(hardware, text)
    store = create_session(directory, cell_ref, plan_doc, "hardware", None,
                           hardware={"file": HARDWARE_COPY, "source": str(Path(hardware).resolve())})  # fmt: skip
    try:
        (directory / HARDWARE_COPY).write_text(text)
    except OSError as exc:
        raise UsageError(f"{directory / HARDWARE_COPY}: cannot write ({exc.strerror})") from None
    return store


def cmd_resume(args) -> int:
    return _campaign(lambda: SessionStore.open(args.session), args.no_analysis)


def _campaign(open_store, no_analysis: bool) -> int:
    try:
        store = open_store()
        if store.events("campaign_done"):
            console.print(f"{store.directory}: the campaign is already complete")
        else:
            drive(store)
    except (StoreError, PlanError) as exc:
        raise UsageError(str(exc)) from None
    if not no_analysis:
        analyse(store)
    return 0


def cmd_replay(args) -> int:
    try:
        recording = SessionStore.open(args.session, readonly=True)
        plan_doc = json.loads(Path(args.plan).read_text()) if args.plan else None
        store = replay_session(recording, Path(args.into), args.cell, plan_doc)
    except (StoreError, PlanError, OSError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    except ReplayDivergence as exc:
        raise UsageError(f"replay diverges from the recording at {exc}") from None
    n = write_export(store, Path(args.into) / "table.csv")
    console.print(f"replayed {n} measurements into {args.into} (the recording is unchanged)")
    return 0


def cmd_export(args) -> int:
    try:
        n = write_export(SessionStore.open(args.session, readonly=True), Path(args.csv))
    except StoreError as exc:
        raise UsageError(str(exc)) from None
    except OSError as exc:
        raise UsageError(f"{args.csv}: cannot write ({exc.strerror})") from None
    console.print(f"{n} measurements written to {args.csv}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("run", help="run a measurement campaign (simulated cell or hardware)")
    p.add_argument("--cell", required=True)
    p.add_argument("--plan", required=True, help="plan.json from `trackcal plan`")
    p.add_argument("--sim", action="store_true", help="the digital twin's cell")
    p.add_argument("--hardware", help="hardware config (configs/hardware/README.md); copied into the session")
    p.add_argument("--seed", type=int, default=1, help="--sim: the twin's seed")
    p.add_argument("--effect", action="append", help="--sim: hidden effect NAME:MAGNITUDE_MM")
    p.add_argument("--sim-speed", type=float, help="--sim: simulated seconds per real second (default: flat out)")
    p.add_argument("--session", required=True, help="session directory to create")
    p.add_argument("--no-analysis", action="store_true", help="skip identification and diagnosis at the end")
    p.set_defaults(func=cmd_run)
    p = sub.add_parser("resume", help="continue an interrupted campaign")
    p.add_argument("session")
    p.add_argument("--no-analysis", action="store_true")
    p.set_defaults(func=cmd_resume)
    p = sub.add_parser("replay", help="re-run a recorded campaign into a new session")
    p.add_argument("session")
    p.add_argument("--into", required=True)
    p.add_argument("--cell", help="replay with this cell instead of the recorded one")
    p.add_argument("--plan", help="replay with this plan instead of the recorded one")
    p.set_defaults(func=cmd_replay)
    p = sub.add_parser("export", help="the measurement table of a session")
    p.add_argument("session")
    p.add_argument("--csv", required=True)
    p.set_defaults(func=cmd_export)
