"""The README's library snippet runs as printed, starts from the configured error and prints the median RMSE; every
relative link of the documentation resolves."""

import os
import re
from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.metrics import total_angle_deg
from lightcurve_gp.attitude.rotations import euler321_to_quat, identity_quat

ROOT = Path(__file__).resolve().parents[1]


DOCUMENTS = ("README.md", "experiments/README.md", "docs/**/*.md", "experiments/results/**/*.md")


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
    start = total_angle_deg(truth.q_true[:, 0], namespace["history"].q_est[:, 0])  # (10,)
    initial = euler321_to_quat(torch.deg2rad(torch.tensor(cfg.scenario.initial_error_deg, dtype=torch.float64)))
    assert torch.allclose(start, total_angle_deg(identity_quat(dtype=torch.float64), initial), atol=1e-9)
    # what it prints is the per-axis median over the seeds of the RMSE over 400-600 s, recomputed here by hand
    printed = [float(v) for v in re.findall(r"-?\d+\.\d+", capsys.readouterr().out.split("tensor(", 1)[1])]
    window = (truth.times >= 400) & (truth.times <= 600)
    by_hand = errors[:, window].pow(2).mean(1).sqrt().median(0).values
    assert printed == pytest.approx(by_hand.tolist(), abs=1e-4)


def heading_anchors(markdown: str) -> set[str]:
    """GitHub's anchors of a Markdown text's headings: lower case, punctuation dropped, spaces as hyphens."""
    text = re.sub(r"```.*?```", "", markdown, flags=re.S)
    titles = re.findall(r"^#+\s+(.+?)\s*$", text, flags=re.M)
    return {re.sub(r"[^\w\- ]", "", t.lower()).replace(" ", "-") for t in titles}


def relative_links(path: Path) -> list[str]:
    """The link and image targets of a Markdown file that are neither URLs nor code."""
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    text = re.sub(r"`[^`\n]*`", "", text)
    return [t for t in re.findall(r"\]\(([^)\s]+)\)", text) if not re.match(r"[a-z][a-z0-9+.-]*:", t)]


def broken_links(root: Path) -> list[str]:
    """``file: target`` for every relative link under ``root`` whose file, or heading anchor, does not exist."""
    files = sorted({p for pattern in DOCUMENTS for p in root.glob(pattern)})
    broken = []
    for path in files:
        for target in relative_links(path):
            name, _, anchor = target.partition("#")
            dest = (path.parent / name) if name else path
            missing = not dest.exists()
            if missing or (anchor and dest.suffix == ".md" and anchor not in heading_anchors(dest.read_text())):
                broken.append(f"{path.relative_to(root)}: {target}")
    return broken


def test_documentation_links_resolve():
    assert broken_links(ROOT) == []


def test_link_check_finds_a_missing_file_and_a_missing_anchor(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "a.md").write_text("# A page\n\n## Threads\n")
    (tmp_path / "README.md").write_text(
        "[ok](docs/a.md) [ok](docs/a.md#threads) [gone](docs/b.md#x) [bad](docs/a.md#missing) "
        "[web](https://example.org) `[code](nowhere.md)`\n")
    assert broken_links(tmp_path) == ["README.md: docs/b.md#x", "README.md: docs/a.md#missing"]
