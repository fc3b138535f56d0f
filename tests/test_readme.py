"""The README's library snippet runs as printed, starts from the configured error and prints the median RMSE."""

import os
import re
from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.metrics import total_angle_deg
from lightcurve_gp.attitude.rotations import euler321_to_quat, identity_quat

ROOT = Path(__file__).resolve().parents[1]


def library_snippet() -> str:
    text = (ROOT / "README.md").read_text()
    section = text.split("## As a library", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


@pytest.mark.slow  # conditions a GP on 1260 points and filters 600 steps
def test_readme_snippet_runs_and_scores_every_seed(capsys):
    namespace: dict = {}
    cwd = os.getcwd()
    os.chdir(ROOT)
    try:
        exec(compile(library_snippet(), "README.md", "exec"), namespace)
    finally:
        os.chdir(cwd)
    rmse, errors = namespace["rmse"], namespace["errors"]
    assert rmse.shape == (10, 3) and bool(torch.isfinite(rmse).all())
    assert errors.shape == (10, 601, 3)
    assert namespace["history"].fallbacks.sum() == 0
    # every filter starts from the configured initial error (yaw, pitch, roll) = (-10, 5, -10) deg
    truth, cfg = namespace["truth"], namespace["cfg"]
    start = total_angle_deg(truth.q_true[0], namespace["history"].q_est[:, 0])
    initial = euler321_to_quat(torch.deg2rad(torch.tensor(cfg.scenario.initial_error_deg, dtype=torch.float64)))
    assert torch.allclose(start, total_angle_deg(identity_quat(dtype=torch.float64), initial), atol=1e-9)
    # what it prints is the per-axis median over the seeds of the RMSE over 400-600 s, recomputed here by hand
    printed = [float(v) for v in re.findall(r"-?\d+\.\d+", capsys.readouterr().out.split("tensor(", 1)[1])]
    window = (truth.times >= 400) & (truth.times <= 600)
    by_hand = errors[:, window].pow(2).mean(1).sqrt().median(0).values
    assert printed == pytest.approx(by_hand.tolist(), abs=1e-4)
