"""Shared test helper: run a call under a watchdog (nothing in vcirun may loop forever)."""
from __future__ import annotations

import threading


def guarded(fn, timeout=60.0):
    """Run fn() in a daemon thread (the compiled loop releases the GIL) and return its value; fail the
    test if it has not returned within `timeout` seconds, re-raise its exception otherwise."""
    box = {}

    def target():
        try:
            box["value"] = fn()
        except BaseException as e:  # re-raised in the test thread
            box["error"] = e

    th = threading.Thread(target=target, daemon=True)
    th.start()
    th.join(timeout)
    assert not th.is_alive(), f"did not return within {timeout} s (endless loop?)"
    if "error" in box:
        raise box["error"]
    return box["value"]
