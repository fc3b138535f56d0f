"""The reporting layer: quantiles, the case record's stored layout and the table writers."""

import csv
import io
import json
import math

import pytest
import torch

from lightcurve_gp.evaluation.reporting import (
    RESULT_COLUMNS,
    CaseRecord,
    Quantiles,
    SeedRow,
    csv_text,
    format_quantiles,
    markdown_table,
    quantiles,
    write_report_table,
)


def test_quantiles_interpolate_linearly_and_ignore_missing_values():
    # order statistics 1, 2, 3, 4: positions 0.75, 1.5 and 2.25 between them
    assert quantiles([4.0, None, 1.0, math.nan, 3.0, 2.0]) == Quantiles(2.5, 1.75, 3.25)
    assert quantiles(torch.tensor([7.0, math.inf])) == Quantiles(7.0, 7.0, 7.0)
    assert all(math.isnan(v) for v in quantiles([None, math.nan]))
    assert format_quantiles(Quantiles(2.5, 1.75, 3.25), 1) == "2.5 [1.8, 3.2]"
    assert format_quantiles(quantiles([])) == "n/a"


def test_case_record_round_trips_through_json_and_refuses_another_format():
    rows = [SeedRow(0, "ukf", 1.0, 2.0, 3.0, 0.7, 0.1, 2.9, 0.01), SeedRow(1, "ukf", status="failed", error="x")]
    record = CaseRecord("abc", {"scenario.rho_true": 0.3}, [0, 1], ["ukf"], rows=rows, summary={"seeds": 2})
    data = json.loads(json.dumps(record.to_dict()))
    assert list(data["rows"][0]) == list(RESULT_COLUMNS)
    back = CaseRecord.from_dict(data)
    assert back == record
    assert back.rmse_deg("ukf").tolist()[0] == [1.0, 2.0, 3.0] and all(math.isnan(v) for v in back.rmse_deg("ukf")[1])
    assert back.metric("ukf", "nees_mean")[0] == 2.9 and math.isnan(back.metric("ukf", "nees_mean")[1])
    assert CaseRecord.from_dict({**data, "format": 0}) is None
    assert CaseRecord.from_dict({**data, "rows": [{"seed": 0}]}) is None  # a row without its estimator


def test_tables_are_markdown_and_full_precision_csv(tmp_path):
    md = markdown_table(["a", "b"], [[1, "x"], [2.5, ""]], note="two rows")
    assert md == "| a | b |\n|---|---|\n| 1 | x |\n| 2.5 |  |\n\ntwo rows\n"
    text = csv_text([{"a": 1 / 3, "b": None}, {"a": 2, "b": "y", "c": "dropped"}])
    assert list(csv.DictReader(io.StringIO(text))) == [{"a": repr(1 / 3), "b": ""}, {"a": "2", "b": "y"}]
    assert float(next(csv.DictReader(io.StringIO(text)))["a"]) == 1 / 3
    assert csv_text([]) == ""
    assert write_report_table(tmp_path, "t", ["a"], [[1]], [{"a": 1}]) == (tmp_path / "t.md").read_text()
    assert (tmp_path / "t.csv").read_text() == "a\n1\n"


@pytest.mark.parametrize("values", [[1.0, 2.0], [3.0]])
def test_quantiles_of_a_tensor_column_equal_those_of_its_list(values):
    assert quantiles(torch.tensor(values, dtype=torch.float64)) == quantiles(values)
