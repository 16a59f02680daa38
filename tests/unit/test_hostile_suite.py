"""Hostile input through the Python API, and damaged files, beyond the cases of test_hostile_inputs.py:
the caps of vcirun.core.limits met in every form and call (hand-written, bodies totals, sized
families, MechanicalSystem, ensemble, verify, periodic_orbit), restitution parameters, a stiff
declaration within the caps that must not hang, and fuzzing of results files and journals: whatever
bytes are damaged, the readers either raise one StorageError line, report what they set aside, or
return data identical to what was written -- never changed numbers, never a traceback of another kind."""
from __future__ import annotations

import random
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

import vcirun
from vcirun.core.limits import CAPS, FAMILY_SIZES
from vcirun.io import legacy_text
from vcirun.io.errors import StorageError
from vcirun.io.journal import read_journal
from vcirun.io.reader import load_trajectory, read_results
from vcirun.io.single import read_single
from vcirun.io.writer import ResultsWriter
from vcirun.mechanics.loader import load_system_yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_storage import KEY, make_traj, run_attrs, write  # noqa: E402


# --- caps ------------------------------------------------------------------------------------------------------
def bodies_file(n_contacts_a=1, n_contacts_b=0, n_springs=0, joints=1, params=None, one_more=False):
    items = [{"name": "a{i}", "repeat": [1, n_contacts_a], "body": "b1", "line": {"point": [0, 0], "normal": [0, 1]}}]
    if n_contacts_b:
        items.append({"name": "c{i}", "repeat": [1, n_contacts_b], "body": "b1",
                      "line": {"point": [0, -1], "normal": [0, 1]}})
    if one_more:
        items.append({"name": "last", "body": "b1", "line": {"point": [0, -2], "normal": [0, 1]}})
    d = {"name": "many", "parameters": {"m": 1.0, "g": 9.81, **(params or {})}, "gravity": "g",
         "bodies": [{"name": "b{i}", "repeat": [1, joints], "mass": "m"}],
         "joints": [{"type": "prismatic", "body": "b{i}", "coordinate": "y{i}", "axis": [0, 1], "repeat": [1, joints]}],
         "contacts": items}
    if n_springs:
        d["springs"] = [{"a": "ground", "b": "b1", "k": "1", "repeat": [1, n_springs]}]
    return d


@pytest.mark.parametrize("what,data,words", [
    ("2,001 contacts: two repeats and one more", bodies_file(1000, 1000, one_more=True),
     ["system.contacts", "2,000", "limit is 1,000"]),
    ("2,000 contacts in two repeats", bodies_file(1000, 1000), ["system.contacts", "2,000", "limit is 1,000"]),
    ("one repeat of 1,001", bodies_file(1001), ["system.contacts[0].repeat", "1,001 items"]),
    ("33 joints", bodies_file(joints=33), ["system.bodies", "33 bodies"]),
    ("1,025 parameters", bodies_file(params={f"p{i}": 1.0 for i in range(1024)}), ["system.parameters", "1,026"]),
    ("1,001 springs", bodies_file(n_springs=1001), ["system.springs", "1,001"]),
])
def test_the_bodies_form_is_held_to_the_totals(what, data, words):
    t = time.perf_counter()
    with pytest.raises(ValueError) as ei:
        load_system_yaml(data)
    assert time.perf_counter() - t < 5.0, what   # refused while counting, before anything is built
    msg = str(ei.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg, msg


def test_a_million_items_are_refused_while_counting():
    d = bodies_file(1000)
    d["contacts"] = d["contacts"] * 1000   # 1000 items of 1000 each: never expanded
    t = time.perf_counter()
    with pytest.raises(ValueError, match="system.contacts: 2,000 contacts"):   # (at the second item)
        load_system_yaml(d)
    assert time.perf_counter() - t < 2.0


def hand_written(n_coords=1, n_constraints=1, n_params=1):
    coords = [f"x{i}" for i in range(n_coords)]
    return {"name": "h", "coordinates": coords, "parameters": {f"p{i}": 1.0 for i in range(n_params)},
            "mass_matrix": [["1" if i == j else "0" for j in range(n_coords)] for i in range(n_coords)],
            "potential": "0", "constraints": [f"x0 + {i + 1}" for i in range(n_constraints)]}


@pytest.mark.parametrize("kw,words", [
    ({"n_coords": 33}, ["system.coordinates: 33 coordinates", "limit is 32"]),
    ({"n_constraints": 1001}, ["system.constraints: 1,001 contacts", "limit is 1,000"]),
    ({"n_params": 1025}, ["system.parameters: 1,025 parameters", "limit is 1,024"]),
])
def test_the_hand_written_form_is_held_to_the_same_caps(kw, words):
    with pytest.raises(ValueError) as ei:
        load_system_yaml(hand_written(**kw))
    for w in words:
        assert w in str(ei.value), str(ei.value)


@pytest.mark.parametrize("family", list(FAMILY_SIZES))
def test_every_sized_family_is_held_to_its_range_in_every_call(family):
    lo, hi, coords, contacts = FAMILY_SIZES[family]
    if family != "newton_cradle":
        assert coords(hi) <= CAPS["coordinates"].limit < coords(hi + 1)
    assert contacts(hi) <= CAPS["contacts"].limit
    for k in (lo - 1, hi + 1, 10**6):
        name = f"{family}_{k}"
        calls = [lambda: vcirun.simulate(name, "CVA", h=0.01, T=0.1),
                 lambda: vcirun.reference(name, T=0.1),
                 lambda: vcirun.ensemble(name, "CVA", h=0.01, T=0.1, beta=[0.1, 0.2]),
                 lambda: vcirun.verify(name),
                 lambda: vcirun.periodic_orbit(name, "CVA", h=0.01, guess=np.zeros(2))]
        for call in calls:
            t = time.perf_counter()
            with pytest.raises(ValueError, match=f"system: {name}"):
                call()
            assert time.perf_counter() - t < 10.0


def test_a_mechanical_system_over_the_caps_is_refused():
    import sympy as sp

    from vcirun.mechanics.system import Constraint, MechanicalSystem

    x = sp.Symbol("x")
    s = MechanicalSystem(name="many", q=[x], params={"m": 1.0}, M=sp.Matrix([[1]]), V=sp.Integer(0),
                         constraints=[Constraint(f"c{i}", x + i + 1) for i in range(1001)])
    with pytest.raises(ValueError, match="system.constraints: 1,001 contacts"):
        vcirun.simulate(s, "CVA", h=0.01, T=0.1, q0=[0.0], p0=[0.0])


def test_ensemble_member_steps_and_results_are_bounded_before_any_run(monkeypatch):
    t = time.perf_counter()
    with pytest.raises(ValueError, match=r"runs: 5,000,000,000,000 member steps .* limit is 1e\+12"):
        vcirun.ensemble("cart_pendulum", "CVA", h=1e-3, T=5000, beta=np.full(10**6, 3.2))
    monkeypatch.setenv("VCIRUN_MAX_MEMORY", "50MB")
    with pytest.raises(ValueError, match=r"runs: the results of 1,000,000 runs need about .* \(limit 47.7 MiB\)"):
        vcirun.ensemble("cart_pendulum", "CVA", h=1e-2, T=0.1, beta=np.full(10**6, 3.2))
    assert time.perf_counter() - t < 30.0


def test_ensemble_progress_reports_runs_and_an_estimate():
    seen = []
    ds = vcirun.ensemble("cart_pendulum", "CVA", h=1e-2, T=0.5, beta=np.linspace(3.0, 3.4, 40), workers=1,
                         progress=lambda done, total, elapsed, left: seen.append((done, total, left)))
    assert list(ds.status.values) == ["ok"] * 40
    assert seen[-1][:2] == (40, 40) and seen[-1][2] == 0.0
    assert all(0 < d <= 40 and t == 40 for d, t, _ in seen) and [d for d, _, _ in seen] == sorted(d for d, _, _ in seen)
    with pytest.raises(ValueError, match="progress: must be true, false or a callable"):
        vcirun.ensemble("cart_pendulum", "CVA", h=1e-2, T=0.5, beta=[3.2], progress="yes")


def test_the_progress_line_appears_only_for_long_calls(monkeypatch):
    import io
    import types

    from vcirun.core import progress
    from vcirun.core.progress import Progress

    # a clock one second on per reading: the lines do not depend on how fast this machine runs the loop
    # (a line is held back while less than a tenth of the elapsed time has passed since the last one)
    ticks = iter(range(1000))
    monkeypatch.setattr(progress, "time", types.SimpleNamespace(perf_counter=lambda: float(next(ticks))))
    buf = io.StringIO()
    p = Progress(100, "ensemble of 100 runs", None, quiet_below=0.0, interval=0.0, stream=buf)
    for _ in range(4):
        p.update(25)
    lines = buf.getvalue().splitlines()
    assert len(lines) == 4 and lines[-1].startswith("ensemble of 100 runs: 100 of 100 (100.0 %) in "), lines
    quiet = io.StringIO()
    p = Progress(100, "x", None, stream=quiet)   # a call estimated under 10 s says nothing
    p.update(100)
    assert quiet.getvalue() == ""


@pytest.mark.parametrize("kw,words", [
    ({"k": 0}, ["k: must be >= 1"]), ({"k": -5}, ["k: must be >= 1"]), ({"k": 1.5}, ["k: must be an integer"]),
    ({"k": True}, ["k: must be a positive integer"]), ({"h": 0.0}, ["h: must be > 0"]),
    ({"h": float("nan")}, ["h: must be a finite number"]), ({"h": 1e-60}, ["h: must be >= 1e-50"]),
    ({"tol": 0}, ["tol: must be > 0"]), ({"maxit": 0}, ["maxit: must be >= 1"]),
    ({"guess": ([float("nan")], [1.0])}, ["guess: must be finite"]), ({"guess": "abc"}, ["guess"]),
])
def test_periodic_orbit_arguments_are_checked_before_any_run(kw, words):
    args = {"h": 5e-3, "guess": (np.array([-0.39]), np.array([1.22])), **kw}
    with pytest.raises(ValueError) as ei:
        vcirun.periodic_orbit("rimless_wheel", "CVA", **args)
    for w in words:
        assert w in str(ei.value), str(ei.value)


def test_the_return_map_names_its_own_search_span():
    with pytest.raises(ValueError) as ei:
        vcirun.periodic_orbit("rimless_wheel", "CVA", h=1e-9, guess=(np.array([-0.39]), np.array([1.22])))
    msg = str(ei.value)
    assert msg.startswith("h: the return map's search for 1 impact on the section runs over T = 4 s at h = 1e-09")
    assert "raise h" in msg


@pytest.mark.parametrize("value", [1.5, -0.1, 1.0000001])
def test_a_restitution_parameter_outside_the_unit_interval_is_named(value):
    with pytest.raises(ValueError, match=rf"params.e: value {value:g} is the restitution coefficient of .* of "
                                         "system ball_in_box; it must be in \\[0, 1\\]"):
        vcirun.simulate("ball_in_box", "CVA", h=0.01, T=0.1, params={"e": value})
    from vcirun.scenes.registry import scene_data

    with pytest.raises(ValueError, match=rf"params.e: value {value:g} is the restitution coefficient of every "
                                         "contact of system cradle_gap_3"):   # (before any symbolic work)
        scene_data("cradle_gap_3").param_values({"e": value})
    d = {"name": "w", "coordinates": ["x"], "parameters": {"e": value, "m": 1.0}, "mass_matrix": [["m"]],
         "potential": "0", "constraints": [{"name": "wall", "phi": "x + 1", "restitution": "e"}],
         "q0": [0.0], "qdot0": [-1.0]}
    with pytest.raises(ValueError, match=rf"params.e: default value {value:g} is the restitution coefficient of "
                                         "constraint wall"):
        load_system_yaml(d)


def test_a_restitution_parameter_in_range_runs():
    tr = vcirun.simulate("ball_in_box", "CVA", h=0.01, T=0.5, params={"e": 1.0})
    assert tr.status == "ok"


def test_an_expression_of_many_terms_parses_in_linear_time():
    import sympy as sp

    from vcirun.mechanics.expressions import parse_expression

    names = {f"p{i}": sp.Symbol(f"p{i}") for i in range(1000)} | {"y": sp.Symbol("y")}
    for text in (" + ".join(f"p{i}*y" for i in range(770)), " - ".join(f"p{i}" for i in range(1000)),
                 "*".join(f"p{i}" for i in range(1000)), "/".join(f"p{i}" for i in range(1000))):
        assert len(text) <= CAPS["expression_characters"].limit
        t = time.perf_counter()
        e = parse_expression(text, names, "f")
        assert time.perf_counter() - t < 3.0, text[:40]
        assert len(e.args) >= 770


def test_a_long_sum_prints_as_code_python_compiles():
    import sympy as sp

    from vcirun.codegen.printer import MAX_CHAIN, pycode

    xs = sp.symbols(f"x0:{3 * MAX_CHAIN}")
    e = sp.Add(*[(i + 1) * x for i, x in enumerate(xs)])
    src = "def f(" + ", ".join(map(str, xs)) + "):\n    return " + pycode(e) + "\n"
    ns = {}
    exec(compile(src, "sum", "exec"), ns)
    v = np.arange(len(xs), dtype=float) / len(xs)
    assert ns["f"](*v) == pytest.approx(float(np.sum((np.arange(len(xs)) + 1) * v)), rel=1e-12)
    short = sp.Add(*xs[:10])
    assert pycode(short) == " + ".join(map(str, xs[:10]))   # short sums print as sympy prints them


def test_a_kernel_nested_past_the_translator_limit_stays_in_numba():
    from vcirun.codegen.c_emit import translate_module

    body = " + ".join(f"{i}.0*q[0]" for i in range(2500))
    small = " + ".join(f"{i}.0*q[0]" for i in range(60))
    text = ("from numba import njit\n\n@njit(cache=True)\ndef k_big(q, prm):\n    return " + body + "\n\n"
            "@njit(cache=True)\ndef k_small(q, prm):\n    return " + small + "\n")
    tr = translate_module(text, salt="x", min_stmts=0)
    assert "k_big" in tr.skipped and "recursion" in tr.skipped["k_big"]
    assert [k.name for k in tr.kernels] == ["k_small"]


# --- damaged results files: fuzzing -------------------------------------------------------------------------
def originals(n=3):
    out = {}
    for i in range(n):
        tr = make_traj(seed=i)
        a, arr = run_attrs(tr, "CVA", tr.h, 3.2 + i, ic_key=f"beta={3.2 + i:g}")
        out[f"r{i:04d}"] = ({**a, "run_id": f"r{i:04d}"}, arr)
    return out


def served_equals_written(path, runs) -> list:
    """Read the file every way a user can; what it serves must be what was written. Returns the run ids
    it served (StorageError: one line, nothing served)."""
    try:
        res = read_results(path)
    except StorageError as e:
        assert "\n" not in str(e)
        return []
    served = []
    for r in res.runs:
        try:
            tr = load_trajectory(path, r.run_id)
        except StorageError as e:
            assert "\n" not in str(e)
            continue
        a, arr = runs[r.run_id]
        for name, v in arr.items():
            got = np.asarray(getattr(tr, name))
            assert got.tobytes() == np.asarray(v).astype(got.dtype).tobytes(), (r.run_id, name)
        assert r.attrs["l2_error"] == a["l2_error"] and r.attrs["beta"] == a["beta"], r.run_id
        served.append(r.run_id)
    missing = set(runs) - set(r.run_id for r in res.runs)
    if missing and not (res.damaged or res.incomplete or res.notes):
        # nothing said about missing runs: acceptable only when the file's structure lost them (its
        # groups unreadable), which the readers report as StorageError above
        raise AssertionError(f"runs {sorted(missing)} missing without a word")
    return served


_ATTR_PROBE = """
import sys, h5py
from vcirun.run.trajectory_files import attr_items
def walk(o):
    attr_items(o.attrs)
    if isinstance(o, h5py.Group):
        for k in o:
            try:
                walk(o[k])
            except (KeyError, OSError, RuntimeError, ValueError):
                pass
try:
    with h5py.File(sys.argv[1], "r") as f:
        walk(f)
except (OSError, RuntimeError, ValueError, KeyError):
    pass
"""


def _attributes_read_in_time(path, seconds=30.0) -> bool:
    """Whether every attribute of the damaged file is read within `seconds`, in a child process (so
    that a file libhdf5 loops on fails the test instead of hanging the suite). libhdf5 never returns
    from reading a variable-length string whose global-heap collection is damaged (it spins in C);
    vcirun writes fixed-length text only, so its files have no global heap to damage."""
    import os
    import subprocess

    try:
        subprocess.run([sys.executable, "-c", _ATTR_PROBE, str(path)], timeout=seconds, capture_output=True,
                       env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])})
    except subprocess.TimeoutExpired:
        return False
    return True


@pytest.mark.parametrize("seed", range(12))
def test_random_damage_to_a_results_file_never_serves_changed_data(tmp_path, seed):
    runs = originals()
    path = write(tmp_path / "r.h5", runs)
    data = bytearray(path.read_bytes())
    rng = random.Random(seed)
    how = seed % 4
    if how == 0:     # single bit flips anywhere
        for _ in range(3):
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
    elif how == 1:   # a zeroed 512-byte block (seed 1: the block at byte 8805 of a file whose text was
        at = rng.randrange(len(data) - 512)   # variable-length, on which libhdf5 never returned)
        data[at:at + 512] = bytes(512)
    elif how == 2:   # a random 4 kB block
        at = rng.randrange(max(1, len(data) - 4096))
        data[at:at + 4096] = bytes(rng.randrange(256) for _ in range(4096))
    else:            # truncated
        data = data[: rng.randrange(len(data) // 2, len(data))]
    path.write_bytes(bytes(data))
    assert _attributes_read_in_time(path), "libhdf5 did not return from reading an attribute of the damaged file"
    damaged_file_is_reported_or_served_unchanged(path, runs)


def damaged_file_is_reported_or_served_unchanged(path, runs) -> None:
    """Every reader and a resume of the damaged file at `path`: one-line StorageErrors, damage reported,
    or the data as written; after a resume that succeeds, every run as written."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        served_equals_written(path, runs)
    try:   # a resume: recomputes or refuses in one line, never keeps changed data
        with ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY) as w:
            for rid, (a, arr) in runs.items():
                if rid not in w.complete_runs:
                    w.add_run(rid, a, arr)
            w.finish("complete")
    except StorageError as e:
        assert "\n" not in str(e)
        return
    assert served_equals_written(path, runs) == sorted(runs)


def text_spans(data: bytes) -> list:
    """(start, end) of the text a results file of `originals` holds: root attributes (format, config key,
    history, times), the batch's JSON attributes of each run, its keys, and its `fields` attribute."""
    needles = [b"vcirun-sweep", KEY.encode(), b'"status": "complete"', b'"core_method"', b'"tolerances"',
               b'"message"', b'"committed_at"', b"r0000", b"r0001", b"r0002", b'["q", ', b'"impacts"']
    spans = []
    for nd in needles:
        at = data.find(nd)
        while at >= 0:
            spans.append((at, at + len(nd)))
            at = data.find(nd, at + 1)
    return sorted(set(spans))


@pytest.mark.parametrize("seed", range(10))
def test_damage_to_the_text_of_a_results_file_is_reported_never_served(tmp_path, seed):
    """Fuzz rounds aimed at the strings (attributes and the batch's key and attrs datasets, stored
    fixed-length inside their objects): flipped bits, zeroed or random bytes over a piece of text.
    The file is read in time, and the readers and a resume report it or serve what was written."""
    runs = originals()
    path = write(tmp_path / "r.h5", runs)
    data = bytearray(path.read_bytes())
    assert b"GCOL" not in data   # no global-heap collection at all
    spans = text_spans(bytes(data))
    assert len(spans) >= 12, spans
    rng = random.Random(1000 + seed)
    for _ in range(1 + seed % 3):
        a, b = spans[rng.randrange(len(spans))]
        how = rng.randrange(3)
        if how == 0:
            data[rng.randrange(a, b)] ^= 1 << rng.randrange(8)
        elif how == 1:
            data[a:a + 64] = bytes(len(data[a:a + 64]))
        else:
            data[a:b] = bytes(rng.randrange(256) for _ in range(b - a))
    path.write_bytes(bytes(data))
    assert _attributes_read_in_time(path), "libhdf5 did not return from reading an attribute of the damaged file"
    damaged_file_is_reported_or_served_unchanged(path, runs)


def variable_length_copy(path, out) -> Path:
    """A copy of a results file with its text rewritten as variable-length strings (the layout of files
    written before vcirun stored text fixed-length; their checksums cover the same text)."""
    import shutil

    import h5py

    shutil.copyfile(path, out)
    with h5py.File(out, "a") as f:
        if legacy_text.MARK in f.attrs:   # (written by the writers that store text fixed-length only)
            del f.attrs[legacy_text.MARK]
        objs = [f]
        f.visititems(lambda name, o: objs.append(o) and None)
        for o in objs:
            for k in list(o.attrs):
                t = o.attrs.get_id(k).get_type()
                if t.get_class() == h5py.h5t.STRING and not t.is_variable_str():
                    v = o.attrs[k]
                    o.attrs[k] = v.decode() if np.ndim(v) == 0 else np.array([x.decode() for x in v],
                                                                             dtype=h5py.string_dtype())
            if isinstance(o, h5py.Group):
                for name in ("key", "attrs"):
                    if name in o and o[name].dtype.kind == "S":
                        vals = list(o[name].asstr()[()])
                        del o[name]
                        o.create_dataset(name, data=np.array(vals, dtype=object), dtype=h5py.string_dtype())
    return Path(out)


_READ_DAMAGED = """
import sys, time
import vcirun.io.legacy_text as L
from vcirun.io.errors import StorageError
from vcirun.io.reader import read_results
from vcirun.io.single import is_trajectory_file, read_single
L.PROBE_SECONDS = float(sys.argv[3])
for what, call in (("sweep", lambda: read_results(sys.argv[1])), ("again", lambda: read_results(sys.argv[1])),
                   ("single", lambda: read_single(sys.argv[2])),
                   ("is_single", lambda: is_trajectory_file(sys.argv[2]))):
    t0 = time.perf_counter()
    try:
        out = call()
        print(what, out if isinstance(out, bool) else "read")
    except StorageError as e:
        print(what, "StorageError", round(time.perf_counter() - t0, 1), str(e).replace(chr(10), " | "))
"""


def test_files_of_variable_length_text_are_read_and_a_damaged_heap_is_reported_in_time(tmp_path, monkeypatch):
    """Files written before text was fixed-length are read, their values unchanged; where their global
    heap is damaged, the readers' child process (vcirun.io.legacy_text) meets its deadline and the file
    is reported damaged in one line instead of hanging the reader."""
    import os
    import subprocess

    import h5py

    runs = originals()
    old = variable_length_copy(write(tmp_path / "new.h5", runs), tmp_path / "old.h5")
    with h5py.File(old, "r") as f:
        assert h5py.check_string_dtype(f.attrs.get_id("format").dtype).length is None   # variable-length
    assert served_equals_written(old, runs) == sorted(runs)
    tr = make_traj()
    single = variable_length_copy(tr.save(tmp_path / "one_new.h5"), tmp_path / "one.h5")
    back = read_single(single)
    assert back.q.tobytes() == tr.q.tobytes() and back.coordinates == tr.coordinate_names
    for p in (old, single):   # zero a block inside the global-heap collection: libhdf5 loops on it
        data = bytearray(p.read_bytes())
        at = data.find(b"GCOL")
        assert at > 0
        data[at + 16:at + 528] = bytes(512)
        p.write_bytes(bytes(data))
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    r = subprocess.run([sys.executable, "-c", _READ_DAMAGED, str(old), str(single), "4"], timeout=240,
                       capture_output=True, text=True, env=env)
    lines = dict(line.split(" ", 1) for line in r.stdout.splitlines())
    assert r.returncode == 0 and set(lines) == {"sweep", "again", "single", "is_single"}, (r.stdout, r.stderr)
    for what in ("sweep", "single"):
        assert lines[what].startswith("StorageError") and "variable-length text" in lines[what] \
            and "not read within 4 s" in lines[what], lines[what]
    assert lines["again"].startswith("StorageError 0.0 ")   # the verdict is kept for the file as it is
    assert lines["is_single"] == "False"
    monkeypatch.setattr(legacy_text, "PROBE_SECONDS", 4.0)
    with pytest.raises(StorageError, match="variable-length text") as e:   # a resume refuses it in one line
        with ResultsWriter(old, root_attrs={"name": "t"}, config_key=KEY) as w:
            w.finish("complete")
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("seed", range(12))
def test_random_damage_to_a_journal_never_serves_changed_data_nor_drops_runs_silently(tmp_path, seed):
    path = tmp_path / "r.h5"
    runs = originals(6)
    w = ResultsWriter(path, root_attrs={"name": "t"}, config_key=KEY)
    w.acquire()
    w.start()
    items = list(runs.items())
    for lo in range(0, 6, 2):
        for rid, (a, arr) in items[lo:lo + 2]:
            w.add_run(rid, a, arr)
        w.commit()
    w._close_journal()   # killed
    w._release_lock()
    jp = w.journal_path
    data = bytearray(jp.read_bytes())
    rng = random.Random(100 + seed)
    for _ in range(1 + seed % 3):
        data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
    jp.write_bytes(bytes(data))
    j = read_journal(jp)
    res = read_results(path)
    shown = {r.run_id for r in res.runs}
    if shown != set(runs):   # runs missing: the readers say so (skipped records) or the tail was torn
        assert res.notes or (j is not None and j.torn) or j is None, (sorted(shown), res.notes)
    served_equals_written(path, runs)


def test_a_resumed_file_of_variable_length_text_is_rewritten_fixed_length(tmp_path):
    """A session that resumes a file of an earlier vcirun rewrites its text fixed-length (the same text:
    its checksums still hold), so the readers no longer need the child process for it."""
    import h5py

    runs = originals()
    old = variable_length_copy(write(tmp_path / "new.h5", dict(list(runs.items())[:2])), tmp_path / "old.h5")
    with h5py.File(old, "r") as f:
        assert legacy_text.has_variable_text(f)
    with ResultsWriter(old, root_attrs={"name": "t"}, config_key=KEY) as w:
        assert sorted(w.complete_runs) == sorted(runs)[:2]
        rid, (a, arr) = list(runs.items())[2]
        w.add_run(rid, a, arr)
        w.finish("complete")
    with h5py.File(old, "r") as f:
        assert f.attrs[legacy_text.MARK] == b"fixed-length"
        found = []

        def visit(name, o):
            found.extend(f"{name}@{k}" for k in o.attrs if o.attrs.get_id(k).get_type().get_class() == h5py.h5t.STRING
                         and o.attrs.get_id(k).get_type().is_variable_str())
            if isinstance(o, h5py.Dataset) and o.dtype.kind == "O":
                found.append(name)

        visit("/", f)
        f.visititems(visit)
        assert found == []
    assert served_equals_written(old, runs) == sorted(runs)
