"""The periodogram finds a known rate on an irregular, gapped light curve and refuses a rate range that excludes it."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from astropy.timeseries import LombScargle

from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.attitude.rotations import axis_angle_to_quat
from lightcurve_gp.config.load import load_config
from lightcurve_gp.inference.periodogram import FALSE_ALARM, detection_power, periodogram, resolution_rate_deg_s
from lightcurve_gp.photometry.render import Scene

ROOT = Path(__file__).resolve().parents[1]


def _gapped_curve(rate_deg_s: float, sigma: float = 0.05):
    """The box-wing spinning about its major axis (body z, stable) at ``rate_deg_s``, 1200 s at 1 Hz, then 40 % of
    the samples dropped in random runs and the rest jittered off the grid: irregular times with gaps."""
    cfg = load_config(ROOT / "configs" / "boxwing.yaml")
    scene = Scene.from_config(cfg, rho=0.5)
    q0 = axis_angle_to_quat(torch.tensor([0.3, -0.5, 0.81], dtype=torch.float64) / 1.0000617, torch.tensor(0.7))
    omega = torch.tensor([0.0, 0.0, math.radians(rate_deg_s)], dtype=torch.float64)
    q, _ = propagate(q0, omega, cfg.shape.inertia_kg_m2, 1.0, 1200)
    m = scene.magnitude(q).numpy()
    rng = np.random.default_rng(4)
    keep = np.ones(m.size, dtype=bool)
    for start in rng.choice(m.size - 60, size=12, replace=False):
        keep[start:start + 40] = False
    t = np.arange(m.size, dtype=np.float64) + rng.uniform(-0.3, 0.3, m.size)
    return t[keep], m[keep] + sigma * rng.standard_normal(keep.sum())


def test_known_rate_found_on_an_irregular_gapped_curve():
    t, y = _gapped_curve(2.0)
    assert np.diff(t).max() > 30 and not np.allclose(np.diff(t), 1.0)  # gaps, irregular
    pg = periodogram(t, y, np.full(t.size, 0.05), rate_range_deg_s=(0.05, 5.0))
    # the box-wing repeats its curve twice per turn about z: the strongest peak sits at twice the rotation frequency
    assert abs(360.0 * pg.peak_frequency_hz[0] - 4.0) < 0.04
    assert np.min(np.abs(pg.rates_deg_s - 2.0)) < 0.02  # within 1 %
    assert np.all((pg.rates_deg_s >= 0.05) & (pg.rates_deg_s <= 5.0))
    assert 0.0 <= pg.power.min() and pg.power.max() <= 1.0


def test_rate_range_that_excludes_the_periodogram_is_one_line():
    t, y = _gapped_curve(2.0)
    with pytest.raises(ValueError, match=r"^rate range 10-20 deg/s excludes every periodogram candidate") as err:
        periodogram(t, y, rate_range_deg_s=(10.0, 20.0), peaks=1)
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match="rate range: need 0 < min < max"):
        periodogram(t, y, rate_range_deg_s=(3.0, 1.0))


def test_resolution_rate():
    assert resolution_rate_deg_s(600.0) == pytest.approx(0.6)


def test_a_curve_of_pure_noise_has_no_detection_and_proposes_no_rate_outside_the_range():
    """White noise at 0.71 mag: the strongest peak is no detection, so a range that excludes it is no error and the
    search gets no candidate from it; the clean curve's peak is a detection far above the threshold."""
    t, y = _gapped_curve(2.0)
    noise = np.random.default_rng(7).normal(13.0, 0.71, t.size)
    pg = periodogram(t, noise, np.full(t.size, 0.71), rate_range_deg_s=(10.0, 20.0), peaks=1)
    assert not pg.detection and pg.peak_power[0] <= pg.threshold_power and pg.rates_deg_s.size <= 3
    assert periodogram(t, y, rate_range_deg_s=(0.05, 5.0)).detection


@pytest.mark.slow  # ~6 s of white-noise periodograms; keeps the fast lane under its 2 minutes
def test_the_detection_threshold_holds_its_false_alarm_rate_on_white_noise():
    """Independent check by simulation (astropy's periodogram on the module's grid, 1 Hz samples to 0.5 Hz): the
    strongest peak of white noise exceeds the threshold no more often than its false-alarm probability (Bonferroni is
    conservative; binomial slack), the threshold is not vacuous at a loose probability, and it grows as that falls."""
    rng = np.random.default_rng(11)
    t = np.arange(300.0)
    span = t[-1] - t[0]
    frequency = np.arange(1.0, 10.0 * span * 0.5 + 1.0) / (10.0 * span)
    peaks = np.array([LombScargle(t, rng.normal(0.0, 1.0, t.size), nterms=2).power(frequency).max()
                      for _ in range(100)])
    independent = 2 * 2 * span * 0.5  # as the module counts them for nterms = 2
    assert np.mean(peaks > detection_power(t.size, 2, independent, false_alarm=0.1)) <= 0.16
    assert np.mean(peaks > detection_power(t.size, 2, independent, false_alarm=0.9)) >= 0.2
    assert detection_power(300, 2, 150.0, FALSE_ALARM) > detection_power(300, 2, 150.0, 0.1)


def test_a_slow_trend_puts_no_peak_where_a_harmonic_aliases():
    # a tumbler far below one turn over the arc: a ramp of 0.5 mag over 600 s and white noise of 0.1 mag at 1 Hz.
    # A 2-term model near 0.5 Hz has its second harmonic near 1 Hz, which the 1 Hz samples alias onto ~0 Hz: it fits
    # the ramp and made a "peak" at 180 deg/s as strong as the trend's, and with the rate range below it, a refusal.
    # The grid now stops where the highest harmonic meets the Nyquist frequency (0.25 Hz, 90 deg/s)
    rng = np.random.default_rng(1058)
    t = np.arange(601.0)
    y = 0.5 * t / 600.0 + 0.1 * rng.standard_normal(t.size)
    pg = periodogram(t, y, np.full(t.size, 0.1), rate_range_deg_s=(0.05, 5.0), nterms=2)
    assert float(pg.frequency_hz.max()) <= 0.25 + float(pg.frequency_hz[0])
    assert np.all(360.0 * pg.peak_frequency_hz < 90.5)
    assert 360.0 * float(pg.peak_frequency_hz[0]) < 1.0                     # the strongest peak is the trend
