"""Shared fixtures: compiled modules per (system, method) and a seeded random generator.

Compiled modules are cached in-process by vcirun.codegen.build and on disk under
$VCIRUN_CACHE_DIR (default ~/.cache/vcirun): a cold run pays numba's compile time once per
(system, kernel set); set VCIRUN_CACHE_DIR to an empty directory to measure a cold run.
"""
from __future__ import annotations

import numpy as np
import pytest


def _compiled(system, method):
    """(MechanicalSystem, compiled module, parameter vector) for a built-in name or a system."""
    from vcirun.codegen.build import load_module
    from vcirun.mechanics import get_scene
    from vcirun.methods import resolve_method

    s = get_scene(system) if isinstance(system, str) else system
    return s, load_module(s, resolve_method(method).kernel_set()), s.param_values()


@pytest.fixture(scope="session")
def compiled():
    """compiled(system, method) -> (system, module, prm); modules are memoised by vcirun itself."""
    return _compiled


@pytest.fixture
def rng():
    return np.random.default_rng(20140527)


@pytest.fixture(autouse=True)
def _build_log(request):
    """With $VCIRUN_TEST_BUILD_LOG set: one JSON line per test that generated a kernel module (its
    node id, the modules, the test's wall time), to find the tests that pay the cold builds."""
    import os

    path = os.environ.get("VCIRUN_TEST_BUILD_LOG")
    if not path:
        yield
        return
    import json
    import time

    from vcirun.codegen import build

    n0, t0 = len(build.BUILD_LOG), time.perf_counter()
    yield
    new = [e for e in build.BUILD_LOG[n0:] if not e["cached"]]
    if new:
        with open(path, "a") as f:
            f.write(json.dumps({"test": request.node.nodeid, "wall_s": round(time.perf_counter() - t0, 2),
                                "modules": [f"{e['system']}|{e['kernels']}" for e in new]}) + "\n")


# Tests that are the only users, in the default suite, of a kernel module whose cold build costs
# 35-100 s (numba compiles the event loop again for every scene and method family: docs/performance.md,
# "Cold builds"). Each feature they check keeps a cheaper representative in the default suite (named
# after the arrow); they run in `make test-all` (-m '') and with -m unique_module.
UNIQUE_MODULE = {
    "test_contacts.py::test_double_pendulum_walls_orders[MCVAC": "the CVA variant on the same scene",
    "test_contacts.py::test_cradle_reference_and_five_balls": "test_newton_cradle (3 balls, every restitution)",
    "test_contacts.py::test_double_pendulum_walls_energy_loss_is_newtons": "test_ball_in_box_impacts_and_errors",
    "test_contacts.py::test_yaml_constraints_with_a_restitution_parameter": "test_zeno_ball_settles_and_stays (YAML, restitution: e)",
    "test_resting.py::test_cart_lift_off_bounces_and_resettles_second_order": "the reference's lift-off test",
    "test_resting.py::test_held_phase_is_second_order_and_conserves_energy[CVA]": "test_zeno_ball_settles_and_stays",
    "test_resting.py::test_bead_release_time_converges[CVA]": "the reference's bead release test",
    "test_extremes_contact.py::test_several_impacts_per_step_ball": "the CVA/VCI accumulation tests",
    "test_extremes_contact.py::test_grazing_double_pendulum[": "its CVA and VCI variants (MCVAA/MCVAC only)",
    "test_extremes_api.py::test_accumulation_message_names_the_onset[VCI]": "the CVA variant",
    "test_forced.py::test_forced_orders_damped_oscillator_wall[CVA4]": "test_order_survives_the_impacts_oscillator",
    "test_forced.py::test_forced_orders_damped_oscillator_wall[MCVAA]": "the MCVAC and MCVA variants",
}


def pytest_collection_modifyitems(config, items):
    for item in items:
        for key in UNIQUE_MODULE:
            if key in item.nodeid and not (key.endswith("grazing_double_pendulum[")
                                           and not item.nodeid.endswith(("MCVAA]", "MCVAC]"))):
                item.add_marker(pytest.mark.slow)
                item.add_marker(pytest.mark.unique_module)
