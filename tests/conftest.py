"""Shared test settings: small tensors run fastest on one thread (dispatch overhead dominates, docs/design.md)."""

import signal

import pytest
import torch

torch.set_num_threads(1)


@pytest.fixture
def sigint_default():
    """Python's own SIGINT handler for the test, whatever the shell gave the process.

    A shell that ignores SIGINT (a script's background job, ``trap "" INT``) starts Python with SIGINT ignored, and
    Python then installs no handler of its own: a test that signals itself to check the Ctrl-C path would see
    nothing. The previous disposition is restored afterwards."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
