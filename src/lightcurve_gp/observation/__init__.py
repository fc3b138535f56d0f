"""Observation models behind one interface: exact GP, inducing-point GP and the parametric renderer."""

from .base import ObservationModel, ObservationModule, Variance
from .exact_gp import ExactGP
from .parametric import Parametric
from .serialization import ModelFileError, build_model, load_model, save_model
from .sparse_gp import SparseGP
from .surface_marginal import SurfaceMarginalGP

__all__ = [
           "ExactGP",
           "ModelFileError",
           "ObservationModel",
           "ObservationModule",
           "Parametric",
           "SparseGP",
           "SurfaceMarginalGP",
           "Variance",
           "build_model",
           "load_model",
           "save_model",
]
