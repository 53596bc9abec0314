"""Analytic Herschel-Bulkley plane-Poiseuille flow: velocity profile, loss and its closed-form Hessian."""
from .flow import velocity
from .hessian import hessian
from .loss import loss

__all__ = ["velocity", "loss", "hessian"]
