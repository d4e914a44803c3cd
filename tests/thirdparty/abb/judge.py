"""Run by the judge venv's Python (tests/mocks/servers/abb/test_abb_judge.py): abb-robot-client's RWS class, unmodified,
drives the controller at argv[1] (base URL) through the scenario argv[2] and prints one JSON document of what it read.
Errors are reported in the document ({"error": type, "text": message}), never as a traceback."""

import json
import sys
import time

from abb_robot_client.egm import EGM
from abb_robot_client.rws import RWS

MOD = "TrackcalRws"


def read_all(rws):
    jt = rws.get_jointtarget()
    rt = rws.get_robtarget()
    ex = rws.get_execution_state()
    return {
        "ctrlstate": rws.get_controller_state(),
        "opmode": rws.get_operation_mode(),
        "execution": [ex.ctrlexecstate, ex.cycle],
        "joints": [float(v) for v in jt.robax],
        "trans": [float(v) for v in rt.trans],
        "rot": [float(v) for v in rt.rot],
        "done": rws.get_rapid_variable(f"{MOD}/trackcal_done"),
        "speed_num": rws.get_rapid_variable_num("trackcal_speed"),
        "tasks": sorted(rws.get_tasks()),
        "elog": [[e.code, e.msgtype, e.title] for e in rws.read_event_log()],
    }


def move(rws, q_deg, number):
    rws.set_rapid_variable("trackcal_target", "[[" + ",".join(f"{v:.4f}" for v in q_deg) + "],[9E9,9E9,9E9,9E9,9E9,9E9]]")
    rws.set_rapid_variable_num("trackcal_speed", 100)
    rws.set_rapid_variable_num("trackcal_move", number)
    deadline = time.monotonic() + 20
    while rws.get_rapid_variable_num("trackcal_done") != number:
        if time.monotonic() > deadline:
            raise TimeoutError("move not done")
        time.sleep(0.02)


def scenario(name, url):
    out = {}
    if name == "drive":
        rws = RWS(url)
        out["before"] = read_all(rws)
        target = [float(v) for v in sys.argv[3].split(",")]
        move(rws, target, 1)
        out["after"] = read_all(rws)
        rws.stop()
        out["stopped"] = rws.get_execution_state().ctrlexecstate
        rws.resetpp()
        rws.start(cycle="forever")
        out["started"] = rws.get_execution_state().ctrlexecstate
        rws.logout()
    elif name == "egm":  # the client's EGM class on argv[1]'s port: its view of the next 50 messages
        egm = EGM(port=int(url))
        got = []
        deadline = time.monotonic() + 20
        while len(got) < 50 and time.monotonic() < deadline:
            ok, state = egm.receive_from_robot(timeout=0.5)
            if ok:
                got.append(state)
        last = got[-1]
        out = {"count": len(got), "joints": [float(v) for v in last.joint_angles],
               "planned": [float(v) for v in last.joint_angles_planned], "motors_on": bool(last.motors_on),
               "rapid_running": bool(last.rapid_running),
               "seqnos": [int(s.robot_message.header.seqno) for s in got]}
    elif name == "password":
        RWS(url, password="wrong").get_controller_state()
    elif name == "busy":
        RWS(url).get_controller_state()
    elif name == "gone":
        rws = RWS(url)
        out["before"] = rws.get_controller_state()
        print(json.dumps(out), flush=True)
        sys.stdin.readline()  # the test kills the controller, then says go on
        rws.get_controller_state()
    return out


def main():
    try:
        out = scenario(sys.argv[2], sys.argv[1])
    except Exception as exc:  # the judge's own word on what went wrong, as data
        out = {"error": type(exc).__name__, "text": str(exc)}
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
