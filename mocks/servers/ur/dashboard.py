"""Dashboard server (port 29999) answers of the mock controller.

Source: Universal Robots, "Dashboard Server e-Series" (DashboardServer_e-Series_2022.pdf): newline-terminated ASCII
commands, case-insensitive, the greeting "Connected: Universal Robots Dashboard Server" on connect, and each reply
text used below (Robotmode: <mode>, Safetystatus: <status>, "Protective stop releasing" or "Cannot unlock
protective stop until 5s after occurrence. Always inspect cause of protective stop before unlocking", "closing
safety popup", "Powering on", "Brake releasing", "Starting program" / "Failed to execute: play", "Stopped",
"Pausing program", "Program running: true", "Disconnected" on quit, "could not understand: '<cmd>'"). ur_rtde's
DashboardClient (src/dashboard_client.cpp) sends the same strings and compares these replies.
"""

from __future__ import annotations

from trackcal.mocks.servers.ur.controller import PAUSED, PLAYING, ROBOT_MODE, SAFETY_MODE, UrController

GREETING = "Connected: Universal Robots Dashboard Server"
UNLOCK_REFUSED = (
    "Cannot unlock protective stop until 5s after occurrence. Always inspect cause of protective stop before unlocking"
)
PROGRAM_STATE = {PLAYING: "PLAYING", PAUSED: "PAUSED"}


def answer(line: str, ctl: UrController) -> tuple[str, bool]:
    """(reply, close the connection after it) for one command line."""
    raw = line.strip()
    cmd = " ".join(raw.split()).lower()
    version = ".".join(str(v) for v in ctl.version)
    if cmd == "quit":
        return "Disconnected", True
    if cmd == "polyscopeversion":
        return f"URSoftware {version} (Jan 16 2024)", False
    if cmd == "version":
        return version, False
    if cmd == "get serial number":
        return ctl.serial, False
    if cmd == "get robot model":
        return ctl.model, False
    if cmd == "is in remote control":
        return "true" if ctl.remote_control else "false", False
    if cmd == "robotmode":
        return f"Robotmode: {ROBOT_MODE[ctl.robot_mode]}", False
    if cmd == "safetystatus":
        return f"Safetystatus: {SAFETY_MODE[ctl.safety_mode]}", False
    if cmd == "safetymode":
        return f"Safetymode: {SAFETY_MODE[ctl.safety_mode]}", False
    if cmd == "running":
        return f"Program running: {'true' if ctl.runtime_state == PLAYING else 'false'}", False
    if cmd == "programstate":
        name = ctl.program or "<unnamed>"
        return f"{PROGRAM_STATE.get(ctl.runtime_state, 'STOPPED')} {name}", False
    if cmd == "get loaded program":
        return (f"Loaded program: {ctl.loaded_program}" if ctl.loaded_program else "No program loaded"), False
    if cmd == "close safety popup":
        return "closing safety popup", False
    if cmd == "close popup":
        return "closing popup", False
    if cmd.startswith("popup"):
        return "showing popup", False
    if cmd.startswith("addtolog"):
        return "Added log message", False
    if cmd == "get operational mode":
        return "NONE", False
    if cmd == "isprogramsaved":
        return f"true {ctl.loaded_program or '<unnamed>'}", False
    # commands reserved to remote control (the manual's remote-only column)
    remote_only = {
        "unlock protective stop",
        "power on",
        "power off",
        "brake release",
        "play",
        "stop",
        "pause",
        "restart safety",
        "shutdown",
    }
    if (cmd in remote_only or cmd.startswith("load ")) and not ctl.remote_control:
        return "Command is not allowed due to safety reasons", False
    if cmd == "unlock protective stop":
        return ("Protective stop releasing" if ctl.unlock_protective_stop() else UNLOCK_REFUSED), False
    if cmd == "power on":
        ctl.power(True)
        return "Powering on", False
    if cmd == "power off":
        ctl.power(False)
        return "Powering off", False
    if cmd == "brake release":
        ctl.brake_release()
        return "Brake releasing", False
    if cmd == "play":
        return ("Starting program" if ctl.dashboard_play() else "Failed to execute: play"), False
    if cmd == "stop":  # a stopped program stops again: ur_rtde stops its script, then calls `stop` and expects this
        ctl.dashboard_stop()
        return "Stopped", False
    if cmd == "pause":
        return ("Pausing program" if ctl.dashboard_pause() else "Failed to execute: pause"), False
    if cmd.startswith("load "):
        return f"File not found: {raw[5:].strip()}", False
    return f"could not understand: '{raw}'", False
