"""Observation models behind one interface: exact GP, inducing-point GP and the parametric renderer."""

from .base import ObservationModel
from .exact_gp import ExactGP
from .parametric import Parametric
from .serialization import ModelFileError, build_model, load_model, save_model
from .sparse_gp import SparseGP

__all__ = ["ObservationModel", "ExactGP", "SparseGP", "Parametric", "ModelFileError", "build_model", "load_model",
           "save_model"]
