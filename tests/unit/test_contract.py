"""The contract between generated kernels and numba units (the declarations of vcirun.codegen.roles),
and the one record table."""
from __future__ import annotations

import ast
import dataclasses
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import vcirun
from vcirun.core import record
from vcirun.codegen import roles, units
from vcirun.codegen.kernel_set import SYSTEM_KERNELS, KernelSet
from vcirun.run.trajectory_files import IMPACT_ARRAYS, TRAJECTORY_ARRAYS, trajectory_payload
from vcirun.methods.table import METHODS, resolve_method
from vcirun.run.trajectory import Trajectory

ROOT = Path(__file__).resolve().parents[2]
RESET_UNITS = tuple(units.Unit(r.unit) for r in roles.RESETS.values())


@pytest.mark.parametrize("unit", units.UNITS + RESET_UNITS, ids=lambda u: u.path)
def test_unit_declarations_match_their_code(unit):
    units.check_unit(unit)  # reads only what it defines or imports; imports what is declared; arities


def test_no_name_is_provided_by_two_units():
    units.check_units()


def _unit(tmp_path, monkeypatch, text):
    (tmp_path / "u.py").write_text(text)
    monkeypatch.setattr(units, "PKG", tmp_path)
    return units.Unit("u.py")


def test_a_stale_declaration_is_named(tmp_path, monkeypatch):
    """A unit reading a name it neither defines nor imports, importing one it never uses or that
    nothing declares, or calling with the wrong number of arguments is refused with the name."""
    u = _unit(tmp_path, monkeypatch, "import math\n\ndef f(x):\n    return sys_phi(x, prm) + math.pi\n")
    with pytest.raises(units.ContractError, match=r"uses \['prm', 'sys_phi'\] without defining or importing it"):
        units.check_unit(u)
    u = _unit(tmp_path, monkeypatch, "from vcirun.codegen.roles import NDOF, sys_phi\n\n"
                                     "def f(x, prm):\n    return sys_phi(x, prm)\n")
    with pytest.raises(units.ContractError, match=r"imports \['NDOF'\] from vcirun.codegen.roles but never uses it"):
        units.check_unit(u)
    u = _unit(tmp_path, monkeypatch, "from vcirun.codegen.roles import sys_psi\n\n"
                                     "def f(x, prm):\n    return sys_psi(x, prm)\n")
    with pytest.raises(units.ContractError, match=r"imports \['sys_psi'\] from vcirun.codegen.roles, which declares"):
        units.check_unit(u)
    u = _unit(tmp_path, monkeypatch, "from vcirun.maps.linalg import solve_kinda\n\n"
                                     "def f(A, b):\n    return solve_kinda(A, b, 2)\n")
    with pytest.raises(units.ContractError, match=r"imports \['solve_kinda'\] from vcirun.maps.linalg, which does not"):
        units.check_unit(u)


_NO_WRAPPER = '@njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True)\n'


def test_a_function_python_calls_keeps_its_wrappers(tmp_path, monkeypatch):
    """A unit function compiled without numba's Python wrapper cannot be called from Python (its entry
    point is a null address): one Python calls on a module (roles.ENTRY) or a role's implementation
    is refused with that flag; any other function may drop it."""
    head = "from numba import njit\n\n"
    for name, params in (("hamiltonian", "q, p, prm"), ("reset_cva", ", ".join(roles.ROLES["reset"].params))):
        u = _unit(tmp_path, monkeypatch, head + _NO_WRAPPER + f"def {name}({params}):\n    return 0\n")
        with pytest.raises(units.ContractError, match=rf"{name} is compiled without numba's Python wrapper, but "
                                                      r"Python calls it .*: drop no_cpython_wrapper"):
            units.check_unit(u)
    units.check_unit(_unit(tmp_path, monkeypatch, head + _NO_WRAPPER + "def inner(q, p, prm):\n    return 0\n"))


def test_a_passed_check_is_stamped_and_any_change_is_checked_again(tmp_path, monkeypatch):
    """A unit that passed is not parsed again by a later process (its stamp in the cache), but a
    changed unit, or changed declarations, are checked anew: the stamp names everything the check
    reads."""
    from vcirun.codegen import cache_store

    monkeypatch.setenv(cache_store.ENV, str(tmp_path / "cache"))
    good = "from vcirun.codegen.roles import sys_phi\n\ndef f(x, prm):\n    return sys_phi(x, prm)\n"
    u = _unit(tmp_path, monkeypatch, good)
    units.check_unit(u)
    stamp = units._stamp(u)
    assert stamp.exists()
    calls = []
    monkeypatch.setattr(units, "_check", lambda path, text: calls.append(path))
    units.check_unit(u)
    assert calls == []                      # stamped: not checked again
    monkeypatch.undo()
    monkeypatch.setenv(cache_store.ENV, str(tmp_path / "cache"))
    u = _unit(tmp_path, monkeypatch, good.replace("sys_phi(x, prm)\n", "sys_phi(x)\n"))
    assert units._stamp(u) != stamp
    with pytest.raises(units.ContractError, match="sys_phi called with 1 arguments"):
        units.check_unit(u)
    assert not units._stamp(u).exists()     # a failed check leaves no stamp
    u = _unit(tmp_path, monkeypatch, good)
    monkeypatch.setitem(roles.ROLES, "extra_role", roles.RoleDecl("extra_role", ("a",), 0, ("a",), "a test role"))
    assert units._stamp(u) != stamp         # the declarations are part of the stamp


def test_the_interpreted_tier_checks_only_units_outside_the_package(monkeypatch):
    """The package's units are checked by every compiled build and by this suite; the interpreted
    tier runs them as Python and checks only a unit registered from outside."""
    from vcirun.methods.table import METHODS

    ks = METHODS["CVA"].kernel_set()
    seen = []
    monkeypatch.setattr(units, "check_unit", lambda u: seen.append(u.path))
    monkeypatch.setattr(units, "check_generated", lambda text, ks: None)
    units.assemble("", ks, check_package=False)
    assert seen == []
    units.assemble("", ks)
    assert len(seen) == len(units.select_units(ks)) > 5
    outside = units.Unit(str(units.PKG / "maps" / "linalg.py"))   # (an absolute path: a unit from outside)
    monkeypatch.setattr(units, "select_units", lambda ks: [units.Unit("maps/newton.py"), outside])
    seen.clear()
    units.assemble("", ks, check_package=False)
    assert seen == [outside.path]


def test_arity_is_checked_at_every_call_and_every_role_implementation(tmp_path, monkeypatch):
    u = _unit(tmp_path, monkeypatch, "from vcirun.codegen.roles import sys_phi\n\n"
                                     "def f(x, prm):\n    return sys_phi(x)\n")
    with pytest.raises(units.ContractError, match=r"u.py:4: sys_phi called with 1 arguments; it takes \(q, prm\)"):
        units.check_unit(u)
    u = _unit(tmp_path, monkeypatch, "from vcirun.maps.linalg import solve_small\n\n"
                                     "def f(A, b):\n    return solve_small(A, b)\n")
    with pytest.raises(units.ContractError, match=r"solve_small called with 2 arguments; it takes \(A, b, n, tiny=\.\.\.\)"):
        units.check_unit(u)
    u = _unit(tmp_path, monkeypatch, "from vcirun.codegen.roles import reset\n\n"
                                     "def f(q, p):\n    return reset(q, p, q, 1.0)\n")
    with pytest.raises(units.ContractError, match=r"reset called with 4 arguments; it takes \(q, pm, d, s0, dE, E_pre"):
        units.check_unit(u)
    # an implementation of a role with the arguments swapped, or one too few
    for params in ("pm, q, d, s0, dE, E_pre, vpre, dtau, tau_rem, h, t, prm, ntol, maxit, pp",
                   "q, pm, d, s0, dE, E_pre, vpre, dtau, tau_rem, h, t, prm, ntol, maxit"):
        u = _unit(tmp_path, monkeypatch, f"def reset_cva({params}):\n    return 1, s0\n")
        with pytest.raises(units.ContractError, match=r"reset_cva implements the role 'reset', whose signature is "
                                                      r"\(q, pm, d, s0"):
            units.check_unit(u)


def test_the_reset_protocol_is_declared_once():
    """The reset role's 15 parameters live in vcirun.codegen.roles; every reset unit has them, and
    Algorithm 1 calls the role with as many."""
    r = roles.ROLES["reset"]
    assert len(r.params) == 15 and r.returns == ("iterations", "s")
    for d in roles.RESETS.values():
        sig = units._signatures(__import__("ast").parse(units.Unit(d.unit).text))
        assert sig[d.function] == (r.params, 0), d.name


def _paths(ks):
    return [u.path for u in units.select_units(ks)]


def test_units_are_selected_by_what_the_generated_part_provides():
    cva = _paths(METHODS["CVA"].kernel_set())
    assert "collision/reset_cva.py" in cva and "collision/reset_vci.py" not in cva
    assert "maps/gauss.py" not in cva
    vci = _paths(METHODS["VCI"].kernel_set())
    assert "collision/reset_vci.py" in vci and "collision/reset_cva.py" not in vci   # the bound reset only
    mcva = _paths(METHODS["MCVAC"].kernel_set())
    assert {"maps/gauss.py", "collision/reset_mcva.py"} <= set(mcva)
    # the system-only set: the continuous dynamics, no step, no loop, no reset
    sysk = _paths(SYSTEM_KERNELS)
    assert "maps/dynamics.py" in sysk and "maps/steps.py" not in sysk and "collision/algorithm1.py" not in sysk
    assert not any("reset_" in p for p in sysk)


def test_a_binding_nothing_can_meet_names_the_missing_symbol():
    """R^VCI without the energy gradient of its stage: the error names the unit and the symbol."""
    ks = KernelSet(full_stages=(("SVC", 1.0),), partial="ld", reset="vci", parts=())
    with pytest.raises(units.ContractError, match=r"reset_vci is provided by collision/reset_vci.py, which "
                                                  r"requires ld_Edv"):
        units.select_units(ks)


def test_bindings_and_kernel_sets_come_from_the_descriptors():
    for name, m in METHODS.items():
        ks = m.kernel_set()
        b = units.bindings(ks)
        r = roles.reset_map(m.reset)
        assert b["reset"] == r.function and b["partial"] == roles.PARTIALS[m.partial].function
        assert b["modified_energy"] == roles.MODIFIED_ENERGY[m.has_modified_energy][1]
        assert [p for p, _ in ks.parts] == [p for p in roles.PARTS if p in set(r.needs) | set(
            roles.PARTIALS[m.partial].needs)]
        assert (ks.part("energy_gradient") is not None) == ("energy_gradient" in r.needs)
        assert m.has_modified_energy == r.modified_hamiltonian
        assert ("Hmod" in r.fills) == m.has_modified_energy
    with pytest.raises(ValueError, match="reset: unknown reset 'bogus'"):
        roles.reset_map("bogus")


def test_the_kernel_abi_of_the_shared_build_is_the_declarations():
    from vcirun.codegen import shared

    kernels = {k.name for _, kind, k, _ in shared.LAYOUT if kind == "kernel"}
    assert kernels == {k.name for k in roles.KERNELS.values() if k.core}
    assert set(shared.SCALARS) | {a for a, _ in shared.ARRAYS} == {
        n for n, c in roles.CONSTANTS.items() if c.slot is not None}
    for part, names in units.GENERATED.items():
        assert set(names) == {n for n, k in roles.KERNELS.items() if k.part == part} | {
            n for n, c in roles.CONSTANTS.items() if c.part == part}


def test_a_declaration_called_from_python_says_where_the_numbers_are():
    with pytest.raises(units.ContractError, match="sys_M is a generated kernel"):
        roles.sys_M(np.zeros(1), np.zeros(0), np.zeros((1, 1)))
    with pytest.raises(units.ContractError, match="reset is a role"):
        roles.reset(*range(15))


# --- names Python calls on a module ---------------------------------------------------------------

def _holds_module(node) -> bool:
    """The names vcirun's code binds a loaded module to: mod, self.mod, c.mod, self.base."""
    return (isinstance(node, ast.Name) and node.id == "mod") or (isinstance(node, ast.Attribute) and (
        node.attr == "mod" or (node.attr == "base" and isinstance(node.value, ast.Name) and node.value.id == "self")))


def _called_names(tree) -> set:
    """Attribute names read on a module holder, and the string (or f-string pattern, {..} -> *)
    names passed to getattr / hasattr on one."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _holds_module(node.value) and not node.attr.startswith("__"):
            out.add(node.attr)
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("getattr", "hasattr")
              and node.args and _holds_module(node.args[0]) and len(node.args) >= 2):
            a = node.args[1]
            if isinstance(a, ast.Constant) and isinstance(a.value, str) and not a.value.startswith("__"):
                out.add(a.value)
            elif isinstance(a, ast.JoinedStr):
                out.add("".join(v.value if isinstance(v, ast.Constant) else "*" for v in a.values))
    return out


def test_entry_declares_every_name_python_calls_on_a_module():
    """Every name vcirun's Python code calls (or reads) on a loaded module is declared: an ENTRY point,
    a generated constant, or a per-Ld kernel <LD>_<suffix> of LD_ENTRY."""
    declared = {n for names in roles.ENTRY.values() for n in names} | set(roles.CONSTANTS)
    declared.add("TIER")   # set by the loader on an interpreted module (vcirun.codegen.kernel_cache), not generated
    ld_patterns = {f"*_{s}" for s in roles.LD_ENTRY}
    found = {}
    for path in sorted((ROOT / "vcirun").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if rel.startswith(("vcirun/maps/", "vcirun/collision/", "vcirun/codegen/")):
            continue   # the units themselves, and the assembler (which handles modules generically)
        for name in _called_names(ast.parse(path.read_text())):
            found.setdefault(name, set()).add(rel)
    missing = {n: sorted(w) for n, w in found.items() if n not in declared and n not in ld_patterns}
    assert not missing, f"called on a module but not declared in vcirun.codegen.roles.ENTRY: {missing}"
    assert {"integrate", "hamiltonian", "mh_energy", "impact_direction", "sys_force"} <= set(found)   # the scan sees them
    # and every declared entry point is met by the units of its part
    for ks in (SYSTEM_KERNELS, METHODS["CVA"].kernel_set(), METHODS["MCVAC"].kernel_set()):
        provided = {n for u in units.select_units(ks) for n in u.provides} | set(units.bindings(ks)) | {
            n for p in units.generated_parts(ks) for n in units.GENERATED[p]}
        assert set(units.entry_points(ks)) <= provided


def test_units_have_no_undefined_name_for_a_linter():
    """`ruff check --select F821` on the units: every name they call is imported (declared)."""
    ruff = shutil.which("ruff") or str(Path(sys.executable).parent / "ruff")
    if not Path(ruff).exists():
        pytest.skip("ruff is not installed (pip install ruff)")
    out = subprocess.run([ruff, "check", "--select", "F821,F401", "--output-format", "concise",
                          "vcirun/maps", "vcirun/collision", "vcirun/codegen/roles.py"], cwd=ROOT,
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


def test_generated_part_defines_its_declared_names():
    from vcirun.codegen.derive import generated_source
    from vcirun.scenes.registry import get_scene

    s = get_scene("oscillator_wall")
    for ks in (SYSTEM_KERNELS, METHODS["VCI"].kernel_set(), resolve_method("SVA").kernel_set()):
        units.check_generated(generated_source(s, ks), ks)


# --- the record table -------------------------------------------------------------------------------

def test_trajectory_storage_and_schema_follow_the_record_table():
    names = {f.name for f in dataclasses.fields(Trajectory)}
    assert {f.name for f in record.FIELDS} <= names
    assert set(IMPACT_ARRAYS) == set(record.stored_names("impacts"))
    assert set(TRAJECTORY_ARRAYS) == {"t"} | set(record.stored_names("trajectory"))
    doc = (ROOT / "docs" / "reference" / "results_schema.md").read_text()
    assert record.schema_markdown() in doc, "docs/reference/results_schema.md: regenerate the datasets table from " \
                                            "vcirun.core.record.schema_markdown()"
    consts = record.module_constants()
    for f in record.FIELDS:
        assert f"{f.index_name} = " in consts


def test_settings_vector_names_every_setting():
    with pytest.raises(ValueError, match="missing"):
        record.settings_vector(constrained=True)
    v = record.settings_vector(constrained=True, newton_tol=1e-12, max_iter=50, event_tol=1e-13,
                               max_impacts_step=64, energies=False, resting_contact=True)
    assert v.dtype == np.float64 and v[record.SETTINGS.index("max_iter")] == 50


@pytest.mark.parametrize("method", ["CVA", "VCI", "MCVAC"])
def test_impact_impulse_is_the_recorded_momentum_jump(method):
    """The row added through the table: impact_impulse is the lambda of
    p+ = p- + lambda grad phi(q) of every impact, and for CVA the elastic one."""
    tr = vcirun.simulate("cart_pendulum", method, h=1e-2, T=5.0, beta=3.2)
    assert tr.ok and len(tr.impacts) == 3 and tr.impact_impulse.shape == (3,)
    grad = np.array([1.0, 0.0])  # phi = y
    for lam, pm, pp in zip(tr.impact_impulse, tr.impact_p_minus, tr.impact_p_plus):
        assert np.allclose(pp - pm, lam * grad, rtol=1e-13, atol=1e-13)
        assert lam > 0
    if method == "CVA":
        from vcirun.scenes.registry import get_scene

        s = get_scene("cart_pendulum")
        for lam, q, pm in zip(tr.impact_impulse, tr.impact_q, tr.impact_p_minus):
            W = np.linalg.inv(s.mass_matrix(q))
            assert lam == pytest.approx(-2 * (grad @ W @ pm) / (grad @ W @ grad), rel=1e-12)


def test_impact_impulse_is_stored_and_read_back(tmp_path):
    tr = vcirun.simulate("oscillator_wall", "CVA", h=1e-2, T=5.0)
    attrs, arrays = trajectory_payload(tr, store_arrays=False)
    assert np.array_equal(arrays["impact_impulse"], tr.impact_impulse)
