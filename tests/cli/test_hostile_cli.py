"""Every command with bad values of its options, bad environment variables, unusable outputs: each ends
in exactly one `error:` line on stderr (naming the option or variable), a non-zero exit, no traceback,
before anything is computed (nothing written, no kernels compiled).

The commands run in this process through the application object itself (`app(args=...)`, the path
the `vcirun` script takes: click's usage errors are one line there too); the cases that need a fresh
process (standard output on /dev/full or a closed pipe, numba's own variables) run what the
`vcirun` script runs."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from vcirun.cli.main import app

ROOT = Path(__file__).resolve().parents[2]
TINY = """\
name: tiny
system: cart_pendulum
methods: [CVA]
h: [1.0e-2]
beta: [3.2]
T: 0.1
reference: {kind: none}
"""


def run(capsys, *args) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as ei:
        app(args=[str(a) for a in args], prog_name="vcirun")
    out, err = capsys.readouterr()
    code = ei.value.code
    return (0 if code is None else code), out, err


def one_error(code, out, err, *words) -> str:
    assert code not in (0, None), (code, out, err)
    assert "Traceback" not in out + err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def place(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "tiny.yaml").write_text(TINY)
    (tmp_path / "afile").write_text("x")
    (tmp_path / "adir").mkdir()
    (tmp_path / "pngdir.png").mkdir()
    (tmp_path / "binary.yaml").write_bytes(b"\xff\xfe\x00\x80name: x\n")
    return tmp_path


# (command and arguments, words the error line must hold); "{d}" is the test's folder
CASES = [
    # simulate
    (["simulate", "--h", "abc"], ["--h"]),
    (["simulate", "--system", "", "--T", "0.1"], ["--system", "empty"]),
    (["simulate", " ", "--T", "0.1"], ["SYSTEM", "empty"]),
    (["animate", "--system", "", "--T", "0.1"], ["--system", "empty"]),
    (["simulate", "--h", "0"], ["h: must be > 0"]),
    (["simulate", "--h", "-1"], ["h: must be > 0"]),
    (["simulate", "--h", "nan"], ["h: must be a finite number"]),
    (["simulate", "--h", "inf"], ["h: must be a finite number"]),
    (["simulate", "--h", "1e-320"], ["h: must be >= 1e-50"]),
    (["simulate", "--T", "0"], ["T: must be > 0"]),
    (["simulate", "--T", "nan"], ["T: must be a finite number"]),
    (["simulate", "--T", "1e9", "--h", "1e-6"], ["steps is too many"]),
    (["simulate", "--T", "1e4", "--h", "1e-6"], ["need about", "raise h or lower T"]),
    (["simulate", "--beta", "nan"], ["beta: must be a finite number"]),
    (["simulate", "--method", "NOPE"], ["NOPE"]),
    (["simulate", "--system", "no_such_scene"], ["system", "no_such_scene"]),
    (["simulate", "--system", "cradle_100000"], ["cradle_100000 has 100,000 coordinates", "from 2 to 32"]),
    (["simulate", "--system", "link_chain_31"], ["link_chain_31 has 33 coordinates"]),
    (["simulate", "--system", "newton_cradle_129"], ["newton_cradle_K takes K from 1 to 128"]),
    (["simulate", "--system", "n_pendulum_0"], ["n_pendulum_K takes K from 1 to 32"]),
    (["simulate", "--system", "{d}/missing.yaml"], ["missing.yaml"]),
    (["simulate", "--system", "{d}/binary.yaml"], ["binary.yaml"]),
    (["simulate", "--param", "g"], ["--param", "NAME=VALUE"]),
    (["simulate", "--param", "g=abc"], ["--param g", "number"]),
    (["simulate", "--param", "nope=1"], ["params.nope", "unknown parameter"]),
    (["simulate", "--param", "g=nan"], ["params.g", "finite"]),
    (["simulate", "--system", "ball_in_box", "--param", "e=1.5"], ["params.e", "restitution", "[0, 1]"]),
    (["simulate", "--q0", "1,2"], ["--q0", "--p0"]),
    (["simulate", "--q0", "a,b", "--p0", "1,2"], ["--q0"]),
    (["simulate", "--q0", "0.1", "--p0", "0"], ["q0"]),
    (["simulate", "--q0", "nan,0", "--p0", "0,0"], ["q0"]),
    (["simulate", "--q0", "0.1,0.2", "--p0", "0,0", "--beta", "3"], ["--beta", "--q0"]),
    (["simulate", "--newton-tol", "0"], ["newton_tol"]),
    (["simulate", "--newton-tol", "-1"], ["newton_tol"]),
    (["simulate", "--event-tol", "nan"], ["event_tol"]),
    (["simulate", "--mh-order", "-1"], ["mh_order"]),
    (["simulate", "--flow-order", "5"], ["flow_order"]),
    (["simulate", "--method", "MCVA", "--ld", "BAD"], ["BAD"]),
    (["simulate", "--output", "{d}/adir"], ["--output", "is a directory"]),
    (["simulate", "--output", "{d}/run.txt"], ["--output", "unknown format"]),
    (["simulate", "--output", "/dev/null"], ["--output", "unknown format"]),
    (["simulate", "--output", "{d}/afile/run.h5"], ["--output", "is a file, not a directory"]),
    (["simulate", "--bogus"], ["No such option: --bogus"]),
    # sweep, validate, study
    (["sweep", "{d}/missing.yaml"], ["missing.yaml"]),
    (["sweep", "{d}/adir"], ["adir"]),
    (["sweep", "{d}/binary.yaml"], ["binary.yaml"]),
    (["sweep", "{d}/tiny.yaml", "--workers", "0"], ["--workers"]),
    (["sweep", "{d}/tiny.yaml", "--task-size", "0"], ["--task-size"]),
    (["sweep", "{d}/tiny.yaml", "--output", "{d}/adir"], ["adir", "is a directory"]),
    (["sweep", "{d}/tiny.yaml", "--output", "{d}/afile/r.h5"], ["afile", "is a file, not a directory"]),
    (["sweep", "{d}/tiny.yaml", "--output", "/dev/null"], ["/dev/null", "not a regular file"]),
    (["validate", "{d}/missing.yaml"], ["missing.yaml"]),
    (["validate", "{d}/binary.yaml"], ["binary.yaml"]),
    (["validate", "{d}/adir"], ["adir"]),
    (["study", "{d}/missing.yaml"], ["missing.yaml"]),
    (["study", "{d}/tiny.yaml"], ["study"]),
    # info, plot
    (["info", "{d}/missing.h5"], ["missing.h5", "not found"]),
    (["info", "{d}/afile"], ["afile", "not a readable HDF5 file"]),
    (["info", "{d}/adir"], ["adir", "directory"]),
    (["info", "/dev/null"], ["/dev/null"]),
    (["plot", "{d}/missing.h5"], ["missing.h5"]),
    (["plot", "{d}/afile"], ["afile"]),
    (["plot", "{d}/afile", "--out", "{d}/afile/figs"], ["afile"]),
    # verify
    (["verify", "no_such_scene"], ["no_such_scene"]),
    (["verify", "cart_pendulum", "--methods", "NOPE"], ["NOPE"]),
    (["verify", "cart_pendulum", "--h", "0.1"], ["h: an order needs at least 3 step sizes"]),
    (["verify", "cart_pendulum", "--h", "0.1,0.05,abc"], ["--h"]),
    (["verify", "cart_pendulum", "--T", "0"], ["T"]),
    (["verify", "cart_pendulum", "--T", "nan"], ["T"]),
    (["verify", "cart_pendulum", "--T", "1e9"], ["steps is too many"]),
    (["verify", "cart_pendulum", "--T", "1e5"], ["T: the runs at h", "need about", "limit"]),
    (["verify", "cart_pendulum", "--output", "{d}/adir"], ["--output", "is a directory"]),
    (["verify", "cart_pendulum", "--output", "/dev/null"], ["--output", "not a regular file"]),
    (["verify", "cart_pendulum", "--param", "nope=1"], ["nope"]),
    (["verify", "cradle_40"], ["cradle_40 has 40 coordinates"]),
    # simulate: the API's checks, in the command's flags
    (["simulate", "cart_pendulum", "--tol", "1e-4", "--unconstrained", "--T", "1"],
     ["--unconstrained: --tol measures", "drop --unconstrained"]),
    (["simulate", "cart_pendulum", "--max-time", "2", "--T", "1"], ["--max-time: only with --tol"]),
    (["simulate", "ball_in_box", "--T", "1", "--q0", "0.5,-2", "--p0", "0,0"], ["(or pass --unconstrained)"]),
    # systems
    (["systems", "no_such_scene"], ["no_such_scene"]),
    (["systems", "cradle_999"], ["cradle_999 has 999 coordinates"]),
    # periodic
    (["periodic", "--h", "0"], ["--h", "positive"]),
    (["periodic", "--h", "nan"], ["--h"]),
    (["periodic", "--h", "1e-320"], ["h: must be >= 1e-50"]),
    (["periodic", "--k", "0"], ["--k", "positive integer"]),
    (["periodic", "--k", "-5"], ["--k", "positive integer"]),
    (["periodic", "--k", "1.5"], ["--k"]),
    (["periodic", "--sweep", "gamma"], ["--sweep"]),
    (["periodic", "--sweep", "gamma=0:1:1"], ["--sweep", "COUNT"]),
    (["periodic", "--sweep", "gamma=0:1:1000000000"], ["--sweep", "COUNT", "10,000"]),
    (["periodic", "--sweep", "gamma=nan:1:3"], ["--sweep"]),
    (["periodic", "--solver", "bogus"], ["solver"]),
    (["periodic", "--jacobian", "bogus"], ["jacobian"]),
    (["periodic", "--output", "{d}/b.png"], ["--output", "--sweep"]),
    (["periodic", "--sweep", "gamma=0.1:0.2:3", "--output", "{d}/pngdir.png"], ["--output", "is a directory"]),
    (["periodic", "--sweep", "gamma=0.1:0.2:3", "--output", "{d}/afile/b.png"], ["--output", "is a file"]),
    (["periodic", "--system", "no_such_scene"], ["no_such_scene"]),
    (["periodic", "--q0", "1"], ["--q0/--p0"]),
    (["periodic", "--param", "gamma=abc"], ["--param"]),
    (["periodic", "--param", "nope=1"], ["nope"]),
    (["periodic", "--q0", "nan", "--p0", "1"], ["guess", "finite"]),
    # the application itself
    (["no_such_command"], ["No such command"]),
]


@pytest.mark.parametrize("args,words", CASES, ids=[" ".join(a) for a, _ in CASES])
def test_bad_option_values_are_one_error_line(place, capsys, args, words):
    before = sorted(p.name for p in place.iterdir())
    code, out, err = run(capsys, *[a.replace("{d}", str(place)) for a in args])
    one_error(code, out, err, *words)
    assert "compiling kernels" not in err
    assert sorted(p.name for p in place.iterdir()) == before   # nothing written


ENV_CASES = [
    ("VCIRUN_COMMIT_INTERVAL", "abc"), ("VCIRUN_COMMIT_INTERVAL", "-1"), ("VCIRUN_COMMIT_INTERVAL", "nan"),
    ("VCIRUN_MAX_MEMORY", "lots"), ("VCIRUN_MAX_MEMORY", "-5GB"), ("VCIRUN_BUILD", "turbo"), ("VCIRUN_TIER", "bogus"),
    ("VCIRUN_CORE_NDOF", "many"), ("VCIRUN_KERNEL_BACKEND", "fortran"), ("VCIRUN_KERNEL_PATH", "sideways"),
    ("VCIRUN_C_MIN_STATEMENTS", "some"), ("VCIRUN_CACHE_DIR", ""), ("NUMBA_OPT", "bogus"),
    ("NUMBA_NUM_THREADS", "0"), ("NUMBA_NUM_THREADS", "abc"),
]


@pytest.mark.parametrize("command", [["simulate", "--T", "0.1"], ["sweep", "{d}/tiny.yaml"], ["info", "{d}/x.h5"],
                                     ["verify", "cart_pendulum"], ["periodic"], ["cache", "info"]],
                         ids=lambda c: c[0])
@pytest.mark.parametrize("var,value", ENV_CASES, ids=[f"{k}={v}" for k, v in ENV_CASES])
def test_bad_environment_variables_are_one_error_line(place, capsys, monkeypatch, command, var, value):
    monkeypatch.setenv(var, value)
    code, out, err = run(capsys, *[a.replace("{d}", str(place)) for a in command])
    one_error(code, out, err, var)


SCRIPT = "import sys; from vcirun.cli.main import app; sys.argv[0] = 'vcirun'; app()"   # what bin/vcirun runs


def _fresh(args, *, env=None, stdout=None, timeout=300):
    e = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    e.update(PYTHONPATH=str(ROOT), **(env or {}))
    return subprocess.run([sys.executable, "-c", SCRIPT, *map(str, args)], env=e, stdout=stdout,
                          stderr=subprocess.PIPE, text=True, timeout=timeout)


@pytest.mark.parametrize("args", [["simulate", "--T", "0.1"], ["systems"], ["--help"], ["cache", "info"]],
                         ids=lambda a: a[0])
def test_a_full_standard_output_is_one_error_line(args):
    with open("/dev/full", "w") as full:
        r = _fresh(args, stdout=full)
    assert r.returncode == 1, r.stderr
    # (a cold kernel cache may first say what it compiles, or that it waits for a process compiling the
    # same kernels: notices, not errors)
    notices = ("compiling kernels", "compiling the shared core", "waiting for ", "vcirun: ")
    lines = [x for x in r.stderr.strip().splitlines() if not x.startswith(notices)]
    assert lines == ["error: cannot write the output (No space left on device); nothing more was written"], r.stderr


def test_a_closed_pipe_is_one_error_line():
    p = subprocess.Popen([sys.executable, "-c", SCRIPT, "systems"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, env={**os.environ, "PYTHONPATH": str(ROOT)})
    p.stdout.close()   # the reader went away (`vcirun systems | head -0`)
    err = p.stderr.read().decode()
    assert p.wait(timeout=120) == 1
    assert "Traceback" not in err and len(err.strip().splitlines()) <= 1, err


@pytest.mark.parametrize("var,value", [("NUMBA_OPT", "bogus"), ("NUMBA_NUM_THREADS", "0"),
                                       ("NUMBA_DEBUG_ARRAY_OPT", "abc"), ("NUMBA_BOUNDSCHECK", "sometimes")])
def test_numba_variables_are_checked_before_numba_reads_them(var, value):
    r = _fresh(["simulate", "--T", "0.1"], env={var: value})
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith(f"error: {var}:"), r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_a_usage_error_is_one_line_in_the_vcirun_script_too():
    r = _fresh(["simulate", "--h", "abc"])
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "error: Invalid value for '--h': Input should be a valid number, unable to parse string as a number "
        "(`vcirun simulate --help` lists the options)"], r.stderr


@pytest.mark.parametrize("args, words", [
    (["--output", "{d}/afile/a.gif"], ["--output", "folder"]),     # a file where its folder should be
    (["--output", "{d}/adir"], ["--output", ".gif or .mp4"]),
    (["--fps", "0.001", "--output", "{d}/a.gif"], ["fps"]),            # a GIF frame lasts at most 655 s
], ids=["file-as-folder", "folder", "fps-tiny"])
def test_animate_refuses_an_unwritable_output_before_the_run(place, capsys, args, words):
    code, out, err = run(capsys, "animate", "--system", "oscillator_wall", "--T", "0.05",
                         *[a.replace("{d}", str(place)) for a in args])
    one_error(code, out, err, *words)
    assert not (place / "a.gif").exists()


@pytest.mark.parametrize("content", [b"garbage", b"", b"[1, 2]", b'{"study": "work_precision", "model": '
                                     b'{"system": "cart_pendulum", "horizons": {"5": {"T": 0}}}}'],
                         ids=["garbage-h5", "empty-h5", "json-list", "json-T0"])
def test_recommend_notes_unreadable_measurements_and_goes_on(place, capsys, content):
    """A damaged or edited store is noted ("not read") and skipped (then pilot runs answer), not a
    traceback (StorageError, AttributeError on a JSON list, ZeroDivisionError on an edited model)."""
    from vcirun.cli.recommend import _stored_models

    f = place / ("m.json" if content.startswith((b"[", b"{")) else "m.h5")
    f.write_bytes(content)
    assert _stored_models("cart_pendulum", [f]) == []
    err = capsys.readouterr().err
    assert "Traceback" not in err
    if not content.startswith(b"["):   # (a JSON list is not a study: skipped without a note)
        assert "not read" in err, err


def test_a_yaml_system_without_a_start_names_the_flags(capsys):
    """A system file with no default state: simulate and verify name the flags that give one."""
    example = ROOT / "docs" / "examples" / "cart_double_spring.yaml"
    for args in (("simulate", "--system", example, "--method", "CVA"), ("verify", example, "-q")):
        one_error(*run(capsys, *args), "needs --q0 and --p0 (or --beta)")
