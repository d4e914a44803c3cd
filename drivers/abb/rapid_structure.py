"""The structure of RAPID modules that program filtering reads: modules, routines, data declarations of the types it
needs (robtarget, jointtarget, tooldata, wobjdata) and the move instructions with their targets, tool and work object.

Syntax followed (ABB "Technical reference manual - RAPID kernel", 3HAC050946-001: modules, routine and data
declarations; "RAPID Instructions, Functions and Data types", 3HAC050917-001: the move instructions):
- `MODULE name [(attributes)] ... ENDMODULE`, one or more per file; in a module, data declarations
  `[LOCAL | TASK] CONST | PERS | VAR type name [{dims}] [:= value];`, routines `[LOCAL] PROC name (params) ...
  ENDPROC`, `FUNC type name (params) ... ENDFUNC`, `TRAP name ... ENDTRAP`, `RECORD ... ENDRECORD` and
  `ALIAS type name;`;
- in a routine, its own data declarations, then statements: what is not a declaration, a move or a procedure call
  (`Name arg, ...;` at a statement's start, Name no reserved word) is skipped with its brackets balanced
  (IF/WHILE/FOR/TEST blocks need no tracking: a move is a move wherever it sits);
- `MoveJ [\\Conc,] ToPoint [\\ID], Speed [\\V | \\T], Zone [\\Z] [\\Inpos], Tool [\\WObj] [\\Corr] [\\TLoad];` and
  MoveL alike; `MoveC [\\Conc,] CirPoint, ToPoint, ...` (two targets); `MoveAbsJ ToJointPos [\\NoEOffs], Speed, Zone,
  Tool [\\WObj];` (a jointtarget); the DO, AO, GO and Sync forms (MoveLDO ...) take the same arguments up to the tool
  and more after it. Optional arguments (`\\name` or `\\name := value`) attach to the argument before them.
- a target argument is a name, an array element `name{i}`, an inline literal `[...]`, or one of these inside
  `Offs(p, dx, dy, dz)` / `RelTool(p, dx, dy, dz [\\Rx] [\\Ry] [\\Rz])`; any other expression (a function call such as
  CRobT(), arithmetic) is no target of the program's text and is left alone.
"""

from __future__ import annotations

from dataclasses import dataclass

from trackcal.drivers.abb.rapid_tokens import Token, fail
from trackcal.drivers.abb.rapid_values import Node, parse_literal

READ_TYPES = ("ROBTARGET", "JOINTTARGET", "TOOLDATA", "WOBJDATA")
# the move instructions read: upper case -> (name as the manual writes it, Cartesian targets; 0: one jointtarget)
MOVES = {
    name.upper(): (name, n)
    for name, n in (
        ("MoveJ", 1),
        ("MoveL", 1),
        ("MoveC", 2),
        ("MoveAbsJ", 0),
        ("MoveJDO", 1),
        ("MoveLDO", 1),
        ("MoveCDO", 2),
        ("MoveJSync", 1),
        ("MoveLSync", 1),
        ("MoveCSync", 2),
        ("MoveJAO", 1),
        ("MoveLAO", 1),
        ("MoveCAO", 2),
        ("MoveJGO", 1),
        ("MoveLGO", 1),
        ("MoveCGO", 2),
    )
}
OFFSET_FUNCTIONS = {"OFFS": "Offs", "RELTOOL": "RelTool"}
ROUTINES = {"PROC": "ENDPROC", "FUNC": "ENDFUNC", "TRAP": "ENDTRAP"}
BLOCK_WORDS = {"MODULE", "ENDMODULE", *ROUTINES, *ROUTINES.values(), "RECORD", "ENDRECORD"}
# RAPID's reserved words (RAPID kernel, "Reserved words"): a statement starting with one is no procedure call
RESERVED = {
    "ALIAS",
    "AND",
    "BACKWARD",
    "CASE",
    "CONNECT",
    "CONST",
    "DEFAULT",
    "DIV",
    "DO",
    "ELSE",
    "ELSEIF",
    "ENDFOR",
    "ENDFUNC",
    "ENDIF",
    "ENDMODULE",
    "ENDPROC",
    "ENDRECORD",
    "ENDTEST",
    "ENDTRAP",
    "ENDWHILE",
    "ERROR",
    "EXIT",
    "FALSE",
    "FOR",
    "FROM",
    "FUNC",
    "GOTO",
    "IF",
    "INOUT",
    "LOCAL",
    "MOD",
    "MODULE",
    "NOSTEPIN",
    "NOT",
    "NOVIEW",
    "OR",
    "PERS",
    "PROC",
    "RAISE",
    "READONLY",
    "RECORD",
    "RETRY",
    "RETURN",
    "STEP",
    "SYSMODULE",
    "TEST",
    "THEN",
    "TO",
    "TRAP",
    "TRUE",
    "TRYNEXT",
    "UNDO",
    "VAR",
    "VIEWONLY",
    "WHILE",
    "WITH",
    "XOR",
}
# the words after which a new statement starts (besides `;` and a CASE's or a label's `:`)
OPENERS = {"THEN", "ELSE", "DO", "ENDIF", "ENDWHILE", "ENDFOR", "ENDTEST", "ERROR", "UNDO", "BACKWARD"}


@dataclass(frozen=True)
class Declaration:
    """A data declaration of a READ_TYPES type. `module` numbers the modules of all files (a scope); `routine` is
    None at module level; `value` is the literal after `:=` (None: no value, or an expression not read)."""

    file: str
    module: int
    routine: str | None
    local: bool
    type: str  # upper case
    name: str  # as written
    line: int
    dims: int  # 0 a scalar, 1 an array {n}, 2 {n, m} ...
    value: Node | None
    storage: str = "VAR"  # CONST, PERS or VAR


@dataclass(frozen=True)
class TargetArgument:
    """A move's target: a reference (`name`, with the array index `index` when literal, () for any element) or an
    inline literal `node`; `via` names the offset function around it ("Offs", "RelTool") or is ""."""

    line: int
    via: str
    name: Token | None = None
    index: tuple[int, ...] | None = None  # None: no index; (): an index that is not a literal
    node: Node | None = None


@dataclass(frozen=True)
class Move:
    """A move instruction: where it is, its targets, and the names of its tool and work object (None: wobj0)."""

    file: str
    module: int
    routine: str | None
    instruction: str  # as the manual writes it
    line: int
    cartesian: bool
    targets: tuple[TargetArgument, ...]
    tool: Token
    wobj: Token | None
    parameters: frozenset[str] = frozenset()  # the names of its routine's parameter list, upper case


@dataclass(frozen=True)
class Procedure:
    """A PROC: where it is, and the names (upper case) of its required parameters in order."""

    file: str
    module: int
    name: str
    local: bool
    positional: tuple[str, ...]


@dataclass(frozen=True)
class Call:
    """A procedure call statement `Name arg, arg ...;`: its positional arguments read as targets (None: an expression
    that is none) and as names (a single name: a tool or work object passed on)."""

    file: str
    module: int
    routine: str | None
    line: int
    name: Token
    targets: tuple[TargetArgument | None, ...]
    names: tuple[Token | None, ...]
    parameters: frozenset[str] = frozenset()

    @property
    def instruction(self) -> str:
        return self.name.text


class Walker:
    """Walks one file's tokens, collecting its declarations, moves, procedures and calls; `module` is the next
    module's number."""

    def __init__(self, file: str, tokens: list[Token], module: int) -> None:
        self.file, self.tokens, self.module = file, tokens, module
        self.declarations: list[Declaration] = []
        self.moves: list[Move] = []
        self.parameters: frozenset[str] = frozenset()  # those of the routine being read
        self.procedures: list[Procedure] = []
        self.calls: list[Call] = []

    def at(self, i: int, expected: str) -> Token:
        """tokens[i], or the error that the file ends where `expected` was expected."""
        if i >= len(self.tokens):
            line = self.tokens[-1].line if self.tokens else 1
            raise fail(self.file, line, f"the file ends early (expected {expected})")
        return self.tokens[i]

    def name_at(self, i: int, what: str) -> Token:
        t = self.at(i, what)
        if t.kind != "name" or t.upper in BLOCK_WORDS:
            raise fail(self.file, t.line, f"expected {what}, found {t.text!r}")
        return t

    def walk(self) -> int:
        """Reads every module of the file; returns the number of the module after the last one."""
        i = 0
        if not self.tokens:
            raise fail(self.file, 1, "expected MODULE, found an empty file")
        while i < len(self.tokens):
            t = self.tokens[i]
            if t.upper != "MODULE":
                raise fail(self.file, t.line, f"expected MODULE, found {t.text!r}")
            name = self.name_at(i + 1, "the module's name")
            i += 2
            if self.at(i, "the module's contents").text == "(":
                i = self.closing(i, "(", ")") + 1
            i = self.module_body(i, name.text)
            self.module += 1
        return self.module

    def closing(self, i: int, opening: str, close: str) -> int:
        """The index of the `close` that matches tokens[i] == `opening` (other brackets balanced inside)."""
        depth = 0
        for j in range(i, len(self.tokens)):
            text = self.tokens[j].text
            depth += (text in ("(", "[", "{")) - (text in (")", "]", "}"))
            if depth < 0 or (depth == 0 and text in (")", "]", "}") and text != close):
                raise fail(self.file, self.tokens[j].line, f"unbalanced {text!r} (expected {close!r})")
            if depth == 0:
                return j
        raise fail(self.file, self.tokens[i].line, f"{opening!r} not closed (expected {close!r})")

    def module_body(self, i: int, module: str) -> int:
        """Reads a module's declarations and routines; returns the index after its ENDMODULE."""
        while True:
            t = self.at(i, f"ENDMODULE of module {module}")
            if t.upper == "ENDMODULE":
                return i + 1
            local = t.upper == "LOCAL"
            if t.upper in ("LOCAL", "TASK"):
                i += 1
                t = self.at(i, "a declaration or a routine")
            if t.upper in ("CONST", "PERS", "VAR"):
                i = self.declaration(i, None, local)
            elif t.upper in ROUTINES:
                i = self.routine(i, local)
            elif t.upper == "RECORD":
                i = self.skip_to(i, "ENDRECORD")
            elif t.upper == "ALIAS":  # ALIAS num level; (RAPID kernel, alias types)
                i = self.statement_end(i + 1) + 1
            else:
                raise fail(
                    self.file,
                    t.line,
                    f"expected a declaration, PROC, FUNC, TRAP, RECORD or ENDMODULE, found {t.text!r}",
                )

    def skip_to(self, i: int, word: str) -> int:
        while self.at(i, word).upper != word:
            i += 1
        return i + 1

    def declaration(self, i: int, routine: str | None, local: bool) -> int:
        """Reads `CONST|PERS|VAR type name [{dims}] [:= value];` at tokens[i]; returns the index after the `;`."""
        start = i
        type_ = self.name_at(i + 1, "a data type")
        name = self.name_at(i + 2, "the data's name")
        i += 3
        dims = 0
        if self.at(i, "':=' or ';'").text == "{":
            end = self.closing(i, "{", "}")
            dims = 1 + sum(t.text == "," for t in self.tokens[i + 1 : end])
            i = end + 1
        value = None
        if self.at(i, "':=' or ';'").text == ":=":
            i += 1
            if type_.upper in READ_TYPES and self.at(i, "a value").text == "[":
                value, i = parse_literal(self.file, self.tokens, i)
            else:
                i = self.statement_end(i)
        if self.at(i, "';'").text != ";":
            raise fail(
                self.file,
                self.tokens[i].line,
                f"expected ';' after the declaration of {name.text}, found {self.tokens[i].text!r}",
            )
        if type_.upper in READ_TYPES:
            self.declarations.append(
                Declaration(
                    self.file,
                    self.module,
                    routine,
                    local,
                    type_.upper,
                    name.text,
                    name.line,
                    dims,
                    value,
                    self.tokens[start].upper,
                )
            )
        return i + 1

    def statement_end(self, i: int) -> int:
        """The index of the `;` ending the statement that tokens[i] is in (brackets balanced before it)."""
        depth, start = 0, i
        while True:
            t = self.at(i, "';'")
            if t.upper in BLOCK_WORDS:
                raise fail(self.file, self.tokens[start].line, f"expected ';' before {t.text}")
            if t.text == ";" and depth == 0:
                return i
            depth += (t.text in ("(", "[", "{")) - (t.text in (")", "]", "}"))
            if depth < 0 or (t.text == ";" and depth):
                raise fail(self.file, t.line, f"unbalanced brackets before {t.text!r}")
            i += 1

    def routine(self, i: int, local: bool = False) -> int:
        """Reads a PROC, FUNC or TRAP: its data declarations, moves and calls; returns the index after its END word."""
        kind = self.tokens[i].upper
        end_word = ROUTINES[kind]
        name = self.name_at(i + 2 if kind == "FUNC" else i + 1, "the routine's name")
        i += 3 if kind == "FUNC" else 2
        self.parameters = frozenset()
        if kind != "TRAP":
            if self.at(i, "'('").text != "(":
                raise fail(self.file, self.tokens[i].line, f"expected '(' after {kind} {name.text}")
            end = self.closing(i, "(", ")")
            params = self.tokens[i + 1 : end]
            self.parameters = frozenset(t.upper for t in params if t.kind == "name")
            if kind == "PROC":
                self.procedures.append(Procedure(self.file, self.module, name.text, local, positional(params)))
            i = end + 1
        routine, starts = name.text.upper(), True
        while True:
            t = self.at(i, f"{end_word} of {name.text}")
            if t.upper == end_word:
                return i + 1
            if t.upper in BLOCK_WORDS:
                raise fail(self.file, t.line, f"expected {end_word} of {name.text} before {t.text}")
            after = self.at(i + 1, "';'").text if t.kind == "name" else ""
            if t.upper in ("CONST", "PERS", "VAR"):
                i = self.declaration(i, routine, False)
            elif t.upper in MOVES and after not in ("(", ":=", "."):
                i = self.move(i, routine)
            elif starts and t.kind == "name" and t.upper not in RESERVED and after not in ("(", ":=", ".", "{", ":"):
                i = self.call(i, routine)
            else:
                i = self.statement_part_end(i)
            previous = self.tokens[i - 1]
            starts = previous.text in (";", ":") or previous.upper in OPENERS

    def call(self, i: int, routine: str) -> int:
        """Reads a procedure call statement at tokens[i]; returns the index after its `;`."""
        end = self.statement_end(i + 1)
        mains = [optional_arguments(piece)[0] for piece in split(self.tokens[i + 1 : end], ",")]
        mains = [m for m in mains if m]
        targets = tuple(self.target(m) for m in mains)
        names = tuple(m[0] if len(m) == 1 and m[0].kind == "name" else None for m in mains)
        self.calls.append(
            Call(self.file, self.module, routine, self.tokens[i].line, self.tokens[i], targets, names, self.parameters)
        )
        return end + 1

    def statement_part_end(self, i: int) -> int:
        """Skips one token of a statement that is not read, checking its brackets; returns the next index."""
        t = self.tokens[i]
        if t.text in ("(", "[", "{"):
            return self.closing(i, t.text, {"(": ")", "[": "]", "{": "}"}[t.text]) + 1
        if t.text in (")", "]", "}"):
            raise fail(self.file, t.line, f"unbalanced {t.text!r}")
        return i + 1

    def move(self, i: int, routine: str) -> int:
        """Reads a move instruction at tokens[i]; returns the index after its `;`."""
        instruction, n_targets = MOVES[self.tokens[i].upper]
        end = self.statement_end(i + 1)
        line = self.tokens[i].line
        pieces = split(self.tokens[i + 1 : end], ",")
        positional, options = [], {}
        for piece in pieces:
            main, opts = optional_arguments(piece)
            if not main and not opts:
                raise fail(self.file, line, f"an empty argument of {instruction} (expected an argument)")
            if main:
                positional.append(main)
            options.update(opts)
        n = max(n_targets, 1)
        if len(positional) < n + 3 or not all(positional):
            targets = "two targets" if n == 2 else "a target"
            raise fail(self.file, line, f"{instruction} needs {targets}, a speed, a zone and a tool")
        targets = tuple(self.target(arg) for arg in positional[:n])
        tool = self.single_name(positional[n + 2], f"a tooldata name as {instruction}'s tool")
        wobj = options.get("WOBJ")
        wobj = None if wobj is None else self.single_name(wobj, f"a wobjdata name after {instruction}'s \\WObj:=")
        self.moves.append(
            Move(
                self.file,
                self.module,
                routine,
                instruction,
                line,
                n_targets > 0,
                tuple(t for t in targets if t is not None),
                tool,
                wobj,
                self.parameters,
            )
        )
        return end + 1

    def single_name(self, tokens: list[Token], what: str) -> Token:
        if len(tokens) != 1 or tokens[0].kind != "name":
            raise fail(self.file, tokens[0].line if tokens else 1, f"expected {what}")
        return tokens[0]

    def target(self, tokens: list[Token], via: str = "") -> TargetArgument | None:
        """The target a move's argument names, or None for an expression that is none."""
        first = tokens[0]
        if first.upper in OFFSET_FUNCTIONS and len(tokens) > 2 and tokens[1].text == "(" and tokens[-1].text == ")":
            inner = split(tokens[2:-1], ",")
            if len(inner) >= 4 and inner[0] and not via:
                return self.target(inner[0], OFFSET_FUNCTIONS[first.upper])
            return None
        if first.text == "[":
            node, j = parse_literal(self.file, tokens, 0)
            return TargetArgument(first.line, via, node=node) if j == len(tokens) and node.kind == "list" else None
        if first.kind != "name" or first.upper in BLOCK_WORDS:
            return None
        if len(tokens) == 1:
            return TargetArgument(first.line, via, name=first)
        if len(tokens) > 2 and tokens[1].text == "{" and tokens[-1].text == "}":
            index = split(tokens[2:-1], ",")
            literal = all(len(x) == 1 and x[0].kind == "num" and x[0].text.isdigit() for x in index)
            numbers = tuple(int(x[0].text) for x in index) if literal else ()
            return TargetArgument(first.line, via, name=first, index=numbers)
        return None


def positional(params: list[Token]) -> tuple[str, ...]:
    """The names (upper case) of a parameter list's required parameters in order (`\\optional` ones and
    alternatives `|` left out): each is the last name before its `{*}`."""
    out = []
    for piece in split(params, ","):
        if not piece or piece[0].text == "\\" or any(t.text == "|" for t in piece):
            continue
        brace = next((k for k, t in enumerate(piece) if t.text == "{"), len(piece))
        names = [t for t in piece[:brace] if t.kind == "name"]
        if names:
            out.append(names[-1].upper)
    return tuple(out)


def split(tokens: list[Token], separator: str) -> list[list[Token]]:
    """`tokens` split at the `separator` tokens outside brackets."""
    out: list[list[Token]] = [[]]
    depth = 0
    for t in tokens:
        if t.text == separator and depth == 0:
            out.append([])
            continue
        depth += (t.text in ("(", "[", "{")) - (t.text in (")", "]", "}"))
        out[-1].append(t)
    return out


def optional_arguments(piece: list[Token]) -> tuple[list[Token], dict[str, list[Token]]]:
    """An argument's own tokens and the optional arguments (`\\name [:= value]`) attached to it, by upper-case name."""
    parts = split(piece, "\\")
    options = {}
    for part in parts[1:]:
        if part and part[0].kind == "name":
            has_value = len(part) > 1 and part[1].text == ":="
            options[part[0].upper] = part[2:] if has_value else []
    return parts[0], options
