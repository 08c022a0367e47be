"""Broad fuzz of the command line with bad input, in-process, stopping before compilation.

Every case is a `jaxform` command line (run, design, taylor-test on every config in
configs/, and material-point) with one bad thing in it: a config key set to a wrong type,
NaN, +-inf, a huge or empty value or a negative one where the range is positive; an
unknown key or section; a missing, directory, binary or empty config file; a bad --out; a
bad flag; a reversed or self-intersecting die profile, or one overlapping the workpiece;
a step count or mesh beyond the caps.  A few valid inputs are mixed in (a config with a
UTF-8 byte-order mark, huge values where the range allows them) to catch refusals of
valid input.

The CLI runs in-process with the entry points that would compile (the forward run, the
design schedule, the material-point program) replaced by a stub that stops the case, so
a case either stops at the stub (accepted) or is refused (or raises) before compiling.
Outcomes:

    clear       refused: exit 2, exactly one line on stderr, naming the key, flag or file
    unclear     refused otherwise (other exit status, several lines, the cause not named)
    traceback   an exception other than the refusal escaped main()
    silent      bad input reached the stub (it would have run)
    accepted    valid (or allowed) input reached the stub
    wrongly refused   valid input refused

    python experiments/fuzz_cli.py [--show silent,traceback,unclear] [--timeout 20]

(run with PYTHONPATH pointing at the checkout to fuzz).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import resource
import signal
import sys
import tempfile
import time
import tomllib
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted((ROOT / "configs").glob("*.toml"))


class Reached(Exception):
    """The stub standing in for compilation was called: the input was accepted."""


class CaseTimeout(Exception):
    pass


@dataclass(frozen=True)
class Case:
    argv: tuple[str, ...]
    needle: str  # what the one error line must name
    expect: str  # "refuse" | "accept" | "either"
    label: str


# --------------------------------------------------------------------------------------
# cases


# keys whose value is a length, speed or time: a huge value is meaningless (overflow of
# the geometry, the step schedule or the contact scale)
def _huge_is_bad(section: str, key: str) -> bool:
    return (
        key.endswith("_mm")
        or key.endswith("_mm_s")
        or key.endswith("_s")
        or section in ("billet", "ring", "block")
    )


def _toml(v) -> str:
    if isinstance(v, float):
        return {math.inf: "inf", -math.inf: "-inf"}.get(v, "nan" if math.isnan(v) else repr(v))
    if isinstance(v, str):
        return '"' + v + '"'
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, list):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    return str(v)


def bad_values(section: str, key: str, f) -> list[tuple[str, object, str]]:
    """(label, value, expect) for one schema field."""
    out = []
    nan, inf = math.nan, math.inf
    if f.kind in ("float", "int"):
        out += [
            ("wrong type", "abc", "refuse"),
            ("wrong type list", [1.0], "refuse"),
            ("nan", nan, "refuse"),
            ("+inf", inf, "refuse"),
            ("-inf", -inf, "refuse"),
            ("empty string", "", "refuse"),
        ]
        if f.kind == "int":
            out.append(("huge", 10**15, "refuse" if f.high is not None else "either"))
            out.append(("float for int", 2.5, "refuse"))
        else:
            huge_bad = f.high is not None or _huge_is_bad(section, key)
            out.append(("huge", 1e300, "refuse" if huge_bad else "either"))
        if f.low is not None and f.low >= 0:
            out.append(("negative", -1, "refuse"))
    elif f.kind == "bool":
        out += [
            ("wrong type", "abc", "refuse"),
            ("number for bool", 1, "refuse"),
            ("nan", nan, "refuse"),
        ]
    elif f.kind == "str":
        out += [
            ("wrong type", 1.5, "refuse"),
            ("nan", nan, "refuse"),
            ("wrong type list", ["a"], "refuse"),
        ]
        if f.choices is not None:
            out += [("empty string", "", "refuse"), ("bad choice", "bogus", "refuse")]
    else:  # lists
        out += [("wrong type", "abc", "refuse"), ("scalar", 1.0, "refuse")]
        if f.kind == "floats":
            out += [
                ("nan entry", [nan, 1.0], "refuse"),
                ("inf entry", [inf, 1.0], "refuse"),
                ("huge entry", [0.0, 1e300], "refuse" if _huge_is_bad(section, key) else "either"),
            ]
        elif f.kind == "points":
            out += [
                ("nan point", [[0.0, 1.0], [nan, 2.0]], "refuse"),
                ("inf point", [[0.0, 1.0], [inf, 2.0]], "refuse"),
                ("huge point", [[0.0, 1.0], [1e300, 1.0]], "refuse"),
                ("ragged point", [[0.0, 1.0], [1.0]], "refuse"),
            ]
        else:
            out += [
                ("number entry", [1.0], "refuse"),
                ("bad entry", ["bogus"], "refuse" if f.choices is not None else "either"),
            ]
        required = f.default is None
        out.append(("empty list", [], "refuse" if required else "either"))
    return out


def config_cases(tmp: Path) -> list[Case]:
    from jaxform.config import SCHEMA

    cases = []
    for path in CONFIGS:
        raw = tomllib.loads(path.read_text())
        kind = next(w for w in ("billet", "ring", "block", "membrane") if w in raw)
        sections = [s for s in SCHEMA if _section_applies(s, kind)]
        for cmd in ("run", "design", "taylor-test"):
            out = ["--out", str(tmp / "out")] if cmd != "taylor-test" else []
            base = (cmd, str(path), *out)
            if cmd != "run" and raw.get("mesh", {}).get("rezone_quality", 0) > 0:
                base += ("--set", "mesh.rezone_quality=0")  # gradient runs do not rezone
            for section in sections:
                if cmd != "run" and section not in ("design", "time", "die", "mesh"):
                    continue  # the design commands: the keys they read beyond run's
                for key, f in SCHEMA[section].items():
                    for label, value, expect in bad_values(section, key, f):
                        if expect == "either" and cmd != "run":
                            continue
                        cases.append(
                            Case(
                                (*base, "--set", f"{section}.{key}={_toml(value)}"),
                                f"{section}.{key}",
                                expect,
                                f"{cmd} {path.stem} {section}.{key} {label}",
                            )
                        )
            cases.append(
                Case(
                    (*base, "--set", "mesh.bogus_key=1"),
                    "mesh.bogus_key",
                    "refuse",
                    f"{cmd} {path.stem} unknown key",
                )
            )
            cases.append(
                Case(
                    (*base, "--set", "bogus.key=1"),
                    "bogus",
                    "refuse",
                    f"{cmd} {path.stem} unknown section",
                )
            )
            cases.append(
                Case(
                    (*base, "--set", "meshnr=3"),
                    "meshnr=3",
                    "refuse",
                    f"{cmd} {path.stem} malformed override",
                )
            )
            cases += scene_cases(cmd, path, kind, base)
    return cases


def _section_applies(section: str, kind: str) -> bool:
    if section in ("billet", "ring", "block", "membrane"):
        return section == kind
    if section in ("die", "friction"):
        return kind != "membrane"
    if section == "load":
        return kind == "membrane"
    return True


def scene_cases(cmd: str, path: Path, kind: str, base: tuple) -> list[Case]:
    """Bad combinations: step and mesh caps, die profiles, design set-ups."""
    name = path.stem
    cases = [
        Case(
            (*base, "--set", "time.dt_s=1e-12"), "time.dt_s", "refuse", f"{cmd} {name} 1e12 steps"
        ),
        Case(
            (*base, "--set", "mesh.nr=2000", "--set", "mesh.nz=2000"),
            "mesh.nr",
            "refuse",
            f"{cmd} {name} 2000x2000 mesh",
        ),
    ]
    if kind == "membrane":
        cases.append(
            Case(
                (*base, "--set", "load.ramp_time_s=1e300"),
                "load.ramp_time_s",
                "refuse",
                f"{cmd} {name} huge ramp time",
            )
        )
    else:
        cases.append(
            Case(
                (*base, "--set", "die.speed_mm_s=1e-300"),
                "die.speed_mm_s",
                "refuse",
                f"{cmd} {name} tiny speed",
            )
        )
        raw = tomllib.loads(path.read_text())
        prof = raw.get("die", {}).get("profile_mm")
        if prof:
            cases.append(
                Case(
                    (*base, "--set", f"die.profile_mm={_toml(prof[::-1])}"),
                    "die.profile_mm",
                    "refuse",
                    f"{cmd} {name} reversed profile",
                )
            )
        top = {
            "billet": lambda w: w["height_mm"] / 2,
            "ring": lambda w: w["height_mm"] / 2,
            "block": lambda w: w["depth_mm"],
        }[kind](raw[kind])
        cross = [[0.0, top + 1], [3.0, top + 2], [3.0, top + 0.5], [1.0, top + 3]]
        cases.append(
            Case(
                (*base, "--set", f"die.profile_mm={_toml(cross)}"),
                "die.profile_mm",
                "refuse",
                f"{cmd} {name} self-intersecting profile",
            )
        )
        low = [[0.0, top - 0.5], [1.0, top - 0.5]]
        cases.append(
            Case(
                (*base, "--set", f"die.profile_mm={_toml(low)}"),
                "die.profile_mm",
                "refuse",
                f"{cmd} {name} die overlapping the workpiece",
            )
        )
        rev = [[5.0, top + 1.0], [0.0, top + 1.0]]
        cases.append(
            Case(
                (*base, "--set", f"die.profile_mm={_toml(rev)}"),
                "die.profile_mm",
                "refuse",
                f"{cmd} {name} flat profile walked inward",
            )
        )
    if cmd == "design":
        cases.append(
            Case(
                (*base, "--set", "design.variables=[]"),
                "design.variables",
                "refuse",
                f"{cmd} {name} no design variables",
            )
        )
    if cmd != "run" and kind != "membrane":
        cases.append(
            Case(
                (*base, "--set", "mesh.rezone_quality=0.3"),
                "mesh.rezone_quality",
                "refuse",
                f"{cmd} {name} rezoning in a gradient run",
            )
        )
        cases.append(
            Case(
                (*base, "--set", "design.objective=die_fill", "--set", "die.closed=false"),
                "die.closed",
                "refuse",
                f"{cmd} {name} die_fill without closed die",
            )
        )
        cases.append(
            Case(
                (*base, "--set", "design.objective=force_misfit"),
                "design.target_csv",
                "refuse",
                f"{cmd} {name} misfit without target",
            )
        )
    if cmd == "taylor-test":
        for label, h in (
            ("zero", ["0"]),
            ("negative", ["-1", "-0.5"]),
            ("nan", ["nan", "0.5"]),
            ("inf", ["inf", "0.5"]),
            ("one value", ["1"]),
            ("increasing", ["0.5", "1"]),
            ("text", ["abc"]),
        ):
            cases.append(Case((*base, "--h", *h), "--h", "refuse", f"{cmd} {name} --h {label}"))
        cases.append(
            Case((*base, "--groups", "bogus"), "--groups", "refuse", f"{cmd} {name} --groups bogus")
        )
        if name in ("upsetting_seed", "cooks_membrane"):  # no friction in these scenes
            cases.append(
                Case(
                    (*base, "--groups", "friction"),
                    "--groups",
                    "refuse",
                    f"{cmd} {name} --groups friction without friction",
                )
            )
    return cases


def path_cases(tmp: Path) -> list[Case]:
    binary = tmp / "binary.toml"
    binary.write_bytes(bytes(range(256)) * 4)
    empty = tmp / "empty.toml"
    empty.write_text("")
    broken = tmp / "broken.toml"
    broken.write_text("[billet\ndiameter_mm = 5\n")
    bom = tmp / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + (ROOT / "configs/upsetting_seed.toml").read_bytes())
    afile = tmp / "a_file"
    afile.write_text("x")
    seed = str(ROOT / "configs/upsetting_seed.toml")
    cases = []
    for cmd in ("run", "design", "taylor-test"):
        out = ["--out", str(tmp / "out")] if cmd != "taylor-test" else []
        for label, p in (
            ("missing", tmp / "missing.toml"),
            ("directory", tmp),
            ("binary", binary),
            ("empty", empty),
            ("broken", broken),
        ):
            cases.append(Case((cmd, str(p), *out), str(p), "refuse", f"{cmd} {label} config"))
        cases.append(Case((cmd, str(bom), *out), str(bom), "accept", f"{cmd} BOM config"))
        for label, p in (("missing", tmp / "missing.msh"), ("directory", tmp)):
            cases.append(
                Case(
                    (cmd, seed, *out, "--set", f"mesh.file={p}"),
                    "mesh.file",
                    "refuse",
                    f"{cmd} mesh.file {label}",
                )
            )
        if cmd != "run":
            for label, content in (
                ("binary", b"\x80\x81"),
                ("no columns", b"a,b\n1,2\n"),
                ("nan", b"stroke_mm,force_N\n0.5,nan\n"),
            ):
                target = tmp / f"target_{label.replace(' ', '_')}.csv"
                target.write_bytes(content)
                cases.append(
                    Case(
                        (
                            cmd,
                            seed,
                            *out,
                            "--set",
                            "design.objective=force_misfit",
                            "--set",
                            f"design.target_csv={target}",
                        ),
                        "design.target_csv",
                        "refuse",
                        f"{cmd} design.target_csv {label}",
                    )
                )
        if cmd != "taylor-test":
            for label, o in (("existing file", afile), ("under a file", afile / "sub")):
                cases.append(
                    Case((cmd, seed, "--out", str(o)), "--out", "refuse", f"{cmd} --out {label}")
                )
    return cases


def material_point_cases(tmp: Path) -> list[Case]:
    afile = tmp / "a_file"
    out = ("--out", str(tmp / "mp"))
    flags = {
        "--rates": ["nan", "inf", "-inf", "0", "-1", "abc", "1e300"],
        "--ram-speeds-mm-s": ["nan", "inf", "0", "-1", "1e300"],
        "--strain": ["nan", "inf", "0", "-1", "5", "abc"],
        "--steps": ["0", "-1", "1000000000000", "2.5", "abc"],
        "--height-mm": ["nan", "inf", "0", "-1", "1e300"],
    }
    cases = []
    for flag, values in flags.items():
        for v in values:
            extra = ("--ram-speeds-mm-s", "1") if flag == "--height-mm" else ()
            cases.append(
                Case(
                    ("material-point", flag, v, *extra, *out),
                    flag,
                    "refuse",
                    f"material-point {flag} {v}",
                )
            )
    for label, o in (("existing file", afile), ("under a file", afile / "sub")):
        cases.append(
            Case(
                ("material-point", "--out", str(o)),
                "--out",
                "refuse",
                f"material-point --out {label}",
            )
        )
    return cases


# --------------------------------------------------------------------------------------
# running a case


@contextlib.contextmanager
def stubs():
    """Replace every entry point that would compile by one that raises Reached."""
    import jaxform.driver
    import jaxform.materialpoint
    import jaxform.xla_options

    def stop(*a, **k):
        raise Reached

    patched = [
        (jaxform.driver, "simulate"),
        (jaxform.materialpoint, "uniaxial_compression"),
        (jaxform.xla_options, "jit"),
    ]
    try:
        import jaxform.design.problem

        patched.append((jaxform.design.problem, "schedule"))
    except ImportError:
        pass
    saved = [(m, n, getattr(m, n)) for m, n in patched]
    for m, n in patched:
        setattr(m, n, stop)
    try:
        yield
    finally:
        for m, n, v in saved:
            setattr(m, n, v)


def _alarm(signum, frame):
    raise CaseTimeout


def run_case(case: Case, timeout_s: int) -> tuple[str, str]:
    """(outcome, detail) of one case."""
    from jaxform.cli import main

    err, out = io.StringIO(), io.StringIO()
    code, exc = None, None
    signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(timeout_s)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            code = main(list(case.argv))
    except Reached:
        code = "reached"
    except SystemExit as e:
        if isinstance(e.code, str):  # what the interpreter would print, and exit 1
            err.write(e.code + "\n")
            code = 1
        else:
            code = e.code
    except CaseTimeout:
        code = "timeout"
    except BaseException as e:  # noqa: BLE001 - the fuzz counts every escape
        exc = e
    finally:
        signal.alarm(0)
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
    if exc is not None:
        return "traceback", f"{type(exc).__name__}: {str(exc)[:160]}"
    if code == "timeout":
        return "traceback", f"timeout after {timeout_s} s"
    if code == "reached" or code == 0:
        return ("silent" if case.expect == "refuse" else "accepted"), ""
    clear = code == 2 and len(lines) == 1 and case.needle in lines[0]
    if case.expect == "accept":
        return "wrongly refused", " | ".join(lines)[:200]
    return ("clear" if clear else "unclear"), f"exit {code}: " + " | ".join(lines)[:240]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--show",
        default="silent,traceback,unclear,wrongly refused",
        help="outcomes whose cases are listed",
    )
    ap.add_argument("--timeout", type=int, default=20, help="seconds per case")
    ap.add_argument("--grep", default="", help="only cases whose label contains this")
    ap.add_argument(
        "--max-memory-gb",
        type=float,
        default=6.0,
        help="address-space limit: a case that would exhaust the machine raises "
        "MemoryError (a traceback) instead",
    )
    args = ap.parse_args()
    limit = int(args.max_memory_gb * 2**30)
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    from jaxform.precision import enable_x64

    enable_x64()
    import jaxform

    print(f"fuzzing {Path(jaxform.__file__).parent}")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        (tmp / "a_file").write_text("x")
        cases = path_cases(tmp) + material_point_cases(tmp) + config_cases(tmp)
        cases = [c for c in cases if args.grep in c.label]
        counts, shown = Counter(), []
        t0 = time.perf_counter()
        with stubs():
            for case in cases:
                outcome, detail = run_case(case, args.timeout)
                counts[outcome] += 1
                if outcome in args.show.split(","):
                    shown.append(f"{outcome:>10}  {case.label}: {detail}")
    print("\n".join(shown))
    print(
        f"{len(cases)} cases in {time.perf_counter() - t0:.1f} s: "
        + ", ".join(
            f"{k} {counts[k]}"
            for k in ("clear", "unclear", "traceback", "silent", "accepted", "wrongly refused")
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
