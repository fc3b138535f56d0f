"""The compiled filter step (``filter.compile: true``): the same estimates as the eager step on short runs of the
paper's filter (the renderer traced into the graph, the exact GP's mean fused, a GP with a variance called eagerly
between two compiled halves), the eager redo of a step whose square root falls back, the exported step compiled
again when the model or the shapes change (and only then), the models it fuses, the same estimates without torch's
private API (its public fallbacks), and the config key."""

import dataclasses
import math

import pytest
import torch

import lightcurve_gp.filters.compiled as usque_compiled
from lightcurve_gp.config.load import ConfigError, ExactModelConfig, ModelConfig, config_to_dict, load_config
from lightcurve_gp.filters.compiled import Capabilities, capabilities, fuses
from lightcurve_gp.filters.unscented import UNROLLED_CHOLESKY_MAX, SqrtFallbackWarning, cholesky_unrolled
from lightcurve_gp.filters.usque import UsqueParams, initial_covariance, run_usque
from lightcurve_gp.observation import ExactGP, SparseGP
from lightcurve_gp.observation.along_pass import AlongPass
from lightcurve_gp.observation.base import ObservationModule
from lightcurve_gp.observation.kernels import blocked_kernel_sum, cross_kernel_cache, exp_neg_sqdist, weighted_blocks
from lightcurve_gp.observation.parametric import Parametric
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_scenario
from lightcurve_gp.training.sets import generate_training_set
from tests.helpers import ToyModel, scenario


class _UncountedToy(ToyModel):
    """:class:`ToyModel` without its call counter (a model whose Python state changes when called is refused)."""

    def _predict(self, q, m_past, variance):
        out = super()._predict(q, m_past, variance)
        self.calls = 0
        return out

CONFIG = "configs/boxwing.yaml"
STEPS = 12
# the fused loops sum in another order than the eager matrix products: the estimates agree to rounding, well inside
TOL = 1e-10


@pytest.fixture(scope="module")
def paper_case():
    """The paper's scenario on a 42-axis training grid: config, scene, truth of 2 noise seeds, the exact GP."""
    cfg = load_config(CONFIG, overrides=["data.icosphere_subdivisions=1"])
    scene = Scene.from_config(cfg)
    truth = simulate_scenario(cfg, seeds=range(2), scene=scene)
    data = generate_training_set(cfg)
    return cfg, scene, truth, ExactGP.from_data(data.q, data.m_past, data.y, cfg.model)


def _both(model, params, truth, *, B=2, P0=None):
    """The eager and the compiled run of ``B`` filters over :data:`STEPS` steps."""
    obs = truth.observations[:B, :STEPS + 1]
    P0 = initial_covariance(10.0, dtype=torch.float64) if P0 is None else P0
    runs = [run_usque(model=model, q_est0=truth.q_est0[:1].expand(B, 4), P0=P0, observations=obs, m_past0=obs[:, 0],
                      increments=truth.increments[0, :STEPS], params=dataclasses.replace(params, compile=c))
            for c in (False, True)]
    return runs


def _assert_same(eager, compiled):
    for name in ("q_est", "P", "y_pred", "y_var", "m_past"):
        a, b = getattr(eager, name), getattr(compiled, name)
        assert torch.allclose(a, b, rtol=0.0, atol=TOL, equal_nan=True), (name, float((a - b).abs().nan_to_num().max()))
    assert torch.equal(eager.updated, compiled.updated)
    assert torch.equal(eager.fallbacks, compiled.fallbacks)


def _counting_exports(monkeypatch) -> list:
    """Calls of :func:`usque_compiled._export` (one per exported and compiled step), counted in the list returned."""
    exports = []
    export = usque_compiled._export
    monkeypatch.setattr(usque_compiled, "_export", lambda *a, **k: exports.append(1) or export(*a, **k))
    return exports


@pytest.mark.slow
@pytest.mark.parametrize("variance", ["none", "fast"])
def test_compiled_gpukf_gives_the_eager_estimates(paper_case, variance):
    """Mean only: the GP's mean fused into the graph; fast variance: the GP called eagerly between the halves."""
    cfg, _, truth, gp = paper_case
    params = dataclasses.replace(UsqueParams.from_config(cfg), variance=variance)
    assert fuses(gp, variance) == (variance == "none")
    eager, compiled = _both(gp, params, truth)
    _assert_same(eager, compiled)
    assert bool(compiled.updated[:, 1:].all())


@pytest.mark.slow
def test_compiled_ukf_with_the_renderer_gives_the_eager_estimates(paper_case):
    cfg, scene, truth, _ = paper_case
    eager, compiled = _both(Parametric(scene, cfg.filter.rho_assumed), UsqueParams.from_config(cfg), truth)
    _assert_same(eager, compiled)


@pytest.mark.slow
def test_a_step_whose_square_root_falls_back_is_done_again_eagerly():
    """An indefinite ``P0`` for one of two filters: the compiled step flags it, the eager step redoes it (the
    eigendecomposition fallback, counted and warned about as without compiling)."""
    _, y, q_est0, increments = scenario(B=2, T=STEPS)
    P0 = initial_covariance(10.0, dtype=torch.float64).repeat(2, 1, 1)
    P0[1, 0, 0] = -P0[1, 0, 0]
    params = UsqueParams(Q=1e-6, R=1e-4, variance="none")
    runs = []
    for compile_ in (False, True):
        with pytest.warns(SqrtFallbackWarning, match="1 of 2 filters"):
            runs.append(run_usque(model=_UncountedToy(), q_est0=q_est0, P0=P0, observations=y, m_past0=y[:, 0],
                                  increments=increments, params=dataclasses.replace(params, compile=compile_)))
    _assert_same(*runs)
    assert runs[1].fallbacks.tolist() == [0, 1]


class _ShiftedToy(_UncountedToy):
    """:class:`_UncountedToy` plus a plain tensor attribute (not a buffer: a constant of the exported graph)."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.shift = torch.zeros((), dtype=torch.float64)

    def _predict(self, q, m_past, variance):
        mean, var = super()._predict(q, m_past, variance)
        return mean + self.shift, var


@pytest.mark.slow
def test_the_exported_step_is_compiled_again_when_the_model_or_the_shapes_change(monkeypatch):
    """A Python attribute (a constant of the graph), a plain tensor changed in place (its version counter) and the
    batch size each compile a new step whose estimates are the eager ones; a buffer changed in place (an input of
    the graph) and a run like the one before reuse the compiled step."""
    exports = _counting_exports(monkeypatch)
    _, y, q_est0, increments = scenario(B=3, T=STEPS)
    model = _ShiftedToy(m_past_gain=0.1)
    params = UsqueParams(Q=1e-6, R=1e-4, variance="none")
    P0 = initial_covariance(10.0, dtype=torch.float64)

    def runs(B=2):
        return [run_usque(model=model, q_est0=q_est0[:B], P0=P0, observations=y[:B], m_past0=y[:B, 0],
                          increments=increments[:B], params=dataclasses.replace(params, compile=c))
                for c in (False, True)]

    changes = [("first run", lambda: None, 1), ("same run", lambda: None, 0),
               ("python attribute", lambda: setattr(model, "m_past_gain", 0.3), 1),
               ("plain tensor in place", lambda: model.shift.add_(0.2), 1),
               ("buffer in place", lambda: model.a.mul_(1.1), 0)]
    before = None
    for what, change, compiles in changes:
        change()
        count = len(exports)
        eager, compiled = runs()
        _assert_same(eager, compiled)
        assert len(exports) - count == compiles, what
        if before is not None and compiles + (what == "buffer in place"):
            assert not torch.allclose(before.y_pred[:, 1:], compiled.y_pred[:, 1:]), what
        before = compiled
    count = len(exports)
    _assert_same(*runs(B=3))
    assert len(exports) == count + 1


@pytest.mark.slow
def test_a_model_that_changes_its_python_state_when_called_runs_in_two_halves(monkeypatch):
    """Its counter moves while the step is traced: no fused graph is kept (it would freeze the counter), the model
    is called eagerly once per step between the compiled halves, and the estimates are the eager ones."""
    _, y, q_est0, increments = scenario(B=2, T=STEPS)
    P0 = initial_covariance(10.0, dtype=torch.float64)
    params = UsqueParams(Q=1e-6, R=1e-4, variance="none")
    models, runs = [ToyModel(), ToyModel()], []
    for model, compile_ in zip(models, (False, True)):
        runs.append(run_usque(model=model, q_est0=q_est0, P0=P0, observations=y, m_past0=y[:, 0],
                              increments=increments, params=dataclasses.replace(params, compile=compile_)))
    _assert_same(*runs)
    assert models[1].calls == models[0].calls == STEPS
    assert [e.fn for e in usque_compiled._EXPORTED[models[1]].values()] == [None]


class _Holding(ObservationModule):
    """A model that only holds another (a wrapper, like the geometry-bound GP)."""

    def __init__(self, inner):
        super().__init__()
        self.inner = inner

    def _predict(self, q, m_past, variance):
        return self.inner(q=q, m_past=m_past, variance=variance)


def test_the_compiled_step_fuses_the_models_it_recognises():
    """Traced into one graph: the renderer, the exact GP's mean, a library-style module and a wrapper of those;
    called eagerly: a GP asked for a variance, the sparse GP, a model along a pass (a per-call counter), a wrapper
    of any of those, and a callable that is not a module."""
    g = torch.Generator().manual_seed(0)
    q, y = torch.randn(30, 4, generator=g, dtype=torch.float64), torch.randn(30, generator=g, dtype=torch.float64)
    cfg = ModelConfig(kind="exact", theta1=1.0, theta2=0.25, noise_std=0.1, variance="fast",
                      fit_hyperparameters=False, exact=ExactModelConfig(fast_variance_neighbors=8))
    exact = ExactGP.from_data(q, torch.zeros(30, dtype=torch.float64), y, cfg)
    sparse = SparseGP.from_data(q, torch.zeros(30, dtype=torch.float64), y, dataclasses.replace(
        cfg, kind="sparse", sparse=dataclasses.replace(cfg.sparse, num_inducing=8, iterations=0)))
    renderer = Parametric(Scene.from_config(load_config(CONFIG)), 0.5)
    table = {"exact": (exact, "none", True), "exact fast": (exact, "fast", False), "sparse": (sparse, "none", False),
             "renderer": (renderer, "fast", True), "toy": (_UncountedToy(), "exact", True),
             "wrapped exact": (_Holding(exact), "none", True), "wrapped exact fast": (_Holding(exact), "fast", False),
             "wrapped sparse": (_Holding(sparse), "none", False), "along a pass": (AlongPass(renderer, None), "none",
                                                                                   False),
             "plain callable": (lambda **kw: renderer(**kw), "none", False)}
    assert {k: fuses(m, v) for k, (m, v, _) in table.items()} == {k: want for k, (_, _, want) in table.items()}


def test_this_torch_has_the_private_entry_points_the_fast_path_uses():
    """The probe finds them here (else the public fallbacks below would be all that runs)."""
    assert capabilities() == Capabilities(inductor_compile=torch._inductor.compile, version_counter=True)


@pytest.mark.slow
def test_without_torchs_private_api_the_compiled_step_gives_the_eager_estimates(monkeypatch):
    """With neither ``torch._inductor.compile`` nor ``Tensor._version``: a model without plain tensors is exported
    and compiled by ``torch.compile``; one that holds a plain tensor (whose in-place changes could not be seen) is
    not exported but runs in two halves; both give the eager estimates."""
    monkeypatch.delattr(torch._inductor, "compile")  # the fallback must not need it
    monkeypatch.setattr(usque_compiled, "capabilities", lambda: Capabilities())
    exports = _counting_exports(monkeypatch)
    _, y, q_est0, increments = scenario(B=2, T=STEPS)
    P0 = initial_covariance(10.0, dtype=torch.float64)
    params = UsqueParams(Q=1e-6, R=1e-4, variance="none")
    for model, compiles in ((_UncountedToy(), 1), (_ShiftedToy(), 0)):
        count = len(exports)
        _assert_same(*[run_usque(model=model, q_est0=q_est0, P0=P0, observations=y, m_past0=y[:, 0],
                                 increments=increments, params=dataclasses.replace(params, compile=c))
                       for c in (False, True)])
        assert len(exports) - count == compiles, type(model).__name__


def test_blocked_kernel_sum_is_the_kernel_row_times_the_weights():
    g = torch.Generator().manual_seed(0)
    refs, w, xs = (torch.randn(1000, 5, generator=g, dtype=torch.float64), torch.randn(1000, generator=g,
                   dtype=torch.float64), 0.3 * torch.randn(7, 5, generator=g, dtype=torch.float64))
    blocks, w_blocks = weighted_blocks(refs, w, block=256)
    assert blocks.shape == (4, 5, 256) and w_blocks.shape == (4, 1, 256)
    want = exp_neg_sqdist(xs, cross_kernel_cache(refs)) @ w
    assert torch.allclose(blocked_kernel_sum(xs, blocks, w_blocks), want, rtol=1e-12, atol=1e-12)


def test_the_unrolled_cholesky_is_lapacks_and_fails_where_lapack_fails():
    """The factor a compiled step uses for small matrices: LAPACK's to rounding where it succeeds, flagged exactly
    where ``cholesky_ex`` reports a failure (a negative and a NaN pivot among positive definite matrices)."""
    g = torch.Generator().manual_seed(1)
    for n in range(1, UNROLLED_CHOLESKY_MAX + 1):
        m = torch.randn(5, n, n, generator=g, dtype=torch.float64)
        a = m @ m.mT + 0.1 * torch.eye(n, dtype=torch.float64)
        a[1, -1, -1] = -1.0
        a[3, 0, 0] = math.nan
        L, failed = cholesky_unrolled(a)
        want, info = torch.linalg.cholesky_ex(a)
        assert failed.tolist() == (info != 0).tolist() == [False, True, False, True, False], n
        assert torch.allclose(L[~failed], want[~failed], rtol=0.0, atol=1e-12), n


def test_the_compile_key_is_checked_and_left_out_of_the_keys_when_off():
    with pytest.raises(ConfigError, match=r"^filter\.compile: expected true or false, got 'sometimes'$"):
        load_config(CONFIG, overrides=["filter.compile=sometimes"])
    off, on = load_config(CONFIG), load_config(CONFIG, overrides=["filter.compile=true"])
    assert "compile" not in config_to_dict(off)["filter"] and config_to_dict(on)["filter"]["compile"] is True
    assert (UsqueParams.from_config(off).compile, UsqueParams.from_config(on).compile) == (False, True)
