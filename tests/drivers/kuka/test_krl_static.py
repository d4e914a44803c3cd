"""A static check of the KR C2 program configs/krc2/trackcal_eki.src (+ .dat) against its channel files and the
signature table of configs/krc2/README.md: what the KRL compiler or the EKX runtime would refuse on the
controller, found here without one.

- every EKX_* call has the arity of the README's table;
- every variable the program uses is declared: in the .dat, in the routine (DECL, parameters), or it is a
  system variable ($...), an enum value (#...), a routine of the program or a KRL / RSI built-in;
- every element path the program reads (EKX_WaitForSensorData, EKX_Get*Element) is declared in TrackcalEki.xml,
  every one it writes (EKX_Write*) exists in the TrackcalEki+.xml template, EKX_Send sends that template's root,
  and the program reads and writes every element of both (the codec does: one source of truth).

Each rule is also shown to catch a broken copy of the program, so the check can fail.
"""

import re

import pytest

from trackcal.drivers.kuka.eki_codec import CHANNEL, COMMAND, STATE, config_text

# KRL words that are no variables: statements, types, operators, literals, the BAS package's names the INI fold
# uses, the RSI functions and ST_SETPARAM indices (ros-industrial/kuka_experimental KR_C2/ros_rsi.src,
# seehma/KMC KukaMatlabConnection_min.src) and the axis names of an AXIS aggregate.
KRL_WORDS = set(
    re.findall(
        r"\S+",
        """DEF END DEFFCT ENDFCT DEFDAT ENDDAT DECL GLOBAL PUBLIC EXT INTERRUPT WHEN DO ON OFF IF THEN ELSE ENDIF FOR TO
    ENDFOR LOOP ENDLOOP WHILE ENDWHILE RETURN HALT WAIT SEC PTP BRAKE RESUME AND OR NOT TRUE FALSE IN OUT
    INT REAL BOOL CHAR AXIS E6AXIS RSIERR BAS BAS_COMMAND IR_STOPM ST_ETHERNET ST_SETPARAM ST_ON ST_OFF
    eERXmaxLatePackages eERXFastCycle A1 A2 A3 A4 A5 A6""",
    )
)
TYPES = {"INT", "REAL", "BOOL", "CHAR", "AXIS", "E6AXIS", "RSIERR"}
READS = {"EKX_WaitForSensorData": 1, "EKX_GetIntegerElement": 1, "EKX_GetRealElement": 1}  # path argument index
WRITES = {"EKX_WriteReal": 0, "EKX_WriteInteger": 0}
CHANNEL_ARG = ("EKX_Open", "EKX_Close")


def strip(text: str) -> str:
    """KRL without comments (';' to the end of the line, outside strings) and without the '&' header lines."""
    out = []
    for line in text.splitlines():
        if line.startswith("&"):
            continue
        code, quoted = [], False
        for c in line:
            if c == '"':
                quoted = not quoted
            elif c == ";" and not quoted:
                break
            code.append(c)
        out.append("".join(code))
    return "\n".join(out)


def routines(src: str) -> list[tuple[str, list[str], str]]:
    """(name, parameter names, body) of every DEF / DEFFCT of a stripped .src."""
    pattern = re.compile(
        r"^\s*(?:GLOBAL\s+)?DEF(?:FCT\s+\w+)?\s+(\w+)\s*\(([^)]*)\)(.*?)^\s*END(?:FCT)?\b", re.M | re.S | re.I
    )
    found = pattern.finditer(src)
    return [(m[1], [p.split(":")[0].strip() for p in m[2].split(",") if p.strip()], m[3]) for m in found]


def declared(text: str) -> set[str]:
    """Names declared by DECL lines (any type) and plain INT/REAL/BOOL/CHAR lines, and EXT routines."""
    names = set()
    for line in text.splitlines():
        m = re.match(r"\s*(?:DECL\s+(?:GLOBAL\s+)?(\w+)|(INT|REAL|BOOL|CHAR))\s+(.*)", line, re.I)
        if m:
            for part in re.sub(r"\[[^]]*\]|=.*", "", m[3]).split(","):
                names.add(part.strip())
        m = re.match(r"\s*EXT\s+(\w+)", line, re.I)
        if m:
            names.add(m[1])
    return names - {""}


def arguments(body: str, start: int) -> list[str]:
    """The comma-separated arguments of the call whose '(' is at body[start]."""
    args, depth, quoted, cur = [], 0, False, []
    for c in body[start + 1 :]:
        if c == '"':
            quoted = not quoted
        elif not quoted and c in "([":
            depth += 1
        elif not quoted and c in ")]":
            if depth == 0:
                break
            depth -= 1
        elif not quoted and c == "," and depth == 0:
            args.append("".join(cur).strip())
            cur = []
            continue
        cur.append(c)
    last = "".join(cur).strip()
    return args + [last] if last or args else args


def ekx_calls(src: str) -> list[tuple[str, list[str]]]:
    return [(m[1], arguments(src, m.end() - 1)) for m in re.finditer(r"\b(EKX_\w+)\s*\(", src)]


def signature_table(readme: str) -> dict[str, int]:
    return {m[1]: int(m[2]) for m in re.finditer(r"^\|\s*(EKX_\w+)\s*\|\s*(\d+)\s*\|", readme, re.M)}


def problems(src_text: str, dat_text: str, readme: str) -> list[str]:
    """Everything the check finds wrong with a program (empty: it passes)."""
    src, found = strip(src_text), []
    arity = signature_table(readme)
    globals_ = declared(strip(dat_text))
    subs = routines(src)
    names = {name for name, _, _ in subs}
    for name, params, body in subs:
        known = globals_ | set(params) | declared(body) | names | KRL_WORDS | set(arity)
        code = re.sub(r'"[^"]*"', '""', body)
        code = re.sub(r"\{[^}]*\}", "", code)  # aggregates: {AXIS: A1 0, ...}
        for m in re.finditer(r"(?<![\w$#.])([A-Za-z_]\w*)", code):
            if m[1] not in known and m[1].upper() not in KRL_WORDS and m[1] not in TYPES:
                found.append(f"{name}: {m[1]} is not declared")
    for fn, args in ekx_calls(src):
        if fn not in arity:
            found.append(f"{fn} is not in the README's signature table")
        elif len(args) != arity[fn]:
            found.append(f"{fn} called with {len(args)} arguments, the table says {arity[fn]}")
            continue
        literal = [a[1:-1] for a in args if a.startswith('"')]
        if fn in CHANNEL_ARG and literal != [CHANNEL]:
            found.append(f"{fn}({', '.join(args)}): not the channel {CHANNEL}")
        for table, tags in ((READS, COMMAND.tags), (WRITES, STATE.tags)):
            if fn in table:
                path = args[table[fn]].strip('"')
                if not path.startswith(CHANNEL + ".") or path[len(CHANNEL) + 1 :] not in tags:
                    found.append(f"{fn}: {path} is not declared for the channel")
        if fn == "EKX_Send" and args != [f'"{CHANNEL}.{STATE.root}"']:
            found.append(f"EKX_Send({args[0]}): not {CHANNEL}.{STATE.root}")
    read = {a.strip('"')[len(CHANNEL) + 1 :] for fn, args in ekx_calls(src) if fn in READS for a in args[1:2]}
    written = {a.strip('"')[len(CHANNEL) + 1 :] for fn, args in ekx_calls(src) if fn in WRITES for a in args[:1]}
    found += [f"{tag} is declared but never read" for tag in COMMAND.tags if tag not in read]
    found += [f"{tag} is in the template but never written" for tag in STATE.tags if tag not in written]
    return found


@pytest.fixture(scope="module")
def shipped():
    return config_text("trackcal_eki.src"), config_text("trackcal_eki.dat"), config_text("README.md")


def test_the_shipped_program_passes(shipped):
    assert problems(*shipped) == []


def test_the_table_lists_every_ekx_function_the_program_calls(shipped):
    src, _, readme = shipped
    called = {fn for fn, _ in ekx_calls(strip(src))}
    assert called == set(signature_table(readme))
    # PR #205's EKX_WaitForSensorData takes 3 arguments (issue 11: the old program passed 2)
    assert signature_table(readme)["EKX_WaitForSensorData"] == 3


@pytest.mark.parametrize(
    ("old", "new", "why"),
    [
        (
            'EKX_WaitForSensorData(1, "TrackcalEki.RobotCommand.ID", nWaitMs)',
            'EKX_WaitForSensorData("TrackcalEki", nWaitMs)',
            "called with 2 arguments",
        ),
        ("nErr = FaultCode( )", "nErr = FaultCodes( )", "FaultCodes is not declared"),
        ("bBraked = TRUE", "bStopped = TRUE", "bStopped is not declared"),
        ('"TrackcalEki.RobotCommand.Pos.A6"', '"TrackcalEki.RobotCommand.Pos.A7"', "Pos.A7 is not declared"),
        (
            '"TrackcalEki.RobotState.RobotCommand.Error"',
            '"TrackcalEki.RobotState.RobotCommand.Err"',
            "RobotCommand.Err is not declared",
        ),
        ('EKX_Send("TrackcalEki.RobotState")', 'EKX_Send("TrackcalEki")', "EKX_Send"),
        ('EKX_Open("TrackcalEki")', 'EKX_WriteXmlString("TrackcalEki")', "not in the README's signature table"),
    ],
)
def test_the_check_catches_a_broken_program(shipped, old, new, why):
    src, dat, readme = shipped
    assert old in src
    assert any(why in p for p in problems(src.replace(old, new), dat, readme))


def test_a_variable_missing_from_the_dat_is_caught(shipped):
    src, dat, readme = shipped
    assert any("nPollMs is not declared" in p for p in problems(src, dat.replace("DECL INT nPollMs", ";"), readme))
