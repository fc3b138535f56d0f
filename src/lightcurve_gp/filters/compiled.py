"""The ω-known USQUE step compiled into fused graphs (``filter.compile: true``, :attr:`UsqueParams.compile`).

One filter's step (B = 1) on the CPU is a few hundred small tensor operations — the sigma points, their propagation,
the model's prediction, the gain and the reset (:func:`lightcurve_gp.filters.step.usque_step`) — and eager torch
spends microseconds of dispatch on each. :func:`compiled_stepper` compiles the very same function with inductor
(fixed shapes, its C++ wrapper): the step becomes a few generated C++ loops plus the library calls that stay calls
(small matrix products; the sigma points' Cholesky factor is written out elementwise,
:func:`~lightcurve_gp.filters.unscented.cholesky_unrolled`, and fused).

Two forms. When this module recognises the model as one whose prediction traces (:func:`fuses`: the renderers, the
exact GP's mean, any other :class:`~lightcurve_gp.observation.base.ObservationModule` that holds no GP with a
variance or the sparse GP, and no :class:`~lightcurve_gp.observation.along_pass.AlongPass`), the whole step is
exported once (``torch.export``, non-strict: the same Python runs, ``torch.compiler.is_compiling()`` is true) to one
graph of flat tensors and compiled; each step then calls that graph directly, with no TorchDynamo frame or guard
check in between. What dynamo's guards did is done once per run instead (:class:`_ExportedStep`): the compiled graph
is looked up by the model object, a fingerprint of the model's Python state (its plain attributes and the identity
and version counter of every tensor it holds outside its buffers, such as the renderer's scene: these are constants
of the graph) and the shapes, strides, dtypes and devices of every input (its buffers and parameters are inputs,
read at the start of each run), and the run's Python constants; any change exports and compiles again. A model
whose Python state moves when it is called (a counter) would be frozen by one traced graph: it is seen during the
trace and run in the other form. Otherwise (a GP asked for a variance, the sparse GP, models that are not modules)
the model is called eagerly between two halves compiled by ``torch.compile`` (TorchDynamo, with its guards).

Private torch API, behind capability checks (:func:`capabilities`), each with a public fallback that gives the same
estimates: ``torch._inductor.compile`` calls the exported graph without TorchDynamo (else ``torch.compile`` of the
exported graph module, a guard check per call); ``Tensor._version`` tells an in-place change of a graph constant
(else a model that holds tensors outside its buffers is not fused but runs in the two-halves form).

What cannot be inside one graph is a host synchronisation: the square root's fallback test, the model's finiteness
check and the renderer's zero-flux test read values back to Python. Under compilation those read-backs are left out
(``torch.compiler.is_compiling()`` in :func:`~lightcurve_gp.filters.unscented.sqrt_psd`,
:func:`~lightcurve_gp.observation.base.check_inputs` and :meth:`~lightcurve_gp.photometry.render.Scene.magnitude`)
and the compiled step returns one flag instead: any square root that fell back, or a posterior that is not finite.
A step so flagged is done again by the eager :func:`~lightcurve_gp.filters.step.usque_step`, which applies the
fallback, raises or warns exactly as the uncompiled filter does. The estimates of both paths therefore agree to
rounding (the fused loops sum in another order). The exact GP's mean is the one model-side change: inside the
graph it is written elementwise over blocks of training points
(:func:`~lightcurve_gp.observation.kernels.blocked_kernel_sum`).

Costs: the first run of each new shape (``B``, the state layout, the model; with per-filter increments
``(B, T, 4)`` also each run length ``T``) compiles — seconds, once per process, less when inductor's on-disk cache
(``TORCHINDUCTOR_CACHE_DIR``) already holds the graph; every run then pays the model's fingerprint (microseconds).
``benchmarks/bench_compile.py`` measures compile time, step times and the break-even run length: on a 2-core CPU
a 5–6× faster step (B = 1) for 7–9 s of CPU compiling with a warm cache, 27 s cold, so compiling pays from ~2000–6000
steps on, ten times the paper's 600-step run; hence opt-in.
"""

from __future__ import annotations

import dataclasses
import functools
import weakref
from typing import Any, Callable

import torch
from torch import Tensor

from lightcurve_gp.filters.state import FilterState, StepRecord
from lightcurve_gp.filters.step import usque_prior, usque_step
from lightcurve_gp.filters.update import Prior, RunConstants, SigmaInputs, sigma_inputs, update_with_predictions
from lightcurve_gp.observation.along_pass import AlongPass
from lightcurve_gp.observation.base import ObservationModule, Variance
from lightcurve_gp.observation.exact_gp import ExactGP
from lightcurve_gp.observation.gp_base import CachedGP

__all__ = ["Capabilities", "capabilities", "compiled_stepper", "fuses"]

#: the run's tensors, the state's fields and the step's inputs, in the order the exported graph takes them
_RUN_TENSORS = ("wm", "wc", "Q", "R")
_STEP_INPUTS = ("L_k", "G_k", "y_k", "observed_k")
#: what every nn.Module carries (its buffers and parameters are inputs of the exported graph, not constants)
_MODULE_INTERNALS = frozenset(vars(torch.nn.Module()))
#: compiled whole steps per model object (dropped with the model), then by the rest of the key (_ExportedStep)
_EXPORTED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
#: inductor's options for every graph: the graph's calls (its loops, the library calls that stay) are made from
#: generated C++ rather than Python (the UKF step's CPU time 238 -> 126 µs at load 4-6; longer compiles)
_INDUCTOR_OPTIONS = {"cpp_wrapper": True}


@dataclasses.dataclass(frozen=True)
class Capabilities:
    """The private torch entry points the exported step uses, where this torch has them; each has a public fallback.

    Attributes:
        inductor_compile: ``torch._inductor.compile``: an exported graph compiled and then called without TorchDynamo
            (no frame evaluation, no guard check per call); ``None``: ``torch.compile`` of the exported graph module.
        version_counter: whether ``Tensor._version`` is readable: a tensor a model holds outside its buffers (a
            constant of the graph, e.g. the renderer's scene) changed in place compiles the step again; ``False``:
            such a model is not fused, its prediction runs eagerly between the two compiled halves.
    """

    inductor_compile: Callable[..., Any] | None = None
    version_counter: bool = False


@functools.cache
def capabilities() -> Capabilities:
    """What this torch offers of :class:`Capabilities` (probed once per process)."""
    inductor = getattr(torch, "_inductor", None)  # torch imports the submodule on first access
    compile_fn = getattr(inductor, "compile", None)
    return Capabilities(inductor_compile=compile_fn if callable(compile_fn) else None,
                        version_counter=isinstance(getattr(torch.empty(0), "_version", None), int))


def fuses(model: Any, variance: Variance) -> bool:
    """Whether the compiled step traces ``model``'s prediction with ``variance`` into its one graph (it must read
    nothing back to Python and keep no per-call Python state), else calls it eagerly between two compiled halves.

    An :class:`~lightcurve_gp.observation.base.ObservationModule` fuses when it and every model it holds do: not an
    :class:`~lightcurve_gp.observation.along_pass.AlongPass` (a per-call sample counter), not a GP asked for a
    variance (it reads values back) and not the sparse GP: kernel rows are ``exp``-bound and the eager ``exp``
    (MKL's on CPU) ran ~2.5× faster than the loop a compiled graph generates; the exact GP's mean alone fuses (its
    whole step was faster all the same)."""
    if not isinstance(model, ObservationModule):
        return False
    return all(_fuses_alone(m, variance) for m in model.modules() if isinstance(m, ObservationModule))


def _fuses_alone(model: ObservationModule, variance: Variance) -> bool:
    if isinstance(model, AlongPass):
        return False
    if isinstance(model, CachedGP):
        return isinstance(model, ExactGP) and variance == "none"
    return True


def _redo(new: FilterState, record: StepRecord) -> Tensor:
    """``()``: whether any filter's square root fell back or its posterior ``q̂``, ``P`` is not finite."""
    finite = torch.isfinite(new.q_hat).all() & torch.isfinite(new.P).all()
    return record.fallback.any() | ~finite


def _whole_step(run: RunConstants, state: FilterState, *, L_k: Tensor, G_k: Tensor, y_k: Tensor,
                observed_k: Tensor) -> tuple[FilterState, StepRecord, Tensor]:
    """:func:`lightcurve_gp.filters.step.usque_step`, the model's prediction included, and :func:`_redo`."""
    new, record = usque_step(run, state, L_k=L_k, G_k=G_k, y_k=y_k, observed_k=observed_k)
    return new, record, _redo(new, record)


def _prior_half(run: RunConstants, state: FilterState, *, L_k: Tensor, G_k: Tensor) -> tuple[Prior, SigmaInputs]:
    """Steps 1–5 and the sigma attitudes the model is asked about."""
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
    # function (many shapes or models), runs the rest eagerly instead of failing
    return torch.compile(fn, dynamic=False, options=_INDUCTOR_OPTIONS)


def _halves_step(run: RunConstants, state: FilterState, *, L_k: Tensor, G_k: Tensor, y_k: Tensor,
                 observed_k: Tensor) -> tuple[FilterState, StepRecord]:
    """The step as two ``torch.compile`` graphs around the model's eager call; a flagged step is done again."""
    step = {"L_k": L_k, "G_k": G_k, "y_k": y_k, "observed_k": observed_k}
    prior, inputs = _compiled(_prior_half)(run, state, L_k=L_k, G_k=G_k)
    if bool(prior.failed.any()):
        return usque_step(run, state, **step)
    y_sig, var_sig = run.model(q=inputs.q, m_past=inputs.m_past, variance=run.variance, **inputs.theta)
    new, record, redo = _compiled(_update_half)(run, state, prior, inputs.R_qm, y_sig, var_sig, y_k=y_k,
                                                observed_k=observed_k)
    return usque_step(run, state, **step) if bool(redo) else (new, record)


def compiled_stepper() -> Callable[..., tuple[FilterState, StepRecord]]:
    """A step function for one run, called like :func:`lightcurve_gp.filters.step.usque_step` (same arguments and
    result): its first call picks the form from that call's arguments — the exported whole step when the model
    :func:`fuses` (:class:`_ExportedStep`, looked up or compiled), else the two compiled halves around the model's
    eager call — and every call runs it; a step whose square root fell back or whose posterior is not finite is
    done again eagerly (module docstring)."""
    chosen: Callable[..., tuple[FilterState, StepRecord]] | None = None

    def step(run: RunConstants, state: FilterState, **inputs: Tensor) -> tuple[FilterState, StepRecord]:
        nonlocal chosen
        if chosen is None:
            exported = _ExportedStep.for_run(run, state, inputs) if fuses(run.model, run.variance) else None
            chosen = exported or _halves_step
        return chosen(run, state, **inputs)

    return step


class _FlatStep(torch.nn.Module):
    """:func:`_whole_step` of flat tensors — the run's :data:`_RUN_TENSORS`, the state's ``fields`` present, the
    step's :data:`_STEP_INPUTS` — returning the new state's fields (contiguous, as the first step's are), the
    record's and the redo flag; the model is a submodule, so that export makes its buffers and parameters inputs.
    ``traced`` receives the model's fingerprint after the traced step (export restores a module's attributes after
    tracing: a model that changed them when called is seen only there)."""

    def __init__(self, run: RunConstants, fields: tuple[str, ...], traced: Callable[[Any], None]):
        super().__init__()
        self.model = run.model
        self.run, self.fields, self.traced = run, fields, traced

    def forward(self, *flat: Tensor) -> tuple[Tensor, ...]:
        n, m = len(_RUN_TENSORS), len(self.fields)
        run = dataclasses.replace(self.run, **dict(zip(_RUN_TENSORS, flat[:n])))
        state = _state(self.fields, flat[n:n + m])
        new, record, redo = _whole_step(run, state, **dict(zip(_STEP_INPUTS, flat[n + m:])))
        self.traced(_fingerprint(self.model, [], set()))
        return (*(getattr(new, f).contiguous() for f in self.fields), *record, redo)


def _state(fields: tuple[str, ...], tensors: Any) -> FilterState:
    """The :class:`FilterState` with ``fields`` set to ``tensors``, the others ``None``."""
    return FilterState(**{**dict.fromkeys(FilterState._fields), **dict(zip(fields, tensors))})


def _fingerprint(obj: Any, objects: list, seen: set[int], depth: int = 0) -> Any:
    """A hashable summary of what an exported graph may hold of ``obj`` as constants: plain values by value,
    tensors by identity and version counter (an in-place change bumps it; without :class:`Capabilities`'
    ``version_counter`` by identity alone, and the caller does not fuse), other objects by identity and their
    attributes (an ``nn.Module`` without its buffers, parameters and hooks: those are inputs), recursively.
    ``objects`` collects what is summarised by identity (the caller checks that they are still the same objects)."""
    if obj is None or isinstance(obj, (bool, int, float, complex, str, bytes, torch.dtype, torch.device)):
        return obj
    if isinstance(obj, Tensor):
        objects.append(obj)
        return "tensor", id(obj), obj._version if capabilities().version_counter else None
    if id(obj) in seen or depth > 8:
        return "seen", id(obj)
    seen.add(id(obj))
    parts = lambda items: tuple((k, _fingerprint(v, objects, seen, depth + 1)) for k, v in items)  # noqa: E731
    if isinstance(obj, (tuple, list)):
        return type(obj).__name__, parts(enumerate(obj))
    if isinstance(obj, dict):
        return "dict", parts(obj.items())
    objects.append(obj)
    attrs = getattr(obj, "__dict__", None)
    if attrs is None:
        return "object", id(obj)
    if isinstance(obj, torch.nn.Module):
        attrs = {k: v for k, v in attrs.items() if k not in _MODULE_INTERNALS}
        attrs["children"] = dict(obj.named_children())
    return type(obj).__qualname__, id(obj), parts(sorted(attrs.items()))


def _signature(tensors: Any) -> tuple:
    """Shape, stride, dtype and device of each tensor (what a compiled graph is specialised to)."""
    return tuple((tuple(t.shape), t.stride(), t.dtype, t.device) for t in tensors)


def _weak(obj: Any) -> Callable[[], Any]:
    """A weak reference to ``obj`` where it takes one, else a strong one (called like a weak reference)."""
    try:
        return weakref.ref(obj)
    except TypeError:
        return lambda: obj


@dataclasses.dataclass(frozen=True, eq=False)
class _Compiled:
    """One exported and compiled whole step (``fn None``: the model cannot be fused, its step runs in two halves):
    the compiled graph, what feeds each of its inputs before the user's (``("buffer" | "parameter", name)`` in the
    model, or ``("constant", tensor)``), and references to the objects of the model's fingerprint when it was
    compiled."""

    fn: Callable[..., Any] | None
    sources: tuple[tuple[str, Any], ...]
    refs: tuple[Callable[[], Any], ...]

    def holds(self, objects: list) -> bool:
        """Whether the fingerprint's objects are still the ones seen at compile time (ids are reused)."""
        return len(objects) == len(self.refs) and all(r() is o for r, o in zip(self.refs, objects))


@dataclasses.dataclass(frozen=True, eq=False)
class _ExportedStep:
    """The whole step of one run as one compiled graph called without TorchDynamo: :meth:`for_run` looks it up or
    exports and compiles it (module docstring: the key), each call passes the flat tensors and redoes a flagged
    step eagerly."""

    fn: Callable[..., Any]
    prefix: tuple[Tensor, ...]  # the model's buffers, parameters and the graph's constants
    fields: tuple[str, ...]  # the state's fields present

    @classmethod
    def for_run(cls, run: RunConstants, state: FilterState, inputs: dict[str, Tensor]) -> _ExportedStep | None:
        """The compiled step for ``run`` (its first step's ``state`` and step ``inputs``), compiled when new;
        ``None`` when the model cannot be fused (its Python state moves when called, or it holds tensors outside
        its buffers and this torch has no version counter)."""
        if state.omega is not None:
            raise ValueError("the compiled step is the ω-known step: omega must be None")
        model = run.model
        fields = tuple(f for f in FilterState._fields if getattr(state, f) is not None)
        flat = (*(getattr(run, n) for n in _RUN_TENSORS), *(getattr(state, f) for f in fields),
                *(inputs[n] for n in _STEP_INPUTS))
        consts = tuple((f.name, getattr(run, f.name)) for f in dataclasses.fields(run)
                       if f.name not in ("model", *_RUN_TENSORS))
        shape = (consts, fields, _signature(flat), _signature(t for _, t in model.named_buffers()),
                 _signature(t for _, t in model.named_parameters()))
        objects: list = []
        key = (_fingerprint(model, objects, set()), shape)
        if not capabilities().version_counter and any(isinstance(o, Tensor) for o in objects):
            return None
        entries = _EXPORTED.setdefault(model, {})
        entry = entries.get(key)
        if entry is None or not entry.holds(objects):
            entry = _export(run, fields, flat, fingerprint=key[0])
            entries[key] = entry = dataclasses.replace(entry, refs=tuple(_weak(o) for o in objects))
        return None if entry.fn is None else cls(entry.fn, _prefix(model, entry.sources), fields)

    def __call__(self, run: RunConstants, state: FilterState, *, L_k: Tensor, G_k: Tensor, y_k: Tensor,
                 observed_k: Tensor) -> tuple[FilterState, StepRecord]:
        m = len(self.fields)
        out = self.fn(*self.prefix, run.wm, run.wc, run.Q, run.R, *(getattr(state, f) for f in self.fields),
                      L_k, G_k, y_k, observed_k)
        if bool(out[-1]):
            return usque_step(run, state, L_k=L_k, G_k=G_k, y_k=y_k, observed_k=observed_k)
        return _state(self.fields, out[:m]), StepRecord(*out[m:-1])


def _prefix(model: Any, sources: tuple[tuple[str, Any], ...]) -> tuple[Tensor, ...]:
    """The tensors that feed the graph's inputs before the user's: the model's buffers and parameters as they are
    now, and the graph's constants."""
    getters = {"buffer": model.get_buffer, "parameter": model.get_parameter}
    return tuple(src if kind == "constant" else getters[kind](src) for kind, src in sources)


def _export(run: RunConstants, fields: tuple[str, ...], flat: tuple[Tensor, ...], *, fingerprint: Any) -> _Compiled:
    """Export :class:`_FlatStep` on the first step's tensors and compile its graph (:func:`_compile_graph`); a model
    whose fingerprint (before: ``fingerprint``) moved while its step was traced is not fused (``fn None``)."""
    traced: list = []
    program = torch.export.export(_FlatStep(run, fields, traced.append), flat, strict=False)
    if traced != [fingerprint]:  # a counter, a per-call setting: one traced graph would freeze it
        return _Compiled(None, (), ())
    kinds = {"PARAMETER": "parameter", "BUFFER": "buffer", "CONSTANT_TENSOR": "constant"}
    specs = program.graph_signature.input_specs
    head = specs[:len(specs) - len(flat)]
    if any(s.kind.name not in kinds for s in head) or any(s.kind.name != "USER_INPUT" for s in specs[len(head):]):
        raise RuntimeError(f"the exported filter step takes inputs {[s.kind.name for s in specs]}; expected the "
                           "model's tensors, then the step's")
    sources = tuple((kinds[s.kind.name], program.constants[s.target] if s.kind.name == "CONSTANT_TENSOR"
                     else s.target.removeprefix("model.")) for s in head)
    return _Compiled(_compile_graph(program.graph_module, [*_prefix(run.model, sources), *flat]), sources, ())


def _compile_graph(graph: torch.fx.GraphModule, example: list[Tensor]) -> Callable[..., Any]:
    """The exported graph (every input flat: the model's tensors, then the step's) compiled by inductor: called
    directly where this torch has ``torch._inductor.compile`` (:class:`Capabilities`), else through the public
    ``torch.compile`` (the same graph, a TorchDynamo guard check per call)."""
    inductor_compile = capabilities().inductor_compile
    if inductor_compile is not None:
        return inductor_compile(graph, example, options=_INDUCTOR_OPTIONS)
    return torch.compile(graph, dynamic=False, options=_INDUCTOR_OPTIONS)
