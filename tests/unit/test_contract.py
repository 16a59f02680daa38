"""The contract between generated kernels and numba units, and the one record table (issue 16)."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import vcirun
from vcirun.core import record
from vcirun.codegen import units
from vcirun.codegen.build import SYSTEM_KERNELS, KernelSet
from vcirun.run.trajectory_files import IMPACT_ARRAYS, TRAJECTORY_ARRAYS, trajectory_payload
from vcirun.methods.table import METHODS, resolve_method
from vcirun.run.trajectory import Trajectory

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("unit", units.UNITS, ids=lambda u: u.path)
def test_unit_declarations_match_their_code(unit):
    units.check_unit(unit)  # provides what it defines, requires what it reads


def test_a_stale_declaration_is_named(tmp_path, monkeypatch):
    """A unit reading a name it does not declare, or declaring one it never uses, is refused with the
    name (so the table cannot drift from the code)."""
    (tmp_path / "u.py").write_text("import math\n\ndef f(x):\n    return sys_phi(x, prm) + math.pi\n")
    monkeypatch.setattr(units, "PKG", tmp_path)
    with pytest.raises(units.ContractError, match=r"uses \['prm', 'sys_phi'\] without declaring it"):
        units.check_unit(units.Unit("u.py", provides=("f",), requires=()))
    with pytest.raises(units.ContractError, match=r"declares \['NDOF'\] as required but never uses it"):
        units.check_unit(units.Unit("u.py", provides=("f",), requires=("sys_phi", "prm", "NDOF")))
    with pytest.raises(units.ContractError, match=r"declared to provide \['g'\]"):
        units.check_unit(units.Unit("u.py", provides=("f", "g"), requires=("sys_phi", "prm")))


def _paths(ks):
    return [u.path for u in units.select_units(ks)]


def test_units_are_selected_by_what_the_generated_part_provides():
    cva = _paths(METHODS["CVA"].kernel_set())
    assert "collision/reset_cva.py" in cva and "collision/reset_vci.py" not in cva  # needs ld_Edv
    assert "maps/gauss.py" not in cva
    vci = _paths(METHODS["VCI"].kernel_set())
    assert "collision/reset_vci.py" in vci
    mcva = _paths(METHODS["MCVAC"].kernel_set())
    assert {"maps/gauss.py", "collision/reset_mcva.py"} <= set(mcva)
    # the system-only set: the continuous dynamics, no step, no loop
    sysk = _paths(SYSTEM_KERNELS)
    assert "maps/dynamics.py" in sysk and "maps/steps.py" not in sysk and "collision/algorithm1.py" not in sysk


def test_a_binding_nothing_can_meet_names_the_missing_symbol():
    """R^VCI without the energy gradient of its stage: the error names the unit and the symbol."""
    ks = KernelSet(full_stages=(("SVC", 1.0),), partial="ld", reset="vci", vci_stage=None)
    with pytest.raises(units.ContractError, match=r"reset_vci is provided by collision/reset_vci.py, which "
                                                  r"requires ld_Edv"):
        units.select_units(ks)


def test_bindings_come_from_the_method_data():
    for name, m in METHODS.items():
        b = units.bindings(m.kernel_set())
        assert b["reset"] == units.RESETS[m.reset] and b["partial"] == units.PARTIALS[m.partial]
        assert b["modified_energy"] == units.MODIFIED_ENERGY[m.reset == "mcva"]


def test_generated_part_defines_its_declared_names():
    from vcirun.codegen.derive import generated_source
    from vcirun.scenes.declarations import get_scene

    s = get_scene("oscillator_wall")
    for ks in (SYSTEM_KERNELS, METHODS["VCI"].kernel_set(), resolve_method("SVA").kernel_set()):
        units.check_generated(generated_source(s, ks), ks)


# --- the record table -------------------------------------------------------------------------------

def test_trajectory_storage_and_schema_follow_the_record_table():
    names = {f.name for f in dataclasses.fields(Trajectory)}
    assert {f.name for f in record.FIELDS} <= names
    assert set(IMPACT_ARRAYS) == set(record.stored_names("impacts"))
    assert set(TRAJECTORY_ARRAYS) == {"t"} | set(record.stored_names("trajectory"))
    doc = (ROOT / "docs" / "results_schema.md").read_text()
    assert record.schema_markdown() in doc, "docs/results_schema.md: regenerate the datasets table from " \
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
    """The row added through the table (issue 16's example): impact_impulse is the lambda of
    p+ = p- + lambda grad phi(q) of every impact, and for CVA the elastic one."""
    tr = vcirun.simulate("cart_pendulum", method, h=1e-2, T=5.0, beta=3.2)
    assert tr.ok and len(tr.impacts) == 3 and tr.impact_impulse.shape == (3,)
    grad = np.array([1.0, 0.0])  # phi = y
    for lam, pm, pp in zip(tr.impact_impulse, tr.impact_p_minus, tr.impact_p_plus):
        assert np.allclose(pp - pm, lam * grad, rtol=1e-13, atol=1e-13)
        assert lam > 0
    if method == "CVA":
        from vcirun.scenes.declarations import get_scene

        s = get_scene("cart_pendulum")
        for lam, q, pm in zip(tr.impact_impulse, tr.impact_q, tr.impact_p_minus):
            W = np.linalg.inv(s.mass_matrix(q))
            assert lam == pytest.approx(-2 * (grad @ W @ pm) / (grad @ W @ grad), rel=1e-12)


def test_impact_impulse_is_stored_and_read_back(tmp_path):
    tr = vcirun.simulate("oscillator_wall", "CVA", h=1e-2, T=5.0)
    attrs, arrays = trajectory_payload(tr, store_arrays=False)
    assert np.array_equal(arrays["impact_impulse"], tr.impact_impulse)
