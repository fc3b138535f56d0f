"""The convexinv reference's own pieces (the program itself is not shipped): its parameter file, the parsing of its
iterations, the nats between its answer and its start at the truth, and the refusal of a missing program."""

import math

import pytest

from experiments.convexinv_reference import ITERATION, POLES, dnats, main, parameter_file


def test_the_parameter_file_frees_pole_and_period_and_fixes_the_rest():
    lines = parameter_file(220.0, -10.0, 5.76198, 50).splitlines()
    assert len(lines) == 13
    assert lines[0].split() == ["220.000000", "1"] and lines[1].split() == ["-10.000000", "1"]
    assert lines[2].split() == ["5.761980000", "1"]
    assert [ln.split()[1] for ln in lines[8:12]] == ["0", "0", "0", "0"]  # phase function and Lambert fixed
    assert lines[6].split() == ["6", "6"] and lines[-1] == "50"
    assert len(POLES) == 16 and len(set(POLES)) == 16


def test_the_last_iteration_is_read():
    text = "some header\n1  chi2 2.500000  dev 0.040000  alambda 0.1\n2  chi2 0.409800  dev 0.016100  alambda 0.01\n"
    steps = ITERATION.findall(text)
    assert steps[-1] == ("0.409800", "0.016100")


def test_dnats_is_the_chi2_difference_over_twice_the_intensity_variance():
    sigma_i = 0.02 * math.log(10.0) / 2.5
    row = {"noise_mag": 0.02, "basin_chi2": 0.5 + 2 * 3.0 * sigma_i ** 2, "best_chi2": 0.5}
    assert dnats(row) == pytest.approx(3.0, rel=1e-12)


def test_a_missing_program_is_refused_by_name(tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--convexinv", str(tmp_path / "nowhere"), "--out", str(tmp_path / "out")])
    assert stop.value.code == 2
    assert f"--convexinv {tmp_path / 'nowhere'}: no such program" in capsys.readouterr().err
