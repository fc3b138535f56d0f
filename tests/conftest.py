"""Shared test settings: small tensors run fastest on one thread (dispatch overhead dominates, docs/design.md)."""

import torch

torch.set_num_threads(1)
