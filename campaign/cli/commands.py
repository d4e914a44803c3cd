"""The command table of `trackcal`: every command, its options and the function that runs it.

A handler is "module:function" and takes the parsed arguments; its module is imported only when the command
runs (campaign.cli.main), so `trackcal --help` and the light commands load neither pinocchio nor matplotlib.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field

from trackcal.calib.identify.noise import DEFAULT_WEIGHTING, WEIGHTINGS
from trackcal.campaign.importers.ipa_ur10 import DEFAULT_PERIOD_S, VIRTUAL_DIRECTIONS

CAUSE_HELP = (
    "none (purely geometric), auto (diagnose's choice) or a cause: joint_compliance, backlash, "
    "encoder_scale, cyclic_error, thermal_drift, station_shift, thermal_warmup, "
    "payload_compliance"
)
TABLE_HELP = "measurement table (CSV: seq,t_s,pose,station,point,q1_deg..qn_deg,x_mm,y_mm,z_mm)"
CELL_HELP = "cell name (configs/cells/NAME.yaml) or path"
WEIGHTING_HELP = (
    "the radial/transverse noise model of the cell's tracker (cell key tracker:, default the AT901; "
    "calib/model/instruments.py), or i.i.d. least squares"
)
TABLE_CELL_HELP = CELL_HELP + ", or a robot YAML/URDF alone (the reference points are then the table's)"
EFFECT_HELP = "hidden effect NAME:MAGNITUDE_MM, a cause of `trackcal diagnose` (repeatable)"
TRUTH_HELP = (
    "JSON of the twin's truth to write: parameter deviations, stations, points, hidden effects, the true "
    "reflector positions at the cell's test pose"
)
ACCEPT_EDITED = (
    "--accept-edited",
    {
        "action": "store_true",
        "help": "use a model whose digest does not match its "
        "content (edited by hand); its units, physical bounds and covariance are checked all the same",
    },
)
ACCEPT_POOR = (
    "--accept-poor",
    {
        "action": "store_true",
        "help": "use a model marked unusable (parameters poorly "
        "determined by its table, or a TCP uncertainty above the uncalibrated error)",
    },
)


def arg(*flags: str, **options) -> tuple[tuple[str, ...], dict]:
    return flags, options


BATCH_ARGS = [
    arg(
        "inputs",
        nargs="+",
        metavar="INPUT",
        help="measurement tables, session folders, or folders holding either (one level down)",
    ),
    arg(
        "--out",
        required=True,
        help="results folder: one JSON per campaign, keyed by the table's sha256; a result "
        "already there is not computed again",
    ),
    arg("--cell", help=CELL_HELP + " of plain tables (default: none; a session knows its cell)"),
    arg("--params", help="parameters (default: the irreducible set)"),
    arg("--weighting", choices=WEIGHTINGS, default=DEFAULT_WEIGHTING, help=WEIGHTING_HELP),
    arg("--scheduler", help="Dask scheduler address (default: a local process pool)"),
]


def seed(text: str) -> int:
    """A seed option: numpy's generators take whole numbers from 0 (a negative one was a traceback)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number from 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a whole number from 0, got {text}")
    return value


@dataclass(frozen=True)
class Command:
    name: str
    help: str
    handler: str  # "module:function"
    args: list[tuple[tuple[str, ...], dict]] = field(default_factory=list)
    group: str | None = None  # `trackcal GROUP NAME` (e.g. import ipa-ur10)
    description: str | None = None


# `--operator web`: the operator's page beside the console (campaign/web; docs/reference/operator-page.md)
OPERATOR_ARGS = [
    arg(
        "--operator",
        choices=("console", "web"),
        default="console",
        help="web: also serve the operator's page (the first answer from page, console or cell button wins)",
    ),
    arg(
        "--web-host",
        help="--operator web: address to listen on, default 127.0.0.1 (any other needs the token "
        "that the console prints)",
    ),
    arg("--web-port", type=int, help="--operator web: port, default 8470 (0: a free one)"),
    arg(
        "--web-linger",
        type=float,
        default=0.0,
        help="--operator web: seconds the page stays up after the analysis (replay: after the replay), with the "
        "outcome and the report",
    ),
]

GROUPS = {
    "import": "convert third-party measurement files into a measurement table",
    "batch": "identify, diagnose or ISO-test many campaigns at once, and Monte-Carlo checks, on a process pool or a "
    "Dask cluster",
    "iso9283": "the ISO 9283 acceptance test: plan it, then compare the figures before and after compensation",
}

COMMANDS = [
    Command(
        "identify",
        "identify robot parameters, stations and points from a measurement table",
        "trackcal.campaign.cli.analysis:cmd_identify",
        [
            arg("data", help=TABLE_HELP),
            arg("--cell", required=True, help=TABLE_CELL_HELP),
            arg("--params", help="comma-separated parameter names (default: the irreducible set)"),
            arg("--weighting", choices=WEIGHTINGS, default=DEFAULT_WEIGHTING, help=WEIGHTING_HELP),
            arg("--extend", default="none", help=CAUSE_HELP),
            arg("--out", required=True, help="model.json to write"),
            arg(
                "--json",
                help="summary JSON to write (residuals, fit against the noise floor, parameters) "
                "(default: not written)",
            ),
        ],
    ),
    Command(
        "diagnose",
        "what the geometric model gets wrong: the physical cause and the gain",
        "trackcal.campaign.cli.diagnose:cmd_diagnose",
        [
            arg("data", help=TABLE_HELP),
            arg("--cell", required=True, help=TABLE_CELL_HELP),
            arg("--params", help="geometric parameters (default: the irreducible set)"),
            arg("--weighting", choices=WEIGHTINGS, default=DEFAULT_WEIGHTING, help=WEIGHTING_HELP),
            arg("--folds", type=int, default=5, help="cross-validation folds (whole poses held out)"),
            arg("--seed", type=seed, default=0, help="seed of the assignment of poses to folds"),
            arg("--plots", help="directory for the residual plots (default: no plots)"),
            arg("--json", required=True, help="verdict JSON to write"),
            arg("--out", help="model.json of the chosen model to write, usable by predict (default: not written)"),
        ],
    ),
    Command(
        "predict",
        "predict reflector positions with a model",
        "trackcal.campaign.cli.analysis:cmd_predict",
        [
            arg("rows", help="CSV with the measurement-table columns (x,y,z optional, ignored)"),
            arg("--model", required=True, help="model.json from identify or diagnose"),
            arg("--out", required=True, help="CSV to write: the rows with x_mm, y_mm, z_mm predicted"),
            arg(ACCEPT_EDITED[0], **ACCEPT_EDITED[1]),
        ],
    ),
    Command(
        "locate",
        "place a tracker station that moved: fit only the station, the robot model held",
        "trackcal.campaign.cli.analysis:cmd_locate",
        [
            arg("--model", required=True, help="model.json from identify or diagnose (held fixed)"),
            arg("--table", required=True, help=TABLE_HELP + " of the new session (at least 3 points)"),
            arg("--station", help="the table's station to locate (default: its only one)"),
            arg(
                "--as",
                metavar="NAME",
                help="the station's name in the model written (default: its id in the "
                "table; a station of that name in the model is replaced)",
            ),
            arg(
                "--poses",
                type=int,
                help="locate on the first K poses of the station (table order), hold "
                "out the rest (default: every pose)",
            ),
            arg("--out", required=True, help="model.json to write: the model plus the located station"),
            arg(
                "--predict-out",
                help="CSV of the held-out rows predicted by the new model (needs --poses; default: not written)",
            ),
            arg(ACCEPT_EDITED[0], **ACCEPT_EDITED[1]),
        ],
    ),
    Command(
        "export-urdf",
        "the calibrated geometric robot as a URDF (and what a URDF cannot hold beside it)",
        "trackcal.campaign.cli.urdf:cmd_export_urdf",
        [
            arg(
                "--model",
                help="model.json from identify or diagnose (the calibrated robot; default: none, one "
                "of --model, --cell, --robot is needed)",
            ),
            arg("--cell", help="or a cell: its nominal robot and tool points (default: none)"),
            arg("--robot", help="or a robot description: configs/robots name, robot YAML or URDF path (default: none)"),
            arg("--out", required=True, help="URDF to write; NAME.trackcal.json is written beside it"),
            arg(ACCEPT_EDITED[0], **ACCEPT_EDITED[1]),
        ],
    ),
    Command(
        "plan",
        "optimal measurement poses for the cell's test pose (or evaluate a plan)",
        "trackcal.campaign.cli.plan:cmd_plan",
        [
            arg("--cell", required=True, help=CELL_HELP),
            arg("--test-pose", help="Q1,..,Qn in degrees (default: the cell's test pose)"),
            arg(
                "--configs",
                type=int,
                help="number of distinct configurations M (default: chosen from the "
                "cell's unknowns, said in the output)",
            ),
            arg("--repeat", type=int, help="each configuration measured K times (default: 1)"),
            arg("--sigma-mm", type=float, help="--noise iid: the noise of one coordinate, mm (default: 0.01)"),
            arg(
                "--noise",
                choices=("tracker", "iid"),
                default="iid",
                help="i.i.d. --sigma-mm (the paper's), or the cell's tracker model identify weighs by (its "
                "plans put poses at the edge of a station's view: docs/reference/plan.md)",
            ),
            arg("--params", help="robot parameters the campaign identifies (default: identify's, the irreducible set)"),
            arg("--criterion", default="rho0", help="rho0 (paper eq. 34) or D, A, E for comparison"),
            arg("--no-visibility", action="store_true", help="ignore tracker stations and reflector cones"),
            arg("--seed", type=seed, default=0, help="seed of the random starting plans"),
            arg("--starts", type=int, default=1000, help="random plans of the candidate pool scored (screening)"),
            arg("--refined", type=int, default=4, help="best screened plans exchanged, then refined"),
            arg("--scheduler", help="Dask scheduler address (default: local process pool)"),
            arg(
                "--evaluate",
                help="CSV of poses (q1_deg..qn_deg, one row per measurement) to evaluate (default: search a plan)",
            ),
            arg("--csv", help="also write the plan as a CSV of rows, repetitions included (default: not written)"),
            arg("--json", default="plan.json", help="plan JSON to write"),
        ],
    ),
    Command(
        "simulate",
        "simulate a campaign of random feasible poses on the digital twin",
        "trackcal.campaign.cli.analysis:cmd_simulate",
        [
            arg("--cell", default="kr270", help=CELL_HELP),
            arg("--poses", type=int, default=30, help="random feasible poses"),
            arg("--repeat", type=int, default=1, help="each pose measured K times"),
            arg("--seed", type=seed, default=1, help="the twin's seed (its true robot, stations and noise)"),
            arg("--noise-free", action="store_true", help="no tracker noise"),
            arg("--effect", action="append", help=EFFECT_HELP + " (default: none)"),
            arg("--out", required=True, help="measurement table to write"),
            arg("--truth", help=TRUTH_HELP + " (default: not written)"),
        ],
    ),
    Command(
        "demo",
        "plan, simulated campaign, identification, diagnosis on the embedded defaults",
        "trackcal.campaign.cli.demo:cmd_demo",
        [
            arg("--cell", default="kr270", help=CELL_HELP),
            arg("--seed", type=seed, default=1, help="the twin's seed"),
            arg("--out", default="out/demo", help="directory of the plan and the session"),
        ],
    ),
    Command(
        "run",
        "run a measurement campaign (simulated cell or hardware)",
        "trackcal.campaign.cli.campaign:cmd_run",
        [
            arg("--cell", required=True, help=CELL_HELP),
            arg("--plan", required=True, help="plan.json from `trackcal plan`"),
            arg("--sim", action="store_true", help="the digital twin's cell"),
            arg(
                "--hardware",
                help="hardware config (configs/hardware/README.md); stored in the session (default: none; "
                "--sim or --hardware is needed)",
            ),
            arg("--seed", type=seed, default=1, help="--sim: the twin's seed"),
            arg("--effect", action="append", help="--sim: " + EFFECT_HELP + " (default: none)"),
            arg("--sim-speed", type=float, help="--sim: simulated seconds per real second (default: flat out)"),
            arg("--truth", help="--sim: " + TRUTH_HELP + " (default: not written)"),
            arg("--session", required=True, help="session directory to create"),
            arg("--no-analysis", action="store_true", help="skip identification, diagnosis and report at the end"),
            *OPERATOR_ARGS,
        ],
    ),
    Command(
        "resume",
        "continue an interrupted campaign",
        "trackcal.campaign.cli.campaign:cmd_resume",
        [
            arg("session", help="session directory"),
            arg("--no-analysis", action="store_true", help="skip identification, diagnosis and report at the end"),
            arg("--analyse", action="store_true", help="analyse a campaign that is already complete again"),
            *OPERATOR_ARGS,
        ],
    ),
    Command(
        "replay",
        "re-run a recorded campaign into a new session",
        "trackcal.campaign.cli.campaign:cmd_replay",
        [
            arg("session", help="session directory of the recording (never modified)"),
            arg("--into", required=True, help="new session directory for the replay"),
            arg("--cell", help="replay with this cell (default: the recorded one)"),
            arg("--plan", help="replay with this plan (default: the recorded one)"),
            *OPERATOR_ARGS,
        ],
    ),
    Command(
        "export",
        "the measurement table of a session",
        "trackcal.campaign.cli.session:cmd_export",
        [
            arg("session", help="session directory"),
            arg("--csv", required=True, help="measurement table to write"),
        ],
    ),
    Command(
        "check",
        "verify a session: database integrity, hash chain, stored plan and config",
        "trackcal.campaign.cli.session:cmd_check",
        [
            arg("session", help="session directory"),
        ],
    ),
    Command(
        "mock",
        "serve the digital twin's cell on loopback for `trackcal run --hardware`",
        "trackcal.campaign.cli.mock:cmd_mock",
        [
            arg("--cell", help=CELL_HELP + " (default: none; needed unless --stop)"),
            arg("--seed", type=seed, default=1, help="the twin's seed"),
            arg("--effect", action="append", help="hidden effect NAME[:MAGNITUDE_MM] (repeatable; default: none)"),
            arg(
                "--write-hardware",
                metavar="FILE",
                help="write the hardware config of the mocks here (default: printed on the console only)",
            ),
            arg(
                "--sim-speed",
                type=float,
                default=1.0,
                help="simulated seconds per real second (default 1: moves and measurements take the device's "
                "own time; more, e.g. 50, runs the cell faster for tests)",
            ),
            arg(
                "--detach",
                action="store_true",
                help="serve in a process of its own, returning once every server listens and the hardware file "
                "is written (its output in FILE.log)",
            ),
            arg(
                "--stop",
                metavar="FILE",
                help="stop the mock that wrote this hardware file, SIGTERM, and wait "
                "for it to exit (default: start a mock)",
            ),
            arg("--ready-fd", type=int, help=argparse.SUPPRESS),  # --detach's child reports on this pipe
        ],
    ),
    Command(
        "compensate",
        "joint targets corrected with an identified model (CSV, controller program)",
        "trackcal.campaign.cli.compensate:cmd_compensate",
        [
            arg("targets", help="CSV of nominal joint targets: q1_deg..qn_deg, optional name"),
            arg("--model", required=True, help="model.json from identify or diagnose"),
            arg("--out", required=True, help="CSV to write: the targets plus compensated angles and errors"),
            arg("--tcp", help="X,Y,Z of the TCP in the last joint frame, mm (default: tool points centroid)"),
            arg("--krl", metavar="NAME", help="also write a KR C2 program NAME.src / NAME.dat (default: none)"),
            arg(
                "--program",
                metavar="NAME",
                help="also write the program NAME of the model's robot controller, "
                "in its language (the controller family its robot config names; KRL without one) (default: "
                "none)",
            ),
            arg("--krl-dir", help="directory of the programs (default: the directory of --out)"),
            arg("--speed", type=int, default=10, help="PTP axis speed and acceleration override, %% (1-100)"),
            arg(
                "--strict",
                action="store_true",
                help="write no program when a target cannot be compensated "
                "(default: the program moves to its nominal target, under a comment saying why)",
            ),
            arg(ACCEPT_EDITED[0], **ACCEPT_EDITED[1]),
            arg(ACCEPT_POOR[0], **ACCEPT_POOR[1]),
            arg(
                "--allow-outside",
                action="store_true",
                help="also compensate targets outside the joint ranges "
                "the model's extension was fitted on, the extension held at the nearest fitted angle (default: "
                "such targets are refused, kept nominal)",
            ),
        ],
    ),
    Command(
        "filter",
        "a robot program's targets corrected for an identified model, each with its predicted "
        "accuracy (the controller family that reads its suffix)",
        "trackcal.campaign.cli.filter:cmd_filter",
        [
            arg("program", help="the program's main file (.src, .script, .mod ...: its suffix picks the reader)"),
            arg("more", nargs="*", metavar="MORE", help="the program's other files (a KRL .dat, $config.dat)"),
            arg("--model", required=True, help="model.json from identify or diagnose"),
            arg(
                "--out",
                required=True,
                help="directory of the filtered program (same file names; never an "
                "input's own) and of filter.json / filter.html",
            ),
            arg(
                "--tolerance-mm",
                type=float,
                help="each target passes when its 95 %% bound is within this (default: no pass/fail)",
            ),
            arg(
                "--strict",
                action="store_true",
                help="exit 1 when a target fails the tolerance or its pass is "
                "unknown (outside the space the model was measured in; the files are written all the same)",
            ),
            arg(ACCEPT_EDITED[0], **ACCEPT_EDITED[1]),
            arg(ACCEPT_POOR[0], **ACCEPT_POOR[1]),
            arg(
                "--allow-outside",
                action="store_true",
                help="also filter targets outside the joint ranges the "
                "model's extension was fitted on, the extension held at the nearest fitted angle (default: "
                "such targets are kept as they were)",
            ),
        ],
    ),
    Command(
        "factory-robot",
        "a robot config whose nominal is the robot controller's own (factory) calibration",
        "trackcal.campaign.cli.factory:cmd_factory_robot",
        [
            arg("--cell", required=True, help=CELL_HELP),
            arg(
                "--conf",
                help="the controller's own calibration file, as its family reads it (default: none, "
                "one of --conf, --hardware is needed)",
            ),
            arg("--hardware", help="hardware config: read the calibration from the robot it names (default: none)"),
            arg("--out", required=True, help="robot YAML to write"),
        ],
    ),
    Command(
        "report",
        "HTML report of a campaign: plan, residuals, parameters, diagnosis",
        "trackcal.campaign.cli.report:cmd_report",
        [
            arg("session", nargs="?", help="session directory (its table, model, plan, verdict)"),
            arg("--table", help=TABLE_HELP + " (default: the session's)"),
            arg("--model", help="model.json from identify or diagnose (default: the session's)"),
            arg("--plan", help="plan.json from trackcal plan (default: the session's; none without a session)"),
            arg(
                "--verdict", help="verdict.json from trackcal diagnose (default: the session's; none without a session)"
            ),
            arg("--plots", help="directory of PNG plots to include, e.g. trackcal diagnose --plots (default: none)"),
            arg("--cell", help="cell (default: the one the model names)"),
            arg("--out", help="directory for report.html and its PNG plots (default: SESSION/report)"),
        ],
    ),
    Command(
        "identify",
        "identify every campaign (model.json and fit of each, one table)",
        "trackcal.campaign.cli.batch:cmd_batch",
        BATCH_ARGS,
        group="batch",
    ),
    Command(
        "diagnose",
        "diagnose every campaign (verdict and chosen model of each, one table)",
        "trackcal.campaign.cli.batch:cmd_batch",
        BATCH_ARGS,
        group="batch",
    ),
    Command(
        "iso9283",
        "the ISO 9283 figures of every test session (AP and RP per session, one table)",
        "trackcal.campaign.cli.batch:cmd_batch",
        [
            arg("inputs", nargs="+", metavar="INPUT", help="sessions of runs of ISO plans, or folders of them"),
            arg("--model", required=True, help="model.json whose station estimate gives the base frame"),
            *[a for a in BATCH_ARGS if a[0][0] in ("--out", "--scheduler")],
        ],
        group="batch",
    ),
    Command(
        "coverage",
        "the honesty check of identification: how often the 95 %% intervals hold the truth",
        "trackcal.campaign.cli.batch:cmd_coverage",
        [
            arg("--cell", required=True, help=CELL_HELP),
            arg("--seeds", type=int, default=200, help="simulated campaigns, one twin robot each"),
            arg("--first-seed", type=seed, default=0, help="seed of the first campaign"),
            arg("--poses", type=int, default=30, help="poses per campaign"),
            arg("--params", help="parameters (default: the irreducible set)"),
            arg("--weighting", choices=WEIGHTINGS, default=DEFAULT_WEIGHTING, help=WEIGHTING_HELP),
            arg("--scheduler", help="Dask scheduler address (default: a local process pool)"),
            arg("--json", help="counts JSON to write (default: none, the console only)"),
        ],
        group="batch",
    ),
    Command(
        "rho0",
        "plan's criterion rho0 by Monte-Carlo: simulated campaigns of a plan, identified",
        "trackcal.campaign.cli.batch:cmd_rho0",
        [
            arg("plan", help="plan.json from trackcal plan"),
            arg("--cell", required=True, help=CELL_HELP),
            arg("--runs", type=int, default=1000, help="simulated campaigns"),
            arg("--seed", type=seed, default=0, help="seed of the noise"),
            arg("--scheduler", help="Dask scheduler address (default: a local process pool)"),
            arg("--json", help="result JSON to write (default: none, the console only)"),
        ],
        group="batch",
    ),
    Command(
        "history",
        "one robot's calibrations over time: which parameters moved, recalibrate or not",
        "trackcal.campaign.cli.history:cmd_history",
        [
            arg(
                "calibrations",
                nargs="+",
                metavar="SESSION_OR_MODEL",
                help="session folders (dated by their campaign) or model.json files (dated by --dates, else by "
                "the file's modification time)",
            ),
            arg("--dates", help="comma-separated ISO dates, one per calibration (default: see above)"),
            arg(ACCEPT_EDITED[0], **ACCEPT_EDITED[1]),
            arg("--json", help="history JSON to write (default: none, the console only)"),
        ],
    ),
    Command(
        "ipa-ur10",
        "IPA UR10 + Leica T-Mac series (Landgraf et al., CASE 2021)",
        "trackcal.campaign.cli.importers:cmd_import_ipa",
        [
            arg("file", help="series CSV (semicolon-separated, decimal commas)"),
            arg("--out", required=True, help="measurement table to write"),
            arg("--station", default="T1", help="station id"),
            arg(
                "--virtual-points",
                type=int,
                default=0,
                choices=range(len(VIRTUAL_DIRECTIONS) + 1),
                metavar="K",
                help="virtual reference points on the probe from its measured orientation (0..6; 2 carry it all)",
            ),
            arg(
                "--lever-mm",
                type=float,
                default=100.0,
                help="distance of the virtual points from the T-Mac centre (mm, at most 10000; the ur10-tmac tool "
                "expects 100)",
            ),
            arg(
                "--period-s",
                type=float,
                default=DEFAULT_PERIOD_S,
                help="nominal time between poses (s, at most a day): the file's timestamps are unusable",
            ),
        ],
        group="import",
        description="Import the IPA UR10 laser-tracker series (christianlandgraf/ipa-robot-accuracy, MIT) as "
        "measurement tables.",
    ),
    Command(
        "table",
        "another tool's tracker export, read through a map (docs/import-map.md)",
        "trackcal.campaign.cli.importers:cmd_import_table",
        [
            arg(
                "files",
                nargs="+",
                metavar="FILE",
                help="the export (delimited text, UTF-8, or MATLAB .mat); "
                'several files: one per point (map `point: "{file}"`), '
                "read in turn",
            ),
            arg(
                "--map", required=True, help="map YAML: separator, decimal, units, layout, columns (docs/import-map.md)"
            ),
            arg("--out", required=True, help="measurement table to write (with --holdout: the training poses)"),
            arg(
                "--joints",
                metavar="FILE",
                help="the robot's side (joints, time, pose, station columns) in a "
                "file of its own; each FILE then holds positions alone, joined "
                "to it by row (default: none, every FILE holds both)",
            ),
            arg(
                "--holdout",
                type=float,
                metavar="FRACTION",
                help="hold this share of the poses out as a test "
                "table (--test-out), drawn with --seed (default: none held out)",
            ),
            arg("--seed", type=seed, default=0, help="the seed of the --holdout draw"),
            arg(
                "--test-out",
                help="with --holdout: the test table to write (no pose in both; default: none, --holdout needs it)",
            ),
        ],
        group="import",
        description="Convert another tool's tracker export into a measurement table through a map.",
    ),
    Command(
        "plan",
        "the ISO 9283 cube of the cell, its five poses and the plan `trackcal run` walks",
        "trackcal.campaign.cli.iso9283:cmd_plan",
        [
            arg("--cell", required=True, help=CELL_HELP),
            arg("--json", default="iso.json", help="plan JSON to write"),
            arg(
                "--model",
                help="model.json: write its compensated joint targets for the same poses (the "
                "'after' test; default: the nominal targets)",
            ),
            arg("--side", type=float, help="cube side, mm (default: the largest the robot reaches)"),
            arg("--centre", help="X,Y,Z of the cube centre in the base frame, mm (default: the TCP at the test pose)"),
            arg("--cycles", type=int, default=30, help="test cycles (ISO 9283:1998, 6.9: 30)"),
            arg(
                "--vap-cycles",
                type=int,
                help="cycles of the multi-directional test, P1, P2, P4 each approached "
                "from -x, -y, -z (ISO 9283:1998, 7.2; default: --cycles; 0: none)",
            ),
            arg(
                "--orientation",
                action="store_true",
                help="also measure every tool point the station sees (at least 3), point after point, for the "
                "orientation figures AP_a..RP_c (ISO 9283:1998, 7.2; default: the one point)",
            ),
            arg(
                "--load",
                help="what the robot carries during the test, for the report (ISO 9283:1998, 6.6: "
                "100 %% of the rated load), e.g. '270 kg, 100 %% rated', or 'unloaded' "
                "(default: none, and a plan without it is refused)",
            ),
            arg(
                "--velocities",
                metavar="PCT,...",
                help="test velocities in %% of the rated velocity, each a test "
                "of its own, the moves' speed override (ISO 9283:1998, 6.7; default: 100,50,10); the "
                "multi-directional test runs at the first",
            ),
            arg(
                "--drift",
                type=float,
                metavar="HOURS",
                help="plan the drift test instead (ISO 9283:1998, 7.6): "
                "P1 measured in groups of --cycles cycles spread over HOURS, the first group at once; compare "
                "states dAP and dRP between the first group and the last (default: the pose test)",
            ),
            arg(
                "--drift-groups",
                type=int,
                metavar="N",
                help="--drift: the number of groups (default: one an hour and one at the start, at least 2)",
            ),
            arg(
                "--field-check",
                metavar="P,P,MM",
                help="measure the certified distance MM between two tool "
                "points with the robot at P1 before the test, the tracker's field check (ASME B89.4.19 / ISO "
                "10360-10), pass or fail against the hardware file's tracker.mpe_um (else the datasheet's) on the "
                "report (default: none)",
            ),
            arg(
                "--warm-up-cycles",
                type=int,
                default=0,
                metavar="N",
                help="cycles of the test's poses at the "
                "first velocity before the test, nothing measured, recorded on the report (ISO 9283:1998, 6.2: "
                "the robot warmed up as its maker specifies; default: 0, none)",
            ),
            arg("--seed", type=seed, default=0, help="seed of the orientations tried when the test pose's fails"),
            arg(ACCEPT_EDITED[0], **ACCEPT_EDITED[1]),
            arg(ACCEPT_POOR[0], **ACCEPT_POOR[1]),
        ],
        group="iso9283",
    ),
    Command(
        "compare",
        "the ISO 9283 figures of test sessions side by side (e.g. before and after compensation)",
        "trackcal.campaign.cli.iso9283:cmd_compare",
        [
            arg("sessions", nargs="+", help="session directories of runs of ISO plans"),
            arg("--model", required=True, help="model.json whose station estimate gives the base frame"),
            arg("--json", help="figures JSON to write (default: none, the console only)"),
            arg("--report", help="HTML report to write, self-contained (default: none, the console only)"),
            arg(
                "--pdf",
                metavar="FILE",
                help="the same report as a PDF, printed by headless chromium, with the "
                "report id and page numbers on every page (default: none)",
            ),
            arg(
                "--tolerance",
                metavar="FIG=MM,...",
                help="upper limits in mm of AP, RP, vAP, AD (|AD_P|), RD, "
                "e.g. AP=0.5,RP=0.1: each figure is then stated pass, fail or not proven (default: none)",
            ),
            arg(
                "--decision-rule",
                choices=("simple", "guarded"),
                default="guarded",
                help="with --tolerance: simple acceptance (ILAC-G8:09/2019, the value decides) or guarded "
                "acceptance (ISO 14253-1:2017, the tolerance less U)",
            ),
            arg("--customer", help="the customer, printed on the report (default: not stated)"),
            arg("--report-id", help="the report's id (default: a digest of the figures it states)"),
            arg(
                "--authorised-by",
                help="the person authorising the report, printed in its signature field "
                "(default: the field left blank, to be signed by hand)",
            ),
            arg(
                "--accept-expired-certificate",
                action="store_true",
                help="state a test measured after its tracker certificate's due date (the hardware config's "
                "tracker.certificate_due); the report says so (default: refused for --report and --pdf)",
            ),
            arg(ACCEPT_EDITED[0], **ACCEPT_EDITED[1]),
        ],
        group="iso9283",
    ),
]
