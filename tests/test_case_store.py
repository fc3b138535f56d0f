"""The case store's resumable case (:func:`lightcurve_gp.sweep.store.resume_case`): computed once, read back after,
a failure stored with its error and retried."""

import json

import pytest

from lightcurve_gp.evaluation.reporting import CaseRecord, SeedRow
from lightcurve_gp.sweep.store import case_path, read_case, resume_case


def test_a_case_is_computed_once_and_read_back(tmp_path):
    calls = []

    def compute():
        calls.append(1)
        return {"per_seed": [{"seed": 3, "x": 0.25}]}, [SeedRow(3, "est", 1.0, 2.0, 3.0)]

    record, ran = resume_case(tmp_path, "abc", compute, values={"study": "t"}, seeds=[3], estimators=["est"])
    assert ran and record.ok and calls == [1]
    again, ran_again = resume_case(tmp_path, "abc", compute, values={"study": "t"}, seeds=[3], estimators=["est"])
    assert not ran_again and calls == [1]
    assert again.summary == record.summary == {"per_seed": [{"seed": 3, "x": 0.25}]}
    assert again.rmse_deg("est").tolist() == [[1.0, 2.0, 3.0]]
    # the sweep's own record format, at the sweep's place
    stored = json.loads(case_path(tmp_path, "abc").read_text())
    assert stored["format"] == CaseRecord("x", {}, [], []).to_dict()["format"]
    assert (stored["case_id"], stored["values"], stored["seeds"], stored["estimators"]) == ("abc", {"study": "t"}, [3],
                                                                                            ["est"])


def test_a_failing_case_is_stored_as_failed_and_retried(tmp_path):
    def broken():
        raise RuntimeError("no convergence")

    with pytest.raises(RuntimeError, match="no convergence"):
        resume_case(tmp_path, "k", broken, values={}, seeds=[1, 2], estimators=["a"])
    failed = read_case(case_path(tmp_path, "k"))
    assert failed.status == "failed" and failed.error == "RuntimeError: no convergence"
    assert "raise RuntimeError" in failed.traceback
    assert [(r.seed, r.estimator, r.status) for r in failed.rows] == [(1, "a", "failed"), (2, "a", "failed")]
    record, ran = resume_case(tmp_path, "k", lambda: ({"ok": True}, []), values={}, seeds=[1, 2], estimators=["a"])
    assert ran and record.ok and read_case(case_path(tmp_path, "k")).summary == {"ok": True}
