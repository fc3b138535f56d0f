"""GP observation models: exactness against closed forms and GPyTorch, fast variance, SGPR limit, model files."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import pytest
import torch

from lightcurve_gp.config.load import (
    ConfigError,
    ExactModelConfig,
    ModelConfig,
    SparseModelConfig,
    config_to_dict,
    load_config,
)
from lightcurve_gp.observation.exact_gp import ExactGP, fast_variance_error
from lightcurve_gp.observation.fitting import gpytorch_exact_model
from lightcurve_gp.observation.inputs import InputMap
from lightcurve_gp.observation.kernels import (
    EXP_CLAMP,
    cross_kernel_cache,
    exp_neg_sqdist,
    lengthscale_to_theta2,
    theta2_to_lengthscale,
)
from lightcurve_gp.observation.serialization import FORMAT_VERSION, ModelFileError, build_model, load_model, save_model
from lightcurve_gp.observation.sparse_gp import FLOAT32_VARIANCE_TOL, SparseGP, kmeans, variance_factor

F64 = torch.float64
PAPER = dict(theta1=1.0, theta2=0.25, noise_std=0.1)


BOXWING = Path(__file__).resolve().parents[1] / "configs" / "boxwing.yaml"
_EXACT_KEYS = {"fit_iterations", "fit_subset", "fast_variance_neighbors"}
_SPARSE_KEYS = {"num_inducing": "num_inducing", "optimize_inducing": "optimize_inducing",
                "sparse_iterations": "iterations"}


def _cfg(**kw) -> ModelConfig:
    """A model config from flat keywords; those of one GP kind go to its section."""
    exact = {"fast_variance_neighbors": 64} | {k: kw.pop(k) for k in _EXACT_KEYS & set(kw)}
    sparse = {"num_inducing": 50} | {_SPARSE_KEYS[k]: kw.pop(k) for k in set(_SPARSE_KEYS) & set(kw)}
    base = dict(kind="exact", **PAPER, variance="fast") | kw
    return ModelConfig(**base, exact=ExactModelConfig(**exact), sparse=SparseModelConfig(**sparse))


def _variance(model, q, m, choice):
    return model.predict(q, m, variance=choice)[1]


def _data(n: int, seed: int = 0):
    """Unit quaternions, m_past around 13 mag and y a smooth function of both plus a little noise."""
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g, dtype=F64)
    q = q / q.norm(dim=-1, keepdim=True)
    m_past = 13.0 + 0.5 * torch.randn(n, generator=g, dtype=F64)
    y = (13.0 + torch.sin(2 * q[:, 0]) + 0.5 * q[:, 1] * q[:, 2] + 0.8 * (m_past - 13.0)
         + 0.05 * torch.randn(n, generator=g, dtype=F64))
    return q, m_past, y


def _closed_form(q, m_past, y, qt, mt, theta1=1.0, theta2=0.25, noise_std=0.1):
    """Textbook GP posterior with the paper's kernel, by a plain Cholesky."""
    x = torch.cat([q, m_past[:, None]], 1)
    xt = torch.cat([qt, mt[:, None]], 1)
    k = theta1 * torch.exp(-torch.cdist(x, x) ** 2 / theta2) + noise_std**2 * torch.eye(len(x), dtype=F64)
    ks = theta1 * torch.exp(-torch.cdist(xt, x) ** 2 / theta2)
    chol = torch.linalg.cholesky(k)
    mu = y.mean()
    mean = mu + ks @ torch.cholesky_solve((y - mu)[:, None], chol)[:, 0]
    v = torch.linalg.solve_triangular(chol, ks.T, upper=False)
    return mean, theta1 - (v * v).sum(0)


@pytest.fixture(scope="module")
def train():
    return _data(200)


@pytest.fixture(scope="module")
def test_pts():
    q, m, _ = _data(30, seed=1)
    return q, m


@pytest.fixture(scope="module")
def exact(train):
    return ExactGP.from_data(*train, _cfg())


@pytest.fixture(scope="module")
def sparse(train):
    return SparseGP.from_data(*train, _cfg(kind="sparse"))


# ----------------------------------------------------------------------------------------------- interface

@pytest.mark.parametrize("which", ["exact", "sparse"])
@pytest.mark.parametrize("batch", [(), (7,), (2, 3)])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_shapes_and_dtypes(which, batch, dtype, exact, sparse):
    # a copy: a float64 -> float32 -> float64 round trip would round the shared fixture's caches
    model = copy.deepcopy(exact if which == "exact" else sparse).to(dtype)
    g = torch.Generator().manual_seed(3)
    q = torch.randn(*batch, 4, generator=g, dtype=dtype)
    m = 13.0 + torch.randn(batch, generator=g, dtype=dtype)
    mean, var = model(q=q, m_past=m)
    assert mean.shape == batch and var.shape == batch
    assert mean.dtype == dtype and var.dtype == dtype
    assert bool((var >= 0).all()) and bool(torch.isfinite(mean).all())
    mean2, none = model.predict(q, m, variance="none")
    assert none is None
    torch.testing.assert_close(mean2, mean)
    # m_past broadcasts against q's batch shape
    mean3, _ = model.predict(q, torch.tensor(13.0, dtype=dtype))
    assert mean3.shape == batch


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
@pytest.mark.parametrize("which", ["exact", "sparse"])
def test_cuda_matches_cpu(which, exact, sparse, test_pts):
    model = exact if which == "exact" else sparse
    q, m = test_pts
    mean, var = model.predict(q, m)
    try:
        model.to("cuda")
        mean_c, var_c = model.predict(q.cuda(), m.cuda())
        torch.testing.assert_close(mean_c.cpu(), mean, rtol=1e-9, atol=1e-9)
        # the sparse variance's quadratic form is float32 on both devices, each within its bound of the float64 form
        float32 = getattr(model, "p_factor", None) is not None
        var_atol = 2 * FLOAT32_VARIANCE_TOL * float(model.theta1) if float32 else 1e-9
        torch.testing.assert_close(var_c.cpu(), var, rtol=1e-7, atol=var_atol)
    finally:
        model.to("cpu")


@pytest.mark.parametrize("which", ["exact", "sparse"])
def test_bad_inputs_raise(which, exact, sparse):
    model = exact if which == "exact" else sparse
    q = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=F64)
    m = torch.tensor(13.0, dtype=F64)
    with pytest.raises(ValueError):
        model.predict(torch.tensor([0.0, 0.0, 1.0], dtype=F64), m)
    with pytest.raises(ValueError):
        model.predict(torch.tensor([0.0, float("nan"), 0.0, 1.0], dtype=F64), m)
    with pytest.raises(ValueError):
        model.predict(q, torch.tensor(float("inf"), dtype=F64))
    with pytest.raises(ValueError):
        model.predict(q.expand(3, 4), torch.zeros(2, dtype=F64))


def test_training_data_checked():
    q, m, y = _data(20)
    y = y.clone()
    y[3] = float("nan")
    with pytest.raises(ValueError, match="non-finite"):
        ExactGP.from_data(q, m, y, _cfg())
    with pytest.raises(ValueError, match="q \\(N, 4\\)"):
        ExactGP.from_data(q[:, :3], m, y, _cfg())


# ----------------------------------------------------------------------------------------------- exact GP

def test_exact_matches_closed_form(exact, train, test_pts):
    mean_ref, var_ref = _closed_form(*train, *test_pts)
    mean = exact.predict(*test_pts, variance="none")[0]
    var = _variance(exact, *test_pts, "exact")
    torch.testing.assert_close(mean, mean_ref, rtol=0, atol=1e-8)
    torch.testing.assert_close(var, var_ref, rtol=0, atol=1e-8)
    # training points too (small variance, near the data)
    var_tr = _variance(exact, train[0][:10], train[1][:10], "exact")
    torch.testing.assert_close(var_tr, _closed_form(*train, train[0][:10], train[1][:10])[1], rtol=0, atol=1e-8)


def test_kernel_mapping_matches_gpytorch(exact, train, test_pts):
    """θ2 = 2ℓ² exactly, and GPyTorch's own posterior (latent and with likelihood) agrees with ours."""
    import gpytorch

    assert lengthscale_to_theta2(theta2_to_lengthscale(0.25)) == pytest.approx(0.25, rel=1e-15)
    assert theta2_to_lengthscale(0.25) == pytest.approx(math.sqrt(0.125), rel=1e-15)
    torch.testing.assert_close(exact.theta2, torch.full((5,), 0.25, dtype=F64), rtol=1e-14, atol=0)
    q, m, y = train
    x = torch.cat([q, m[:, None]], 1)
    model, lik = gpytorch_exact_model(x, y - y.mean(), 1.0, theta2_to_lengthscale(0.25), 0.01)
    model.eval()
    lik.eval()
    xt = torch.cat([test_pts[0], test_pts[1][:, None]], 1)
    with torch.no_grad(), gpytorch.settings.max_cholesky_size(10**6), gpytorch.settings.fast_pred_var(False):
        latent = model(xt)
        noisy = lik(model(xt))
    mean, var = exact.predict(*test_pts)
    var = _variance(exact, *test_pts, "exact")
    torch.testing.assert_close(latent.mean + y.mean(), mean, rtol=0, atol=1e-7)
    torch.testing.assert_close(latent.variance, var, rtol=0, atol=1e-7)
    torch.testing.assert_close(noisy.variance, var + 0.01, rtol=0, atol=1e-7)


def test_fast_variance_close_to_exact_and_an_upper_bound(train):
    """Documented tolerance: with k = 64 of N = 200 neighbours, fast ≥ exact and within 5% (measured ≲ 1%)."""
    model = ExactGP.from_data(*train, _cfg(fast_variance_neighbors=64))
    q, m, _ = _data(40, seed=2)
    # single points and sigma-point-like clusters (13 points within ~3 degrees) sharing one neighbour set
    err = fast_variance_error(model, q, m)
    assert err["n"] == 40 and err["max_rel"] < 0.05, err
    g = torch.Generator().manual_seed(5)
    qc = (q[:4, None, :] + 0.02 * torch.randn(4, 13, 4, generator=g, dtype=F64))
    mc = m[:4, None].expand(4, 13)
    err_c = fast_variance_error(model, qc, mc)
    assert err_c["max_rel"] < 0.05, err_c
    fast = _variance(model, qc, mc, "fast")
    ex = _variance(model, qc, mc, "exact")
    assert bool((fast >= ex - 1e-12).all())
    # a set wider than cluster_radius does not share neighbours: each point as if predicted alone
    wide = _variance(model, q[:12].reshape(3, 4, 4), m[:12].reshape(3, 4), "fast")
    torch.testing.assert_close(wide.reshape(-1), _variance(model, q[:12], m[:12], "fast"), rtol=0, atol=1e-12)
    # all training points as neighbours: the fast variance is the exact one
    model.neighbors = 200
    torch.testing.assert_close(_variance(model, q, m, "fast"), _variance(model, q, m, "exact"),
                               rtol=0, atol=1e-9)


def test_variance_none_and_exact_choices(train, test_pts):
    ex = ExactGP.from_data(*train, _cfg(variance="none"))  # the config's choice is the filter's, not the model's
    assert ex.predict(*test_pts, variance="none")[1] is None
    torch.testing.assert_close(_variance(ex, *test_pts, "exact"), _closed_form(*train, *test_pts)[1], rtol=0, atol=1e-8)
    ex.drop_cholesky()  # recomputed lazily
    torch.testing.assert_close(_variance(ex, *test_pts, "exact"), _closed_form(*train, *test_pts)[1], rtol=0, atol=1e-8)


@pytest.mark.parametrize("which", ["exact", "sparse"])
def test_variance_is_chosen_per_call_and_leaves_no_state(which, exact, sparse, test_pts):
    """The same model answers each choice as asked, in any order; nothing about the choice is stored."""
    model = exact if which == "exact" else sparse
    fast, ex = _variance(model, *test_pts, "fast"), _variance(model, *test_pts, "exact")
    mean_none, var_none = model.predict(*test_pts, variance="none")
    assert var_none is None
    assert torch.equal(_variance(model, *test_pts, "fast"), fast)  # not changed by the calls in between
    assert torch.equal(model(q=test_pts[0], m_past=test_pts[1])[0], mean_none)
    assert torch.equal(model(q=test_pts[0], m_past=test_pts[1])[1], fast)  # the default choice is "fast"
    if which == "sparse":  # its variance is exact and cheap: "fast" is the same
        assert torch.equal(fast, ex)
    else:  # with 64 of 200 neighbours, the fast variance bounds the exact one from above and differs from it
        assert bool((fast >= ex - 1e-12).all()) and not torch.equal(fast, ex)
    assert not any("variance" in name for name in vars(model) if not name.startswith("_"))
    with pytest.raises(ValueError, match="^variance must be one of none, fast, exact, got 'full'$"):
        model.predict(*test_pts, variance="full")


def test_standardised_inputs(train, test_pts):
    model = ExactGP.from_data(*train, _cfg(standardize_inputs=True))
    x = model.inputs.raw(*train[:2])
    torch.testing.assert_close(model.x_train.mean(0), torch.zeros(5, dtype=F64), rtol=0, atol=1e-12)
    torch.testing.assert_close(model.x_train.std(0), torch.ones(5, dtype=F64), rtol=0, atol=1e-12)
    torch.testing.assert_close(model.inputs.shift, x.mean(0))
    mean, var = model.predict(*test_pts)
    assert bool(torch.isfinite(mean).all()) and bool((var > 0).all())


def test_input_registry():
    with pytest.raises(ValueError, match="unknown input kind"):
        InputMap("nope")
    with pytest.raises(ValueError, match="already registered"):
        from lightcurve_gp.observation.inputs import quaternion_features, register_input_kind

        register_input_kind("quaternion", 5, quaternion_features)
    q = torch.tensor([[0.1, 0.2, 0.3, 0.9]], dtype=F64)
    torch.testing.assert_close(InputMap()(q, torch.tensor([13.0], dtype=F64)),
                               torch.tensor([[0.1, 0.2, 0.3, 0.9, 13.0]], dtype=F64))


def test_marginal_likelihood_fit_increases_mll(train):
    cfg = _cfg(fit_hyperparameters=True, fit_iterations=30, fit_lr=0.05, fit_subset=150, ard=True)
    model = ExactGP.from_data(*train, cfg)
    hist = model.fit_history
    assert len(hist) == 31 and hist[-1] > hist[0] + 1e-3
    assert model.lengthscale.shape == (5,) and not torch.allclose(model.lengthscale, model.lengthscale[0])


# ----------------------------------------------------------------------------------------------- sparse GP

def test_sparse_with_training_inputs_as_inducing_equals_exact(train, test_pts):
    q, m, y = train
    x = torch.cat([q, m[:, None]], 1)
    sparse = SparseGP.from_data(q, m, y, _cfg(kind="sparse"), inducing_points=x, jitter=1e-10)
    mean_ref, var_ref = _closed_form(*train, *test_pts)
    mean, var = sparse.predict(*test_pts)
    torch.testing.assert_close(mean, mean_ref, rtol=0, atol=1e-6)
    torch.testing.assert_close(var, var_ref, rtol=0, atol=1e-6)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_exp_neg_sqdist_against_cdist(dtype):
    g = torch.Generator().manual_seed(5)
    ref = torch.randn(300, 5, generator=g, dtype=F64)
    xs = torch.cat([ref[:4] + 0.01, 3.0 * torch.randn(3, 5, generator=g, dtype=F64)])  # near and far points
    expected = torch.exp(-torch.cdist(xs, ref) ** 2)
    got = exp_neg_sqdist(xs.to(dtype), cross_kernel_cache(ref.to(dtype)))
    assert got.dtype == dtype and got.shape == (7, 300)
    if dtype == torch.float64:
        torch.testing.assert_close(got, expected, rtol=1e-10, atol=1e-14)
    else:  # exponents clamped to [-EXP_CLAMP, 0]
        torch.testing.assert_close(got.double(), expected.clamp_min(math.exp(-EXP_CLAMP)), rtol=1e-4, atol=1e-6)
        assert float(got.min()) >= math.exp(-EXP_CLAMP) * (1 - 1e-6) and float(got.max()) <= 1.0


def _sgpr_variance_float64(model: SparseGP, q, m_past):
    """``θ1 − k*uᵀ P k*u`` in float64 from the model's saved ``z``, ``p`` (the form before the float32 factor)."""
    from lightcurve_gp.observation.kernels import kernel_matrix, scaled

    xs = scaled(model.inputs(q, m_past), model.lengthscale)
    ks = kernel_matrix(xs, scaled(model.z, model.lengthscale), model.outputscale)
    return model.outputscale - (ks @ model.p * ks).sum(-1)


def test_sparse_float32_variance_agrees_with_the_float64_form(sparse, train, test_pts):
    assert sparse.p_factor is not None and sparse.p_factor.dtype == torch.float32
    q, m, _ = train
    for pts in (test_pts, (q[:40], m[:40] + 0.01)):  # far from and next to the training inputs
        var = sparse.predict(*pts)[1]
        ref = _sgpr_variance_float64(sparse, *pts).clamp_min(0.0)
        assert float((var - ref).abs().max()) <= FLOAT32_VARIANCE_TOL * sparse.theta1
        assert not torch.equal(var, ref)  # the float32 path did run


def test_variance_factor_refuses_what_float32_cannot_hold():
    g = torch.Generator().manual_seed(3)
    basis = torch.linalg.qr(torch.randn(40, 40, generator=g, dtype=F64))[0]
    e = torch.rand(8, 40, generator=g, dtype=F64)
    well = basis @ torch.diag(torch.linspace(0.1, 10.0, 40, dtype=F64)) @ basis.T
    factor = variance_factor(well, e, 1.0)
    torch.testing.assert_close(factor.double() @ factor.double().T, well, rtol=0, atol=1e-5)
    # a form of size ~1e8 whose float32 rounding exceeds the tolerance, and an indefinite matrix
    assert variance_factor(well * 1e7, e, 1.0) is None
    indefinite = basis @ torch.diag(torch.linspace(-1.0, 10.0, 40, dtype=F64)) @ basis.T
    assert variance_factor(indefinite, e, 1.0) is None


def test_sparse_error_decreases_with_m(train, test_pts):
    mean_ref, var_ref = _closed_form(*train, *test_pts)
    errors = []
    for m_ind in (10, 50, 150):
        sp = SparseGP.from_data(*train, _cfg(kind="sparse", num_inducing=m_ind))
        mean, var = sp.predict(*test_pts)
        errors.append(float((mean - mean_ref).abs().max() + (var - var_ref).abs().max()))
    assert errors[0] > errors[1] > errors[2], errors


def test_sparse_optimisation_increases_bound(train):
    cfg = _cfg(kind="sparse", num_inducing=15, optimize_inducing=True, sparse_iterations=20, fit_lr=0.02)
    sp = SparseGP.from_data(*train, cfg, init="random")
    assert len(sp.fit_history) == 21 and sp.fit_history[-1] > sp.fit_history[0]


def test_sparse_hyperparameter_fit_raises_the_bound_and_predicts_better(train):
    """Fitting (θ1, ℓ, σ) on the collapsed bound beats the paper's fixed values on held-out data of the same
    function (θ2 = 0.25 is far too short a lengthscale for these inputs)."""
    q_new, m_new, y_new = _data(300, seed=1)
    rmse = {}
    for fit in (False, True):
        cfg = _cfg(kind="sparse", num_inducing=50, fit_hyperparameters=fit, sparse_iterations=40, fit_lr=0.05)
        sp = SparseGP.from_data(*train, cfg)
        rmse[fit] = float((sp.predict(q_new, m_new)[0] - y_new).pow(2).mean().sqrt())
        if fit:
            assert len(sp.fit_history) == 41 and sp.fit_history[-1] > sp.fit_history[0]
            assert float(sp.lengthscale[0]) > 1.5 * (0.25 / 2) ** 0.5  # well beyond the start ℓ = sqrt(θ2 / 2)
    assert rmse[True] < 0.5 * rmse[False], rmse


def test_kmeans_is_seeded_and_reduces_inertia():
    x = _data(200)[0]
    c1, c2 = kmeans(x, 8, seed=1), kmeans(x, 8, seed=1)
    torch.testing.assert_close(c1, c2)
    inertia = lambda c: float(torch.cdist(x, c).min(1).values.pow(2).sum())  # noqa: E731
    assert inertia(c1) < inertia(kmeans(x, 8, iterations=0, seed=1))


def test_kmeans_centres_are_distinct_when_the_data_repeat_points():
    x = _data(60)[0].repeat(5, 1)  # every row five times, like the paper grid's repeated identity attitude
    for seed in range(5):
        c = kmeans(x, 40, seed=seed)
        assert torch.unique(c, dim=0).shape[0] == 40
    torch.testing.assert_close(kmeans(x, 100), torch.unique(x, dim=0))  # fewer distinct rows than centres


# ----------------------------------------------------------------------------------------------- model files

@pytest.mark.parametrize("which", ["exact", "sparse"])
def test_save_load_roundtrip(which, exact, sparse, test_pts, tmp_path):
    model = exact if which == "exact" else sparse
    path = save_model(model, tmp_path / f"{which}.pt", extra={"note": "test", "n": 3})
    loaded = load_model(path)
    assert type(loaded) is type(model) and loaded.extra == {"note": "test", "n": 3}
    assert loaded.config == model.config
    m1, v1 = model.predict(*test_pts)
    m2, v2 = loaded.predict(*test_pts)
    assert torch.equal(m1, m2) and torch.equal(v1, v2)
    if which == "exact":  # lazily recomputed Cholesky gives the same exact variance
        torch.testing.assert_close(_variance(loaded, *test_pts, "exact"),
                                   _variance(model, *test_pts, "exact"), rtol=0, atol=1e-12)


def test_model_file_errors(exact, tmp_path):
    with pytest.raises(ModelFileError, match="no such model file"):
        load_model(tmp_path / "missing.pt")
    path = save_model(exact, tmp_path / "m.pt")
    raw = path.read_bytes()
    (tmp_path / "trunc.pt").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ModelFileError, match="not a readable model file"):
        load_model(tmp_path / "trunc.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a model at all")
    with pytest.raises(ModelFileError):
        load_model(tmp_path / "junk.pt")
    payload = torch.load(path, weights_only=True)
    torch.save(dict(payload, format_version=FORMAT_VERSION + 1), tmp_path / "v2.pt")
    with pytest.raises(ModelFileError, match="format version"):
        load_model(tmp_path / "v2.pt")
    torch.save({"something": "else"}, tmp_path / "foreign.pt")
    with pytest.raises(ModelFileError, match="not a lightcurve-gp-model"):
        load_model(tmp_path / "foreign.pt")
    state = dict(payload["state"], alpha=payload["state"]["alpha"][:-1])
    torch.save(dict(payload, state=state), tmp_path / "bad_shape.pt")
    with pytest.raises(ModelFileError, match="inconsistent"):
        load_model(tmp_path / "bad_shape.pt")
    assert issubclass(ModelFileError, ValueError)


def test_config_dict_is_stored_and_build_model_dispatches(exact, train):
    assert exact.config == config_to_dict(_cfg()) and "sparse" not in exact.config
    assert isinstance(build_model(*train, _cfg(kind="sparse", num_inducing=10)), SparseGP)
    assert isinstance(build_model(*train, _cfg(variance="none")), ExactGP)


def test_shared_lengthscale_fit_runs_from_the_config_start():
    """fit_hyperparameters with ard = false starts from the paper's θ2 and fits one shared lengthscale."""
    cfg = load_config(BOXWING,
                      ["model.fit_hyperparameters=true", "model.ard=false", "model.exact.fit_iterations=5"]).model
    gen = torch.Generator().manual_seed(0)
    q = torch.nn.functional.normalize(torch.randn(60, 4, generator=gen, dtype=torch.float64), dim=-1)
    m_past = 12 + torch.rand(60, generator=gen, dtype=torch.float64)
    y = m_past + 0.3 * q[:, 0]
    model = ExactGP.from_data(q, m_past, y, cfg)
    ls = model.lengthscale
    assert torch.allclose(ls, ls[:1].expand_as(ls))  # one shared value
    assert model.fit_history[-1] > model.fit_history[0]


@pytest.mark.parametrize("which", ["exact", "sparse"])
def test_files_written_with_a_stored_variance_choice_still_load(which, exact, sparse, test_pts, tmp_path):
    """Model files of the format before the variance became a per-call choice carry a ``variance_mode`` (exact)
    or ``with_variance`` (sparse) and a flat model config: they load and predict the same."""
    model = exact if which == "exact" else sparse
    payload = torch.load(save_model(model, tmp_path / "new.pt"), weights_only=True)
    old_key = {"exact": ("variance_mode", "none"), "sparse": ("with_variance", False)}[which]
    flat_config = {"kind": which, "inputs": "quaternion", "target": "magnitude", **PAPER, "variance": "none",
                   "num_inducing": 50, "sparse_iterations": 200}
    torch.save(dict(payload, state=dict(payload["state"], **dict([old_key])), config=flat_config), tmp_path / "old.pt")
    loaded = load_model(tmp_path / "old.pt")
    assert loaded.config["target"] == "magnitude"
    for choice in ("none", "fast", "exact"):
        m1, v1 = model.predict(*test_pts, variance=choice)
        m2, v2 = loaded.predict(*test_pts, variance=choice)
        assert torch.equal(m1, m2) and (v1 is None if choice == "none" else torch.allclose(v1, v2, rtol=0, atol=1e-12))


@pytest.mark.parametrize("override, message", [
    ("model.sparse.num_inducing=64",
     "model.sparse: settings of the sparse GP (num_inducing) do not apply to model.kind exact"),
    ("model.num_inducing=64",
     "model.num_inducing: a setting of the sparse GP only; give it as model.sparse.num_inducing"),
    ("model.sparse_iterations=5",
     "model.sparse_iterations: a setting of the sparse GP only; give it as model.sparse.iterations"),
    ("model.fit_subset=100", "model.fit_subset: a setting of the exact GP only; give it as model.exact.fit_subset"),
    ("model.exact.num_inducing=64",
     "model.exact.num_inducing: unknown key (known keys: fit_iterations, fit_subset, fast_variance_neighbors)"),
])
def test_a_setting_given_to_the_wrong_model_kind_is_a_config_error(override, message):
    with pytest.raises(ConfigError) as err:
        load_config(BOXWING, [override])
    assert str(err.value) == message


def test_kind_sections_apply_to_their_kind():
    """Switching kind needs nothing else; a section given with its kind is read; the exact section with the
    sparse kind is refused."""
    sparse = load_config(BOXWING, ["model.kind=sparse", "model.sparse.num_inducing=64", "model.sparse.iterations=3"])
    assert (sparse.model.sparse.num_inducing, sparse.model.sparse.iterations) == (64, 3)
    assert sparse.model.exact == ExactModelConfig()  # defaults, unused by this kind
    exact = load_config(BOXWING, ["model.exact.fast_variance_neighbors=32"])
    assert exact.model.exact.fast_variance_neighbors == 32
    with pytest.raises(ConfigError) as err:
        load_config(BOXWING, ["model.kind=sparse", "model.exact.fit_subset=100"])
    assert str(err.value) == "model.exact: settings of the exact GP (fit_subset) do not apply to model.kind sparse"


@pytest.mark.parametrize("kind", ["exact", "sparse"])
def test_a_config_written_as_a_dict_reads_back(kind):
    """config_to_dict keeps only the settings of the model's kind, so that config_from_dict accepts it again."""
    from lightcurve_gp.config.load import config_from_dict

    cfg = load_config(BOXWING, [f"model.kind={kind}"])
    raw = config_to_dict(cfg)
    assert [s for s in ("exact", "sparse") if s in raw["model"]] == [kind]
    assert config_from_dict(raw) == cfg
    assert kind in config_to_dict(cfg.model) and ({"exact", "sparse"} - {kind}).isdisjoint(config_to_dict(cfg.model))
