"""The generalized MCVA (Section 4.4) runs on every discrete Lagrangian of the
library for s = 1, 2, 3 (and 4), and refuses an unsupported combination with a clear message.

The default suite runs the generated module uncompiled (simulate's loader=
vcirun.codegen.evaluate.python_module_for: same source text, no numba compile) on a short run with
one impact; the compiled runs of the whole matrix on the Figure 3 setting are marked slow
(one numba compile of ~10-20 s per combination).
"""
from __future__ import annotations

import numpy as np
import pytest

import vcirun
import vcirun.run.api
from vcirun.discrete.lagrangians import LIBRARY
from vcirun.modified import MH_LDS
from vcirun.methods.table import METHODS, resolve_method
from vcirun.methods.table import generalized_mcva
from vcirun.codegen.evaluate import python_module_for


@pytest.fixture
def uncompiled():
    """simulate's loader for the generated module run as Python."""
    return python_module_for


def _short_state():
    s = vcirun.run.resolve.resolve_system("cart_pendulum")
    q0 = np.array([0.3, 0.2])
    return q0, s.mass_matrix(q0) @ np.array([-1.0, 1.0])


@pytest.mark.parametrize("s", [1, 2, 3])
@pytest.mark.parametrize("ld", MH_LDS)
def test_generalized_mcva_runs_uncompiled(uncompiled, ld, s):
    q0, p0 = _short_state()
    tr = vcirun.simulate("cart_pendulum", "MCVA", ld=ld, mh_order=s, flow_order=4, h=0.02, T=0.5, q0=q0, p0=p0,
                         loader=uncompiled)
    assert tr.status == "ok", tr.message
    assert len(tr.impacts) == 1 and tr.impacts[0] == pytest.approx(0.163, abs=0.01)
    assert tr.Hmod is not None and np.all(np.isfinite(tr.Hmod))
    # the impact step conserves the truncation (partial flows + R^MCVA)
    assert np.max(np.abs(np.diff(tr.Hmod)[tr.impact_step])) < 1e-10
    assert tr.method == f"MCVA[{ld},s={s},g4]"


def test_generalized_mcva_order4_and_flow6_uncompiled(uncompiled):
    q0, p0 = _short_state()
    for ld, s, g in [("SVC", 4, 4), ("SVA", 4, 6), ("SE2", 2, 6)]:
        tr = vcirun.simulate("cart_pendulum", "MCVA", ld=ld, mh_order=s, flow_order=g, h=0.02, T=0.5, q0=q0, p0=p0,
                             loader=uncompiled)
        assert tr.status == "ok" and len(tr.impacts) == 1


def test_named_methods():
    a, c = METHODS["MCVAA"], METHODS["MCVAC"]
    assert (a.ld, a.partial, a.reset, a.mh_order, a.flow_order) == ("SVA", "gauss", "mcva", 4, 4)
    assert (c.ld, c.partial, c.reset, c.mh_order, c.flow_order) == ("SVC", "gauss", "mcva", 3, 4)
    assert a.properties == {"conserves_mh": True, "symplectic": True, "explicit_ld": False, "forcing": "order 2"}
    assert c.properties == {"conserves_mh": True, "symplectic": True, "explicit_ld": True, "forcing": "order 2"}
    m = resolve_method("MCVA", ld="midpoint", mh_order=2, flow_order=6)
    assert (m.ld, m.reset, m.partial, m.mh_order, m.flow_order) == ("midpoint", "mcva", "gauss", 2, 6)
    assert m.kernel_set().modified == ("midpoint", 2, 6)
    assert resolve_method("MCVA") == generalized_mcva()


@pytest.mark.parametrize("kwargs, field", [
    (dict(ld="SVD"), "ld"), (dict(ld=3), "ld"),
    (dict(mh_order=0), "mh_order"), (dict(mh_order=5), "mh_order"), (dict(mh_order=3.0), "mh_order"),
    (dict(mh_order=True), "mh_order"), (dict(flow_order=2), "flow_order"), (dict(flow_order=5), "flow_order"),
    (dict(flow_order=8), "flow_order"), (dict(order=3), "options"),
])
def test_refuses_unsupported_combinations(kwargs, field):
    with pytest.raises(ValueError) as exc:
        generalized_mcva(**kwargs)
    msg = str(exc.value)
    assert msg.startswith(f"{field}:") and "\n" not in msg
    # and through the public API, before any compile
    with pytest.raises(ValueError, match=f"^{field}:"):
        vcirun.simulate("cart_pendulum", "MCVA", h=0.01, T=0.1, beta=3.2, **kwargs)


def test_accepts_a_forced_system():
    """The MCVA family takes forced systems (orders: tests/scenes/test_forced.py): the
    full step is the forced DEL, the partial flow adds the force to the modified equations."""
    tr = vcirun.simulate("damped_oscillator", "MCVAC", h=0.01, T=1.0)
    assert tr.ok and np.all(np.diff(tr.H) < 0)  # linear drag: the energy decreases every step


@pytest.mark.slow
@pytest.mark.parametrize("s", [1, 2, 3])
@pytest.mark.parametrize("ld", MH_LDS)
def test_generalized_mcva_compiled_figure3_setting(ld, s):
    """Every (Ld, s) runs compiled on the Figure 3 setting and its impact steps conserve the truncation.
    Accuracy needs a second-order Ld and s >= 2: with s = 1 the reset conserves eta = H + O(h) and the
    partial flow follows eta's dynamics, so every impact costs O(h) (measured L2 ~ 1.3 against 0.02-0.05
    for s >= 2, and a spurious fourth impact); SE1/SE2 are first order anyway (L2 5-11)."""
    tr = vcirun.simulate("cart_pendulum", "MCVA", ld=ld, mh_order=s, h=1e-2, T=5.0, beta=3.2)
    assert tr.status == "ok", tr.message
    exact = [0.72901, 2.17544, 3.71608]   # vcirun.reference("cart_pendulum", T=5, beta=3.2).impacts
    assert len(tr.impacts) >= 3 and abs(tr.impacts[0] - exact[0]) < 5e-3
    assert np.max(np.abs(np.diff(tr.Hmod)[tr.impact_step])) < 1e-8
    if LIBRARY[ld].order >= 2 and s >= 2:
        assert len(tr.impacts) == 3
        np.testing.assert_allclose(tr.impacts, exact, atol=2e-3)
    if s >= 3:  # a third-order truncation is conserved better than H (order <= 2)
        assert np.ptp(tr.Hmod) < np.ptp(tr.H)
