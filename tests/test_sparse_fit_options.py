"""The cheaper fits of the sparse GP (model.sparse: optimizer, fit_dtype, fit_subset, fit_inducing, fit_objective,
fit_form) and the bound they are compared on."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from lightcurve_gp.config.load import ConfigError, config_from_dict, config_to_dict, load_config
from lightcurve_gp.observation.fitting import (
    fit_hyperparameters,
    gpytorch_sgpr_model,
    gram_bound,
    inducing_sqdist,
    maximise_mll,
    seeded_subset,
    sgpr_bound,
)
from lightcurve_gp.observation.gp_base import GPTrainingSet
from lightcurve_gp.observation.sparse_gp import SparseGP, sgpr_cache
from lightcurve_gp.training.store import model_key

ROBUST = Path(__file__).resolve().parents[1] / "configs" / "boxwing_robust.yaml"
F64 = torch.float64
#: the options below are GPyTorch-form options; the robust config itself fits in the Gram form
GPYTORCH_FORM = ["model.sparse.fit_form=gpytorch"]
NEW_KEYS = ("optimizer", "fit_dtype", "fit_subset", "fit_inducing", "fit_objective", "fit_form")


def _data(n: int, seed: int = 0):
    """Unit quaternions, a constant m_past (unused by attitude_matrix inputs) and a smooth y of A(q) plus noise."""
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g, dtype=F64)
    q = q / q.norm(dim=-1, keepdim=True)
    y = 13.0 + torch.sin(2 * q[:, 0] * q[:, 3]) + 0.5 * q[:, 1] * q[:, 2] + 0.05 * torch.randn(n, generator=g,
                                                                                              dtype=F64)
    return q, torch.full((n,), 13.0, dtype=F64), y


def _model_cfg(*overrides: str):
    base = ["model.sparse.num_inducing=40", "model.sparse.iterations=8", *GPYTORCH_FORM]
    return load_config(ROBUST, base + list(overrides)).model


@pytest.fixture(scope="module")
def train():
    return _data(300)


@pytest.mark.parametrize("override, message", [
    ("model.sparse.optimizer=sgd", "model.sparse.optimizer: 'sgd' is not one of adam, lbfgs"),
    ("model.sparse.fit_dtype=float16", "model.sparse.fit_dtype: 'float16' is not one of float64, float32"),
    ("model.sparse.fit_subset=0", "model.sparse.fit_subset: 0 must be >= 1"),
    ("model.sparse.fit_subset=half", "model.sparse.fit_subset: expected an integer, got 'half'"),
    ("model.sparse.fit_inducing=1.5", "model.sparse.fit_inducing: expected an integer, got 1.5"),
    ("model.sparse.fit_objective=exact", "model.sparse.fit_objective: 'exact' is not one of sparse_bound, "
                                         "exact_subset"),
    ("model.sparse.fit_form=dense", "model.sparse.fit_form: 'dense' is not one of gpytorch, gram"),
])
def test_bad_fit_options_are_config_errors_naming_the_key(override, message):
    with pytest.raises(ConfigError) as err:
        load_config(ROBUST, [override])
    assert str(err.value) == message


def test_fewer_fit_inducing_inputs_cannot_be_moved():
    with pytest.raises(ConfigError) as err:
        load_config(ROBUST, ["model.sparse.fit_inducing=500", "model.sparse.optimize_inducing=true"])
    assert str(err.value).startswith("model.sparse.fit_inducing: cannot be combined with "
                                     "model.sparse.optimize_inducing")


def test_default_fit_options_leave_the_model_key_alone():
    """At their defaults the options are absent from the config dict (stored models keep their keys); any other
    value is written, read back and changes the key."""
    cfg = load_config(ROBUST, GPYTORCH_FORM)
    assert set(NEW_KEYS).isdisjoint(config_to_dict(cfg)["model"]["sparse"])
    keys = {model_key(cfg)}
    for override in ("optimizer=lbfgs", "fit_dtype=float32", "fit_subset=3000", "fit_inducing=500",
                     "fit_objective=exact_subset", "fit_form=gram"):
        extra = ["model.sparse.fit_subset=2000"] if override.startswith("fit_objective") else []
        changed = load_config(ROBUST, [*GPYTORCH_FORM, f"model.sparse.{override}", *extra])
        raw = config_to_dict(changed)
        assert override.split("=")[0] in raw["model"]["sparse"]
        assert config_from_dict(raw).model == changed.model and config_to_dict(config_from_dict(raw)) == raw
        keys.add(model_key(changed))
    assert len(keys) == 7


@pytest.mark.parametrize("overrides, message", [
    (["model.sparse.fit_objective=exact_subset"],
     "model.sparse.fit_subset: needed by model.sparse.fit_objective exact_subset (the points the exact evidence is "
     "fitted on)"),
    (["model.sparse.fit_objective=exact_subset", "model.sparse.fit_subset=2000", "model.sparse.fit_inducing=500"],
     "model.sparse.fit_inducing: not used by model.sparse.fit_objective exact_subset (the exact evidence has no "
     "inducing inputs)"),
    (["model.sparse.fit_objective=exact_subset", "model.sparse.fit_subset=2000",
      "model.sparse.optimize_inducing=true"],
     "model.sparse.optimize_inducing: not used by model.sparse.fit_objective exact_subset (the exact evidence has no "
     "inducing inputs)"),
])
def test_exact_subset_objective_needs_a_subset_and_no_inducing_options(overrides, message):
    with pytest.raises(ConfigError) as err:
        load_config(ROBUST, GPYTORCH_FORM + overrides)
    assert str(err.value) == message


@pytest.mark.parametrize("overrides, message", [
    (["model.sparse.fit_objective=exact_subset", "model.sparse.fit_subset=2000"],
     "model.sparse.fit_form: gram computes the collapsed bound, which model.sparse.fit_objective exact_subset does "
     "not use"),
    (["model.sparse.fit_dtype=float32"],
     "model.sparse.fit_form: gram needs model.sparse.fit_dtype float64 (K_uu + K_uf K_fu / sigma^2 rounded to "
     "float32 is not positive definite)"),
    (["model.ard=true"],
     "model.sparse.fit_form: gram fits one shared lengthscale; it cannot be combined with model.ard true"),
    (["model.sparse.optimize_inducing=true"],
     "model.sparse.fit_form: gram keeps the inducing inputs fixed; it cannot be combined with "
     "model.sparse.optimize_inducing"),
])
def test_gram_form_refuses_what_it_cannot_do(overrides, message):
    with pytest.raises(ConfigError) as err:
        load_config(ROBUST, ["model.sparse.fit_form=gram", *overrides])
    assert str(err.value) == message


def test_gram_bound_names_the_matrix_that_is_not_positive_definite():
    x = torch.zeros(4, 2, dtype=F64)  # four equal inducing inputs: K_uu has rank one
    with pytest.raises(ValueError) as err:
        gram_bound(x, x[:, 0], x, torch.tensor(1.0, dtype=F64), torch.tensor([1.0], dtype=F64),
                   torch.tensor(0.1, dtype=F64))
    assert str(err.value) == ("model.sparse.fit_form: gram: K_uu is not positive definite at theta1 1, sigma^2 0.1; "
                              "fit_form gpytorch adds a jitter where this form cannot")


def test_gram_bound_refuses_float32():
    x = torch.zeros(3, 2, dtype=torch.float32)
    with pytest.raises(ValueError, match="gram_bound needs float64 inputs"):
        gram_bound(x, x[:, 0], x, torch.tensor(1.0), torch.tensor(1.0), torch.tensor(0.1))


def test_gram_form_equals_gpytorchs_bound_and_gradient(train, monkeypatch):
    """The Gram form (K_uf K_fu, built in blocks of 7 columns: several blocks, the last one short) of the collapsed
    bound against GPyTorch's InducingPointKernel form: the value and the gradient over the raw hyperparameters, to
    rounding."""
    import gpytorch

    import lightcurve_gp.observation.fitting as fitting

    monkeypatch.setattr(fitting, "GRAM_BLOCK", 7)
    ts = GPTrainingSet.prepare(*train, _model_cfg(), None)
    z = ts.x[::7].clone()
    model, likelihood = gpytorch_sgpr_model(ts.x, ts.r, z, 0.8, torch.full((9,), 0.6, dtype=F64), 0.02, False)
    model.train()
    likelihood.train()
    base = model.base_covar
    params = [base.raw_outputscale, base.base_kernel.raw_lengthscale, likelihood.raw_noise]
    with gpytorch.settings.max_cholesky_size(10**9):
        value = gpytorch.mlls.ExactMarginalLogLikelihood(likelihood, model)(model(ts.x), ts.r)
    expected = torch.autograd.grad(value, params)
    gram = gram_bound(ts.x, ts.r, z, base.outputscale, base.base_kernel.lengthscale, likelihood.noise.reshape(()))
    got = torch.autograd.grad(gram, params)
    assert float(gram.detach()) == pytest.approx(float(value.detach()), rel=1e-12)
    for g, e in zip(got, expected):
        assert float(g) == pytest.approx(float(e), rel=1e-9)


def test_gram_bound_takes_one_shared_lengthscale(train):
    ts = GPTrainingSet.prepare(*train, _model_cfg(), None)
    one = torch.tensor(1.0, dtype=F64)
    with pytest.raises(ValueError, match="gram_bound needs one shared lengthscale, got 9"):
        gram_bound(ts.x, ts.r, ts.x[::7], one, torch.full((9,), 0.6, dtype=F64), one)
    assert inducing_sqdist(ts.x, ts.x[:3]).shape == (3, len(ts.r))


def test_gram_form_takes_gpytorchs_adam_steps(train):
    """The same Adam fit in both forms ends at the same hyperparameters (float64, to 1e-8 relative), away from the
    start."""
    q, m, y = train
    cfg = _model_cfg("model.fit_hyperparameters=true")
    z = GPTrainingSet.prepare(q, m, y, cfg, None).x[::7].clone()
    fits = [SparseGP.from_data(q, m, y, _model_cfg("model.fit_hyperparameters=true", f"model.sparse.fit_form={form}"),
                               inducing_points=z) for form in ("gpytorch", "gram")]
    values = [(f.theta1, float(f.theta2[0]), f.noise_std) for f in fits]
    assert values[1] == pytest.approx(values[0], rel=1e-8)
    assert values[0][0] != pytest.approx(cfg.theta1, rel=1e-2)


def test_bound_with_the_training_inputs_as_inducing_inputs_is_the_evidence(train):
    """With Z = X the Nyström approximation is exact and the trace term vanishes: the collapsed bound is the exact
    log marginal likelihood, computed here independently with a dense Gaussian."""
    q, m, y = _data(60)
    ts = GPTrainingSet.prepare(q, m, y, _model_cfg(), None)
    theta1, ls, noise = 0.7, torch.full((9,), 0.8, dtype=F64), 0.05
    k = theta1 * torch.exp(-0.5 * torch.cdist(ts.x / ls, ts.x / ls) ** 2) + noise * torch.eye(60, dtype=F64)
    evidence = torch.distributions.MultivariateNormal(torch.zeros(60, dtype=F64), k).log_prob(ts.r) / 60
    assert sgpr_bound(ts.x, ts.r, ts.x, theta1, ls, noise) == pytest.approx(float(evidence), abs=1e-6)
    # fewer inducing inputs: a lower bound
    assert sgpr_bound(ts.x, ts.r, ts.x[:10], theta1, ls, noise) < float(evidence)


def _bound_gradient(model, likelihood, x, r) -> float:
    """Largest |gradient| of the bound per point over the raw hyperparameters."""
    import gpytorch

    params = list(model.base_covar.parameters()) + list(likelihood.parameters())
    mll = gpytorch.mlls.ExactMarginalLogLikelihood(likelihood, model)
    with gpytorch.settings.max_cholesky_size(10**9):
        grads = torch.autograd.grad(mll(model(x), r), params)
    return max(float(g.abs().max()) for g in grads)


def test_lbfgs_ends_nearer_a_stationary_point_than_adam_in_as_many_evaluations(train):
    ts = GPTrainingSet.prepare(*train, _model_cfg(), None)
    z = ts.x[:30]
    finals, gradients = {}, {}
    for optimizer in ("adam", "lbfgs"):
        model, likelihood = gpytorch_sgpr_model(ts.x, ts.r, z, ts.outputscale, ts.lengthscale, ts.noise, False)
        params = list(model.base_covar.parameters()) + list(likelihood.parameters())
        history = maximise_mll(model, likelihood, ts.x, ts.r, params, iterations=40, lr=0.05, optimizer=optimizer)
        assert len(history) <= 41 and history[-1] > history[0]
        bound = sgpr_bound(ts.x, ts.r, z, float(model.base_covar.outputscale.detach()),
                           model.base_covar.base_kernel.lengthscale.detach().reshape(-1),
                           float(likelihood.noise.detach()))
        assert bound == pytest.approx(history[-1], abs=1e-10)  # the history's last value is the fitted bound
        finals[optimizer], gradients[optimizer] = history[-1], _bound_gradient(model, likelihood, ts.x, ts.r)
    assert finals["lbfgs"] > finals["adam"]
    assert gradients["lbfgs"] < 1e-3 * gradients["adam"], gradients  # near a stationary point, Adam far from one
    with pytest.raises(ValueError, match="optimizer must be adam or lbfgs, got 'sgd'"):
        maximise_mll(model, likelihood, ts.x, ts.r, params, iterations=1, lr=0.1, optimizer="sgd")


def test_fit_on_all_points_or_all_inducing_inputs_is_the_default_fit(train):
    """A subset as large as the data is the data in order, and fit_inducing = num_inducing draws the same k-means
    inducing inputs: both reproduce the default fit bit for bit."""
    default = SparseGP.from_data(*train, _model_cfg())
    for override in ("model.sparse.fit_subset=300", "model.sparse.fit_inducing=40"):
        other = SparseGP.from_data(*train, _model_cfg(override))
        assert other.fit_history == default.fit_history
        for name in ("z", "w", "p", "lengthscale", "outputscale", "noise"):
            assert torch.equal(getattr(other, name), getattr(default, name)), (override, name)


def test_cheaper_fits_condition_in_float64_on_all_points(train):
    """A float32 fit lands within float32 rounding of the float64 one; a subset, fewer inducing inputs or L-BFGS
    change the hyperparameters, the model still has all num_inducing inducing inputs and float64 caches, and the
    fit raised the bound on all points above that of the start (the paper's values)."""
    default = SparseGP.from_data(*train, _model_cfg())
    f32 = SparseGP.from_data(*train, _model_cfg("model.sparse.fit_dtype=float32"))
    assert f32.theta1 == pytest.approx(default.theta1, rel=1e-4)
    assert float(f32.noise) == pytest.approx(float(default.noise), rel=1e-4)
    assert torch.allclose(f32.lengthscale, default.lengthscale, rtol=1e-4)
    ts = GPTrainingSet.prepare(*train, _model_cfg(), None)
    start = sgpr_bound(ts.x, ts.r, default.z, ts.outputscale, ts.lengthscale, ts.noise)
    for override in ("model.sparse.fit_subset=150", "model.sparse.fit_inducing=20", "model.sparse.optimizer=lbfgs"):
        other = SparseGP.from_data(*train, _model_cfg(override))
        assert torch.equal(other.z, default.z) and other.w.dtype == F64 and other.p.dtype == F64
        assert not torch.equal(other.lengthscale, default.lengthscale), override
        assert sgpr_bound(ts.x, ts.r, other.z, other.theta1, other.lengthscale, float(other.noise)) > start, override


@pytest.mark.parametrize("optimizer", ["adam", "lbfgs"])
def test_exact_subset_fits_the_subset_evidence_and_conditions_on_all_points(train, optimizer):
    """fit_objective exact_subset: the hyperparameters are those of the exact GP's evidence fit on the same seeded
    subset (computed here without the sparse GP), and the cache is the SGPR's on all points at those values."""
    cfg = _model_cfg("model.sparse.fit_objective=exact_subset", "model.sparse.fit_subset=120",
                     f"model.sparse.optimizer={optimizer}")
    model = SparseGP.from_data(*train, cfg)
    ts = GPTrainingSet.prepare(*train, cfg, None)
    keep = seeded_subset(300, 120, 0, ts.x.device)
    theta1, ls, noise, history = fit_hyperparameters(ts.x[keep], ts.r[keep], ts.outputscale, ts.lengthscale, ts.noise,
                                                     ard=False, iterations=8, lr=cfg.fit_lr, optimizer=optimizer)
    assert model.fit_history == history and history[-1] > history[0]
    assert model.theta1 == theta1 and float(model.noise) == noise and torch.equal(model.lengthscale, ls)
    assert model.theta1 != ts.outputscale
    w, p = sgpr_cache(ts.x, ts.r, model.z, theta1, ls, noise)
    assert torch.allclose(model.w, w, rtol=0, atol=1e-12) and torch.allclose(model.p, p, rtol=0, atol=1e-12)
    assert model.num_inducing == 40
