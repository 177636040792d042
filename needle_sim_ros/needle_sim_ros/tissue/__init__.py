"""Needle-tissue interaction models (ROS-free): seed 001 (Karnopp friction, bevel tip, angular-spring needle), seed 002
(insertion force profile), seed 003 (modified LuGre), and their coupling to the ANCF needle as force contributions
(``build_tissue_model``, ``TissueModel``: imported on first use, as they need ``needle_sim_ros.model``).
Identification from data: :mod:`needle_sim_ros.identification`.
"""
from .angular_spring import AngularSpringNeedle
from .bevel_tip import BevelTip
from .geometry import TissueBlock, TissueLayer, inserted_interval
from .insertion_profile import InsertionForceProfile
from .lugre import LuGreParameters, ModifiedLuGre

_COUPLING_NAMES = ("build_tissue_model", "TISSUE_PARAMETERS", "TissueModel", "TissueReadout")


def __getattr__(name: str):
    if name in _COUPLING_NAMES:
        from . import factory, tissue_model
        return getattr(factory if hasattr(factory, name) else tissue_model, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["AngularSpringNeedle", "BevelTip", "TissueBlock", "TissueLayer", "inserted_interval",
           "InsertionForceProfile", "LuGreParameters", "ModifiedLuGre", *_COUPLING_NAMES]
