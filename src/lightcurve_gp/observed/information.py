"""What a light curve can say about the attitude before anything runs: a flat one says little.

A light curve tells the attitude through its variation; one that does not vary beyond its noise fits every attitude
about as well, and a filter run on it ends where it started (a small NIS says only that the noise is large). The
test is the scatter about the weighted mean, ``χ² = Σ_k ((m_k − m̄) / σ_k)²`` over the ``n`` samples: noise alone
gives ``χ² ≈ n − 1`` (± √(2(n − 1))), so at or below ``n − 1`` (or with a peak-to-peak below 2σ) the light curve
shows no variation beyond its noise and :func:`flat_light_curve` returns a warning in words. A stricter test (χ²
below its 99 % point) would also flag the paper's case at σ = 0.71 mag (χ² 664 for 600 degrees of freedom, a
variation of about a third of the noise), where the estimators still gain on the start; the warning is kept for
light curves that show nothing. ``σ_k`` is the file's ``mag_err`` when it has one, else the noise the run assumes
(``filter.measurement_noise`` for ``estimate``, ``--mag-err`` for ``invert``).
"""

from __future__ import annotations

import math

import numpy as np

from lightcurve_gp.observed.lightcurve_file import LightCurve

__all__ = ["flat_light_curve"]


def flat_light_curve(lc: LightCurve, *, noise_std: float) -> str | None:
    """A warning when ``lc`` varies no more than its noise (module docstring), else ``None``.

    Args:
        lc: the light curve (``mag`` and, when given, ``mag_err`` in mag).
        noise_std: the 1σ noise (mag) assumed where the file gives no ``mag_err``.
    """
    mag = np.asarray(lc.mag, dtype=np.float64)
    n = mag.size
    if n < 2:
        return None
    sigma = np.full(n, float(noise_std)) if lc.mag_err is None else np.asarray(lc.mag_err, dtype=np.float64)
    sigma = np.where(sigma > 0, sigma, float(noise_std))
    w = 1.0 / sigma ** 2
    mean = float(np.sum(w * mag) / np.sum(w))
    chi2 = float(np.sum(w * (mag - mean) ** 2))
    typical = float(np.median(sigma))
    peak_to_peak = float(np.ptp(mag))
    if chi2 > n - 1 and peak_to_peak >= 2.0 * typical:
        return None
    source = "its mag_err" if lc.mag_err is not None else "the noise the run assumes"
    return (f"{lc.source or 'the light curve'}: flat within its noise (peak to peak {peak_to_peak:.3g} mag, "
            f"RMS about the mean {math.sqrt(float(np.mean((mag - mean) ** 2))):.3g} mag, noise {typical:.3g} mag "
            f"from {source}; chi-square {chi2:.1f} for {n - 1} degrees of freedom, no more than noise alone gives): it "
            f"carries little information on the attitude, and the estimate will stay near its start")
