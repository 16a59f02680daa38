"""`vcirun verify` on the command line: a passing verification exits 0 and writes the
report and figure; bad input is a one-line error with exit 1; a failing check exits 1 after the table."""
from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

import vcirun
from vcirun.cli.main import app
from vcirun.verification import checks as ck
from vcirun.verification.suite import VerifyResult


@pytest.fixture
def runner():
    return CliRunner()


def test_verify_passes_and_writes_the_report(runner, tmp_path):
    out = tmp_path / "rep" / "report.md"
    r = runner.invoke(app, ["verify", "oscillator_wall", "--methods", "CVA", "--q0", "1.0", "--p0", "0", "--T", "6",
                            "--h", "0.04,0.02,0.01,0.005", "--output", str(out)])
    assert r.exit_code == 0, r.output
    assert "smooth order" in r.output and "L2 order through impacts" in r.output
    assert f"wrote {out}" in r.output and out.with_suffix(".png").is_file()
    text = out.read_text()
    assert text.startswith("# vcirun verify: oscillator_wall") and "## Details" in text
    assert "| h | L2 error | local slope | used in fit |" in text


@pytest.mark.parametrize("args, message", [
    (["--q0", "a,b", "--p0", "0"], "error: --q0: expected comma-separated numbers"),
    (["--methods", "CVA,NOPE"], "error: method: unknown method 'NOPE'"),
    (["--h", "0.1,0.05"], "error: h: an order needs at least 3 step sizes"),
    (["--param", "zeta=1"], "error: params.zeta: unknown parameter"),
])
def test_bad_input_is_one_line(runner, args, message):
    r = runner.invoke(app, ["verify", "oscillator_wall", *args])
    assert r.exit_code == 1
    assert message in r.output and len(r.output.strip().splitlines()) == 1, r.output


def test_a_failed_check_exits_1_and_warnings_do_not(runner, monkeypatch):
    """The command is a thin wrapper: its exit status follows VerifyResult.ok (fail -> 1, warn -> 0)."""
    def fake(verdicts):
        def run(system, **kw):
            res = VerifyResult(system="s", n=1, methods=["CVA"], q0=np.zeros(1), p0=np.zeros(1), T=1.0, h=[0.1],
                               params={})
            res.checks = [ck.Check(f"c{i}", "CVA", v, 1.0, "t", "e", f"note {v}") for i, v in enumerate(verdicts)]
            return res
        return run

    monkeypatch.setattr(vcirun, "verify", fake([ck.PASS, ck.WARN]))
    r = runner.invoke(app, ["verify", "oscillator_wall", "-q"])
    assert r.exit_code == 0 and "note warn" in r.output
    monkeypatch.setattr(vcirun, "verify", fake([ck.PASS, ck.FAIL, ck.WARN]))
    r = runner.invoke(app, ["verify", "oscillator_wall", "-q"])
    assert r.exit_code == 1 and "note fail" in r.output
