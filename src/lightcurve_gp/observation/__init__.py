"""Observation models behind one interface: exact GP, inducing-point GP and the parametric renderer."""

from lightcurve_gp.observation.base import ObservationModel, ObservationModule, Variance
from lightcurve_gp.observation.exact_gp import ExactGP
from lightcurve_gp.observation.parametric import Parametric
from lightcurve_gp.observation.serialization import ModelFileError, build_model, load_model, save_model
from lightcurve_gp.observation.sparse_gp import SparseGP
from lightcurve_gp.observation.surface_marginal import SurfaceMarginalGP

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
