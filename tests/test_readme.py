"""The README's library snippet runs as printed and scores every seed."""

import os
import re
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]


def library_snippet() -> str:
    text = (ROOT / "README.md").read_text()
    section = text.split("## As a library", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_readme_snippet_runs_and_scores_every_seed(capsys):
    namespace: dict = {}
    cwd = os.getcwd()
    os.chdir(ROOT)
    try:
        exec(compile(library_snippet(), "README.md", "exec"), namespace)
    finally:
        os.chdir(cwd)
    rmse = namespace["rmse"]
    assert rmse.shape == (10, 3) and bool(torch.isfinite(rmse).all())
    assert namespace["errors"].shape == (10, 601, 3)
    assert namespace["history"].fallbacks.sum() == 0
    assert "tensor(" in capsys.readouterr().out
