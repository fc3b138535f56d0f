"""Training: the data and the fit of the GP observation models, and the store they are kept in.

* :mod:`.windows` — the paper's training windows and what every training set shares.
* :mod:`.surfaces`, :mod:`.geometry` — training sets over many surfaces, over geometries.
* :mod:`.sets` — the training set a config needs, its cache, the targets.
* :mod:`.fit` — :func:`~.fit.train`: data, fit, held-out metrics, model file (no command-line or plotting code).
* :mod:`.keys`, :mod:`.store` — what a model depends on, and the one model store keyed by it.
"""
