"""The ω-known USQUE step compiled into fused graphs (``filter.compile: true``, :attr:`UsqueParams.compile`).

One filter's step (B = 1) on the CPU is a few hundred small tensor operations — the sigma points, their
propagation, the model's prediction, the gain and the reset (:func:`lightcurve_gp.ukf.usque_step`) — and eager
torch spends microseconds of dispatch on each. :func:`compiled_usque_step` hands the very same function to
``torch.compile`` (inductor, fixed shapes): the step becomes a few generated C++ loops plus the
library calls that stay calls (the Cholesky factor, small matrix products), with the model's prediction fused in
when the model says it traces (``fuses_in_compiled_step``), else called eagerly between two compiled halves.

What cannot be inside one graph is a host synchronisation: the square root's fallback test, the model's finiteness
check and the renderer's zero-flux test read values back to Python. Under compilation those read-backs are left
out (``torch.compiler.is_compiling()`` in :func:`~lightcurve_gp.unscented.sqrt_psd`,
:func:`~lightcurve_gp.observation.base.check_inputs` and :meth:`~lightcurve_gp.render.Scene.magnitude`) and the
compiled step returns one flag instead: any square root that fell back, or a posterior that is not finite. A step so
flagged is done again by the eager :func:`~lightcurve_gp.ukf.usque_step`, which applies the fallback, raises or
warns exactly as the uncompiled filter does. The estimates of both paths therefore agree to rounding (the fused
loops sum in another order). The exact GP's mean is the one model-side change: inside the graph it is written
elementwise over blocks of training points (:func:`~lightcurve_gp.observation.kernels.blocked_kernel_sum`), so the
kernel row, its ``exp`` and the sum with ``α`` are one loop; eagerly it stays one matrix product.

Costs: the first call of each new shape (``B``, the state layout, the model; with per-filter increments
``(B, T, 4)`` also each run length ``T``) compiles — seconds to tens of seconds,
once per process, less when inductor's on-disk cache (``TORCHINDUCTOR_CACHE_DIR``) already holds the graph — and
each further call costs the compiled function's Python wrapper and guard checks, ~50–100 µs on this project's
CPU. The step's arithmetic is not reduced: the exact GP's mean (7 × 19 260 ``exp`` in the paper's case) stays, and
the generated loop's ``exp`` is slower than the eager one (MKL's), which is why the GPs with a variance and the
sparse GP keep their kernel rows eager.
"""

from __future__ import annotations

import functools

import torch
from torch import Tensor

from .filter_state import FilterState, StepRecord
from .usque_update import Prior, RunConstants, SigmaInputs, sigma_inputs, update_with_predictions

__all__ = ["compiled_usque_step"]


def _redo(new: FilterState, record: StepRecord) -> Tensor:
    """``()``: whether any filter's square root fell back or its posterior ``q̂``, ``P`` is not finite."""
    finite = torch.isfinite(new.q_hat).all() & torch.isfinite(new.P).all()
    return record.fallback.any() | ~finite


def _whole_step(run: RunConstants, state: FilterState, *, L_k: Tensor, G_k: Tensor, y_k: Tensor,
                observed_k: Tensor) -> tuple[FilterState, StepRecord, Tensor]:
    """:func:`lightcurve_gp.ukf.usque_step`, the model's prediction included, and :func:`_redo`."""
    from .ukf import usque_step

    new, record = usque_step(run, state, L_k=L_k, G_k=G_k, y_k=y_k, observed_k=observed_k)
    return new, record, _redo(new, record)


def _prior_half(run: RunConstants, state: FilterState, *, L_k: Tensor, G_k: Tensor) -> tuple[Prior, SigmaInputs]:
    """Steps 1–5 and the sigma attitudes the model is asked about."""
    from .ukf import usque_prior

    prior = usque_prior(run, state, L_k=L_k, G_k=G_k)
    return prior, sigma_inputs(run, state, prior)


def _update_half(run: RunConstants, state: FilterState, prior: Prior, R_qm: Tensor, y_sig: Tensor,
                 var_sig: Tensor | None, *, y_k: Tensor, observed_k: Tensor) -> tuple[FilterState, StepRecord, Tensor]:
    """Steps 6–9 from the model's predictions, and :func:`_redo`."""
    new, record = update_with_predictions(run, state, prior, R_qm, y_sig, var_sig, y_k=y_k, observed_k=observed_k)
    return new, record, _redo(new, record)


@functools.cache
def _compiled(fn):
    # not fullgraph: a model that reads a value back, or a process past torch's limit of recompilations per
    # function (many shapes or models), runs the rest eagerly instead of failing. cpp_wrapper: the graph's calls
    # (its loops, the library calls that stay) are made from generated C++ rather than Python: the UKF step's CPU
    # time 238 -> 126 µs (load 4-6), longer compiles
    return torch.compile(fn, dynamic=False, options={"cpp_wrapper": True})


def compiled_usque_step(run: RunConstants, state: FilterState, *, L_k: Tensor, G_k: Tensor, y_k: Tensor,
                        observed_k: Tensor) -> tuple[FilterState, StepRecord]:
    """:func:`lightcurve_gp.ukf.usque_step` (same arguments and result) as compiled graphs: one for the whole step
    when the model's ``fuses_in_compiled_step(variance)`` says so, else two around the model's eager call (models
    without that method are called eagerly); a step whose square root fell back or whose posterior is not finite
    is done again eagerly (module docstring)."""
    from .ukf import usque_step

    step = {"L_k": L_k, "G_k": G_k, "y_k": y_k, "observed_k": observed_k}
    fuses = getattr(run.model, "fuses_in_compiled_step", None)
    if fuses is not None and fuses(run.variance):
        new, record, redo = _compiled(_whole_step)(run, state, **step)
    else:
        prior, inputs = _compiled(_prior_half)(run, state, L_k=L_k, G_k=G_k)
        if bool(prior.failed.any()):
            return usque_step(run, state, **step)
        y_sig, var_sig = run.model(q=inputs.q, m_past=inputs.m_past, variance=run.variance, **inputs.theta)
        new, record, redo = _compiled(_update_half)(run, state, prior, inputs.R_qm, y_sig, var_sig, y_k=y_k,
                                                    observed_k=observed_k)
    return usque_step(run, state, **step) if bool(redo) else (new, record)
